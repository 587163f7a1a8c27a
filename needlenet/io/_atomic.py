"""Write outputs whole or not at all: a temporary file in the same directory, then a rename."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = ["atomic_write", "check_outputs"]


def check_outputs(paths: list[Path], overwrite: bool) -> None:
    """Refuse to replace an existing output unless ``overwrite``; the directory must exist."""
    for p in paths:
        if (p.exists() or p.is_symlink()) and not overwrite:
            raise FileExistsError(f"output {p} exists; pass overwrite=True (--overwrite) to "
                                  "replace it")
        parent = p.parent if str(p.parent) else Path(".")
        if not parent.is_dir():
            raise FileNotFoundError(f"output {p}: directory {parent} does not exist")


def atomic_write(writers: dict[Path, Callable], overwrite: bool) -> list[Path]:
    """Write several files together: each ``writer(fh)`` fills a temporary file next to its
    target; only when all have been written are they renamed into place (so an error or an
    interruption leaves every existing output as it was)."""
    paths = [Path(p) for p in writers]
    check_outputs(paths, overwrite)
    tmps: list[tuple[str, Path]] = []
    try:
        for path, write in writers.items():
            path = Path(path)
            parent = path.parent if str(path.parent) else Path(".")
            # the name shortened: a temporary name must fit where the output's own fits
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name[:64]}.", suffix=".tmp", dir=parent)
            tmps.append((tmp, path))
            with os.fdopen(fd, "wb") as fh:
                write(fh)
            os.chmod(tmp, 0o644)  # mkstemp makes it private
        for tmp, path in tmps:
            os.replace(tmp, path)
    finally:
        for tmp, _ in tmps:
            if os.path.exists(tmp):
                os.unlink(tmp)
    return paths
