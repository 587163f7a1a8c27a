"""Reading and writing: sequence files (via synth) and overlay animations."""

from ._overlay import overlay_frames, write_overlay

__all__ = ["overlay_frames", "write_overlay"]
