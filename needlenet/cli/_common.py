"""What every subcommand shares: the one-line user error and the checks of output paths."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["CLIError", "check_output", "check_plus_output", "seed"]


class CLIError(Exception):
    """A user error: printed as one line, exit status 2."""


def seed(text: str) -> int:
    """argparse type of ``--seed``: a whole number 0 to 2^63 - 1 (what numpy's generators
    take)."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 0 <= value < 2**63:
        raise argparse.ArgumentTypeError(f"{value} is outside 0 to 2^63 - 1")
    return value


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist
        pass
    try:
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError):  # a symlink loop, a name too long
        return False


def check_output(path: str | None, suffix: str, overwrite: bool, what: str,
                 inputs: tuple = ()) -> Path | None:
    """``path`` (None stays None) if it ends in ``suffix``, is no directory and none of
    ``inputs`` (a recording is never overwritten by its own results, even with
    ``overwrite``), does not exist (or ``overwrite``; a symlink there counts as existing,
    even one that points nowhere) and its directory exists and is writable; otherwise a
    CLIError naming ``what``. Checked before any work is done."""
    if path is None:
        return None
    if not str(path).strip():
        raise CLIError(f"{what} {path!r}: give a file name ending in {suffix}")
    p = Path(path)
    if p.suffix.lower() != suffix:
        raise CLIError(f"{what} {p}: must end in {suffix}")
    try:
        _check_path(p, suffix, overwrite, what, inputs)
    except OSError as exc:  # a name too long, a symlink loop, a path under a file
        raise CLIError(f"{what} {p}: {exc.strerror or exc}") from None
    return p


def _check_path(p: Path, suffix: str, overwrite: bool, what: str, inputs: tuple) -> None:
    if len(os.fsencode(p.name)) > _name_max(p.parent):
        raise CLIError(f"{what} {p}: the file name is longer than this file system allows")
    if p.is_dir():
        raise CLIError(f"{what} {p} is a directory; give a file name ending in {suffix}")
    for src in inputs:
        if _same_file(p, Path(src)):
            raise CLIError(f"{what} {p} is the input {src}; write the results to another file")
    if (p.exists() or p.is_symlink()) and not overwrite:
        raise CLIError(f"{what} {p} exists; pass --overwrite to replace it")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise CLIError(f"{what} {p}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise CLIError(f"{what} {p}: directory {parent} is not writable")


def _name_max(directory: Path) -> int:
    """The longest file name the directory's file system takes (255 where it cannot say),
    less one for the ``.zraw`` beside an ``.mhd``."""
    try:
        limit = os.pathconf(directory if str(directory) else ".", "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = 255
    return int(limit) - 1


def check_plus_output(path: str, overwrite: bool, what: str, inputs: tuple = ()) -> Path:
    """A PLUS output (``.mha``, ``.seq.mha``, or ``.mhd`` with its ``.zraw``): checked like
    every output, the data file next to an ``.mhd`` included."""
    from ..io import plus_outputs

    suffix = Path(path).suffix.lower()
    if suffix not in (".mha", ".mhd"):
        raise CLIError(f"{what} {path}: a PLUS sequence file must end in .mha or .mhd "
                       "(e.g. NAME.seq.mha)")
    if suffix == ".mhd" and any(c.isspace() for c in Path(path).name):
        raise CLIError(f"{what} {path}: an .mhd's data file is named in its header, where a "
                       "name with spaces or line breaks cannot be read back; use .mha or "
                       "another name")
    first = check_output(path, suffix, overwrite, what, inputs)
    for extra in plus_outputs(first)[1:]:
        check_output(str(extra), extra.suffix.lower(), overwrite, what, inputs)
    return first
