"""NRRD volumes and sequences (``.nrrd``, ``.seq.nrrd``, ``.nhdr``) through pynrrd.

Each NRRD axis has a ``kind``: ``domain`` / ``space`` axes are spatial; a ``list`` (or
``time``) axis is the frame axis, as in 3D Slicer's sequence files (``kinds: list domain
domain domain`` with the frame times in the custom field ``axis 0 index values``); an
``RGB-color`` / ``RGBA-color`` / ``3-color`` / ``4-color`` / ``vector`` axis is converted to
gray. Without ``kinds``, an axis whose ``space directions`` entry is ``none`` is the frame axis.

The spacing of a spatial axis is the length of its ``space directions`` vector, or its
``spacings`` entry; the origin is ``space origin`` projected on each axis direction. NRRD's
first (fastest) spatial axis is read as lateral and its last as depth, so a volume comes out as
``[depth, elevation, lateral]`` and a 2D frame as ``[depth, lateral]``, like the sequence file.
"""

from __future__ import annotations

import os
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._errors import RecordingError
from ._metaimage import _to_gray_uint8

__all__ = ["NrrdRecording", "read_nrrd"]

_SPATIAL = ("domain", "space")
_LIST = ("list", "time")
_COLOR = ("rgb-color", "rgba-color", "3-color", "4-color", "vector", "3-vector", "4-vector")


@dataclass
class NrrdRecording:
    images: np.ndarray  # uint8 (T, H, W) or (T, Z, Y, X)
    spacing_mm: np.ndarray | None
    origin_mm: np.ndarray
    timestamps_s: np.ndarray | None
    meta: dict = field(default_factory=dict)


def read_nrrd(path: str | os.PathLike) -> NrrdRecording:
    """Read a NRRD image, volume or sequence; raise :class:`RecordingError` naming the file and
    the field at fault."""
    import nrrd

    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise FileNotFoundError(f"{src}: no such recording")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            data, header = nrrd.read(src, index_order="F")
    except (nrrd.NRRDError, OSError, ValueError, EOFError, zlib.error, TypeError) as exc:
        raise RecordingError(f"{src}: not a readable NRRD file ({exc})") from None
    nd = data.ndim
    kinds = [str(k).lower() for k in header.get("kinds", [])]
    if kinds and len(kinds) != nd:
        raise RecordingError(f"{src}: field kinds has {len(kinds)} entries for dimension {nd}")
    dirs = header.get("space directions")
    if dirs is not None:
        dirs = np.asarray(dirs, dtype=float)
        if dirs.shape[0] != nd:
            raise RecordingError(f"{src}: field space directions has {dirs.shape[0]} entries "
                                 f"for dimension {nd}")
    roles = []
    for a in range(nd):
        k = kinds[a] if kinds else None
        if k in _LIST:
            roles.append("list")
        elif k in _COLOR:
            roles.append("color")
        elif k in _SPATIAL or k is None:
            if k is None and dirs is not None and not np.all(np.isfinite(dirs[a])):
                roles.append("list")
            else:
                roles.append("space")
        else:
            raise RecordingError(f"{src}: field kinds: axis {a} has kind {k!r}; needlenet reads "
                                 "domain/space axes, one list (frame) axis and one colour axis")
    spatial = [a for a, r in enumerate(roles) if r == "space"]
    lists = [a for a, r in enumerate(roles) if r == "list"]
    colors = [a for a, r in enumerate(roles) if r == "color"]
    if len(lists) > 1 or len(colors) > 1 or len(spatial) not in (2, 3):
        raise RecordingError(
            f"{src}: axes {roles} (from kinds / space directions): expected 2 or 3 spatial "
            "axes, at most one list (frame) axis and at most one colour axis")
    order = lists + spatial[::-1] + colors  # -> (T, depth, ..., lateral, C)
    arr = np.transpose(data, order)
    if not lists:
        arr = arr[None]
    channels = int(data.shape[colors[0]]) if colors else 1
    images, irange = _to_gray_uint8(np.ascontiguousarray(arr), channels)

    spacing = None
    unit = []
    if dirs is not None and all(np.all(np.isfinite(dirs[a])) for a in spatial):
        spacing = np.array([np.linalg.norm(dirs[a]) for a in spatial])
        unit = [dirs[a] / max(np.linalg.norm(dirs[a]), 1e-300) for a in spatial]
    elif "spacings" in header:
        sp = np.asarray(header["spacings"], float)
        if sp.shape == (nd,) and np.all(np.isfinite(sp[spatial])):
            spacing = np.abs(sp[spatial])
    if spacing is not None and np.any(spacing <= 0):
        raise RecordingError(f"{src}: spatial axes have zero spacing ({spacing})")
    origin = np.zeros(len(spatial))
    if "space origin" in header and unit:
        so = np.asarray(header["space origin"], float)
        if np.all(np.isfinite(so)):
            origin = np.array([so @ u for u in unit])
    elif "axis mins" in header:
        mins = np.asarray(header["axis mins"], float)
        if mins.shape == (nd,) and np.all(np.isfinite(mins[spatial])):
            origin = mins[spatial]
    if spacing is not None:
        spacing, origin = spacing[::-1], origin[::-1]
    else:
        origin = origin[::-1]

    timestamps = None
    if lists:
        key = f"axis {lists[0]} index values"
        if key in header:
            try:
                ts = np.array([float(v) for v in str(header[key]).split()])
            except ValueError:
                raise RecordingError(f"{src}: field {key!r} is not a list of numbers") from None
            if ts.shape != (images.shape[0],):
                raise RecordingError(f"{src}: field {key!r} has {ts.size} values for "
                                     f"{images.shape[0]} frames")
            timestamps = ts
    meta = {"nrrd": {"kinds": kinds, "space": header.get("space")}}
    if irange is not None:
        meta["intensity_range"] = list(irange)
    return NrrdRecording(images, spacing, origin, timestamps, meta)
