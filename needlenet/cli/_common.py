"""What every subcommand shares: the one-line user error and the checks of output paths."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["CLIError", "check_output", "check_plus_output"]


class CLIError(Exception):
    """A user error: printed as one line, exit status 2."""


def check_output(path: str | None, suffix: str, overwrite: bool, what: str) -> Path | None:
    """``path`` (None stays None) if it ends in ``suffix``, does not exist (or ``overwrite``)
    and its directory exists and is writable; otherwise a CLIError naming ``what``."""
    if path is None:
        return None
    p = Path(path)
    if p.suffix.lower() != suffix:
        raise CLIError(f"{what} {p}: must end in {suffix}")
    if p.exists() and not overwrite:
        raise CLIError(f"{what} {p} exists; pass --overwrite to replace it")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise CLIError(f"{what} {p}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise CLIError(f"{what} {p}: directory {parent} is not writable")
    return p


def check_plus_output(path: str, overwrite: bool, what: str) -> Path:
    """A PLUS output (``.mha``, ``.seq.mha``, or ``.mhd`` with its ``.zraw``): checked like
    every output, the data file next to an ``.mhd`` included."""
    from ..io._metaimage import plus_outputs

    suffix = Path(path).suffix.lower()
    if suffix not in (".mha", ".mhd"):
        raise CLIError(f"{what} {path}: a PLUS sequence file must end in .mha or .mhd "
                       "(e.g. NAME.seq.mha)")
    first = check_output(path, suffix, overwrite, what)
    for extra in plus_outputs(first)[1:]:
        if extra.exists() and not overwrite:
            raise CLIError(f"{what} {extra} exists; pass --overwrite to replace it")
    return first
