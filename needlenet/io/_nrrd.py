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

import math
import os
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._errors import RecordingError
from ._gray import to_gray_uint8
from ._lazy import ZlibStream, inflated_frames, mapped_frames
from ._limits import check_allocation, check_frame_shape

__all__ = ["NrrdRecording", "read_nrrd"]

_UINT8 = ("uchar", "unsigned char", "uint8", "uint8_t")
_SPATIAL = ("domain", "space")
_LIST = ("list", "time")
_COLOR = ("rgb-color", "rgba-color", "3-color", "4-color", "vector", "3-vector", "4-vector")


@dataclass
class NrrdRecording:
    images: np.ndarray  # uint8 (T, H, W) or (T, Z, Y, X); raw 8-bit data: a FrameStack
    spacing_mm: np.ndarray | None
    origin_mm: np.ndarray
    timestamps_s: np.ndarray | None
    meta: dict = field(default_factory=dict)


# NRRD's scalar type names (the format's specification) and their sizes in bytes
_TYPE_BYTES = {**dict.fromkeys(("signed char", "int8", "int8_t", "uchar", "unsigned char",
                                "uint8", "uint8_t"), 1),
               **dict.fromkeys(("short", "short int", "signed short", "signed short int",
                                "int16", "int16_t", "ushort", "unsigned short",
                                "unsigned short int", "uint16", "uint16_t"), 2),
               **dict.fromkeys(("int", "signed int", "int32", "int32_t", "uint",
                                "unsigned int", "uint32", "uint32_t", "float"), 4),
               **dict.fromkeys(("longlong", "long long", "long long int", "signed long long",
                                "signed long long int", "int64", "int64_t", "ulonglong",
                                "unsigned long long", "unsigned long long int", "uint64",
                                "uint64_t", "double"), 8)}


def _check_header(path: Path, src: str) -> tuple[dict, tuple | None, tuple | None]:
    """The header alone, before any pixel is read: a known scalar type, sizes this machine can
    hold, and a detached data file that is a regular file next to the header holding (for raw
    encoding) the bytes the sizes need. Returns the header; for raw unsigned 8-bit data that
    the file holds exactly (no line skip), the data file and the offset of the pixels, which
    can then be memory-mapped (else None); for gzip-encoded unsigned 8-bit data that inflates
    to exactly those bytes, the data file, where the gzip stream starts and how many inflated
    bytes to skip (else None)."""
    import nrrd

    try:
        with open(path, "rb") as fh, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            header = nrrd.read_header(fh)
            header_end = fh.tell()
    except Exception as exc:  # a damaged header raises whatever pynrrd's parser meets
        raise RecordingError(f"{src}: not a readable NRRD header ({type(exc).__name__}: "
                             f"{' '.join(str(exc).split())[:200]})") from None
    kind = str(header.get("type", "")).strip().lower()
    if kind not in _TYPE_BYTES:
        raise RecordingError(f"{src}: field type = {header.get('type')!r} is not a scalar type "
                             "needlenet reads (uchar, short, float, ...)")
    sizes = np.atleast_1d(np.asarray(header.get("sizes", []))).astype(object)
    if not sizes.size or any(not isinstance(n, (int, np.integer)) or n < 1 for n in sizes):
        raise RecordingError(f"{src}: field sizes = {sizes.tolist()} must be positive whole "
                             "numbers")
    nbytes = math.prod(int(n) for n in sizes) * _TYPE_BYTES[kind]
    encoding = str(header.get("encoding", "")).lower()
    span = _mappable_span(path, header, header_end, nbytes) if kind in _UINT8 else None
    if span is None:  # read whole: it must fit in memory
        check_allocation(sizes, _TYPE_BYTES[kind], src, "sizes/type")
    kinds = [str(k).lower() for k in header.get("kinds", [])]
    if len(kinds) == sizes.size:  # a frame: the spatial axes (not the list or colour axis)
        check_frame_shape([n for n, k in zip(sizes, kinds, strict=True)
                           if k not in _LIST + _COLOR], src, "sizes/kinds")
    raw = encoding == "raw"
    data_file = header.get("data file", header.get("datafile"))
    if data_file is None:
        target, start = path, header_end
    else:
        target = Path(str(data_file))
        target = target if target.is_absolute() else path.parent / target
        if not target.is_file():
            raise RecordingError(f"{src}: field data file = {data_file!r} is not a regular "
                                 "file (missing, a folder or a device); needlenet reads one "
                                 "detached data file")
        start = 0
    avail = os.path.getsize(target) - start
    line_skip = header.get("line skip", header.get("lineskip", 0))
    byte_skip = header.get("byte skip", header.get("byteskip", 0))
    # every skipped line is at least one byte: a line skip beyond the data is a damaged
    # header (pynrrd would read 10^9 empty lines, for minutes)
    if not isinstance(line_skip, (int, np.integer)) or not 0 <= line_skip <= avail:
        raise RecordingError(f"{src}: field line skip = {line_skip!r} must be 0 to the "
                             f"{avail} bytes of data")
    if not isinstance(byte_skip, (int, np.integer)) or byte_skip < -1 or \
            (raw and byte_skip > avail):
        raise RecordingError(f"{src}: field byte skip = {byte_skip!r} must be -1 to the "
                             f"{avail} bytes of data")
    if raw and avail - max(int(byte_skip), 0) < nbytes:
        where = src if data_file is None else f"{target} ({src}'s data file)"
        raise RecordingError(f"{where}: truncated: sizes/type need {nbytes} bytes of pixels, "
                             f"the file has {avail - max(int(byte_skip), 0)}")
    gz_at = None
    if encoding in ("gzip", "gz", "bzip2", "bz2"):
        total = _check_inflated(target, start, encoding, nbytes + max(int(byte_skip), 0), src)
        skip = total - nbytes if byte_skip == -1 else int(byte_skip)
        if encoding in ("gzip", "gz") and kind in _UINT8 and line_skip == 0 and \
                total - skip == nbytes:  # as pynrrd reads it: exactly the bytes of the sizes
            gz_at = (target, start, skip)
    return header, span, gz_at


def _mappable_span(path: Path, header: dict, header_end: int,
                   nbytes: int) -> tuple[Path, int] | None:
    """The data file and the offset of ``nbytes`` of raw pixels when the file holds exactly
    those after the header and skips (as pynrrd reads raw data: to the end of the file, or the
    last bytes with ``byte skip: -1``), with no line skip; None otherwise."""
    if str(header.get("encoding", "")).lower() != "raw" or \
            header.get("line skip", header.get("lineskip", 0)) != 0 or \
            not all(k in header for k in ("dimension", "type", "sizes", "encoding")):
        return None
    data_file = header.get("data file", header.get("datafile"))
    target, start = (path, header_end) if data_file is None else (Path(str(data_file)), 0)
    if data_file is not None and not target.is_absolute():
        target = path.parent / target
    byte_skip = header.get("byte skip", header.get("byteskip", 0))
    if not target.is_file() or not isinstance(byte_skip, (int, np.integer)) or byte_skip < -1:
        return None
    end = os.path.getsize(target)
    first = end - nbytes if byte_skip == -1 else start + int(byte_skip)
    return (target, first) if first >= start and end - first == nbytes else None


def _check_inflated(target: Path, start: int, encoding: str, need: int, src: str) -> int:
    """The compressed data inflates to no more than ``need`` bytes: pynrrd inflates the whole
    stream before it compares sizes, so a few megabytes that inflate to gigabytes would be
    allocated whole. Inflated here in 1 MiB pieces, counted and dropped; returns the count."""
    import bz2

    gz = encoding in ("gzip", "gz")
    d = zlib.decompressobj(zlib.MAX_WBITS | 16) if gz else bz2.BZ2Decompressor()
    step = 1 << 20
    total = 0

    def count(out: bytes) -> None:
        nonlocal total
        total += len(out)
        if total > need:
            raise RecordingError(f"{src}: the {encoding} data inflates to more than the {need} "
                                 "bytes that sizes/type describe; damaged header or data?")

    try:
        with open(target, "rb") as fh:
            fh.seek(start)
            while not d.eof:
                chunk = fh.read(step)
                if not chunk:
                    break
                if gz:
                    while chunk and not d.eof:
                        count(d.decompress(chunk, step))
                        chunk = d.unconsumed_tail
                else:
                    count(d.decompress(chunk, step))
                    while not d.eof and not d.needs_input:
                        count(d.decompress(b"", step))
    except (zlib.error, OSError, EOFError) as exc:
        raise RecordingError(f"{src}: the {encoding} data is damaged "
                             f"({' '.join(str(exc).split())[:120]})") from None
    return total


def _axes(header: dict, nd: int, src: str):
    """The axes' roles from ``kinds`` (or ``space directions``): the space directions
    (None without them), the kinds, and the spatial, list (frame) and colour axes."""
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
    return dirs, kinds, spatial, lists, colors


def read_nrrd(path: str | os.PathLike) -> NrrdRecording:
    """Read a NRRD image, volume or sequence; raise :class:`RecordingError` naming the file and
    the field at fault."""
    import nrrd

    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise FileNotFoundError(f"{src}: no such recording")
    header, span, gz_at = _check_header(path, src)
    if span is not None or gz_at is not None:
        sizes = [int(n) for n in header["sizes"]]
        dirs, kinds, spatial, lists, colors = _axes(header, len(sizes), src)
        if lists and lists[0] != len(sizes) - 1:
            span = gz_at = None  # frames interleaved (list axis not the slowest): read whole
    if span is None and gz_at is None:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                data, header = nrrd.read(src, index_order="F")
        except (nrrd.NRRDError, OSError, ValueError, EOFError, zlib.error, TypeError,
                KeyError, StopIteration, MemoryError) as exc:
            raise RecordingError(f"{src}: not a readable NRRD file "
                                 f"({' '.join(str(exc).split())[:200]})") from None
        sizes = list(data.shape)
        dirs, kinds, spatial, lists, colors = _axes(header, data.ndim, src)
    nd = len(sizes)
    order = lists + spatial[::-1] + colors  # -> (T, depth, ..., lateral, C)
    channels = int(sizes[colors[0]]) if colors else 1
    if span is not None or gz_at is not None:
        # frame after frame, each in Fortran order: a C-order frame is its axes reversed
        frame_c = (sizes[:-1] if lists else sizes)[::-1]
        frame_order = spatial[::-1] + colors
        T, out_shape = sizes[-1] if lists else 1, [sizes[a] for a in spatial[::-1]]

        def prepare(raw: np.ndarray) -> np.ndarray:
            return to_gray_uint8(raw.T.transpose(frame_order)[None], channels)[0][0]

        if span is not None:
            images = mapped_frames(span[0], span[1], T, frame_c, np.uint8, prepare, out_shape)
        else:
            target, start, skip = gz_at
            stream = ZlibStream(target, start, os.path.getsize(target) - start,
                                wbits=zlib.MAX_WBITS | 16)
            images = inflated_frames(stream, T, frame_c, np.uint8, prepare, out_shape, src,
                                     skip=skip)
        irange, notes = None, []
    else:
        arr = np.transpose(data, order)
        if not lists:
            arr = arr[None]
        images, irange, notes = to_gray_uint8(np.ascontiguousarray(arr), channels)

    spacing = None
    unit = []
    if dirs is not None and all(np.all(np.isfinite(dirs[a])) for a in spatial):
        with np.errstate(over="ignore", invalid="ignore"):  # 1e300: refused by the spacing
            spacing = np.array([np.linalg.norm(dirs[a]) for a in spatial])
            unit = [dirs[a] / max(np.linalg.norm(dirs[a]), 1e-300) for a in spatial]
    elif "spacings" in header:
        sp = np.asarray(header["spacings"], float)
        if sp.shape == (nd,) and np.all(np.isfinite(sp[spatial])):
            spacing = np.abs(sp[spatial])
    if spacing is not None and np.any(spacing <= 0):
        raise RecordingError(f"{src}: spatial axes have zero spacing ({spacing.tolist()})")
    origin = np.zeros(len(spatial))
    if "space origin" in header and unit:
        so = np.asarray(header["space origin"], float)
        if so.shape != unit[0].shape:
            raise RecordingError(f"{src}: field space origin has {so.size} values for "
                                 f"{unit[0].size}-dimensional space directions")
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
    if notes:
        meta["warnings"] = [f"{src}: {n}" for n in notes]
    return NrrdRecording(images, spacing, origin, timestamps, meta)
