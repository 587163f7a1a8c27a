"""The errors of reading, writing and streaming recordings: one line that names the file,
the field or the port, never a traceback from deep inside numpy or zlib."""

from __future__ import annotations

__all__ = ["RecordingError", "StreamError"]


class RecordingError(ValueError):
    """A recording cannot be read or written as asked: the message names the file and the
    field (or the command-line option) at fault."""


class StreamError(ValueError):
    """An OpenIGTLink stream cannot be set up: the message names the host, port or device."""
