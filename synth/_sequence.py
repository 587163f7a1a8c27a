"""The sequence file: one ``.npz`` per sequence, the contract between synth, track and bench.

This module is the only writer and reader of the format (see DESIGN.md, "The sequence
file"). :func:`validate_sequence` checks every key's presence, dtype and shape and raises
:class:`SequenceFileError` naming the file and the key.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "MODALITIES",
    "Sequence",
    "SequenceFileError",
    "save_sequence",
    "load_sequence",
    "validate_sequence",
]

MODALITIES = ("inplane", "axial", "volume")
REQUIRED = ("images", "spacing_mm", "origin_mm", "modality", "timestamps_s", "dynamic_range_db",
            "meta")
OPTIONAL = ("probe_pose", "tip_mm", "entry_mm", "direction", "visible", "centerline_mm",
            "tip_3d_mm", "contrast_ratio")


_MAX_INFLATION = 1032  # deflate inflates at most ~1032:1 (a 258-byte match costs >= 2 bits)
# the largest frame a sequence file may hold: 4096^2 pixels (synth's own limit for a 2D
# frame) or 512^3 voxels, as needlenet.io._limits.MAX_FRAME_PIXELS
MAX_FRAME_PIXELS = {2: 1 << 24, 3: 1 << 27}


class SequenceFileError(ValueError):
    """A sequence file (or in-memory sequence) is missing a key or has a wrong one."""


@dataclass
class Sequence:
    """A labelled sequence of B-mode frames. Array and point conventions as DESIGN.md.

    ``images`` is a uint8 array, or (for a long recording read from disk) an array-like stack
    whose frames ``images[i]`` are read when indexed."""

    images: np.ndarray
    spacing_mm: np.ndarray
    origin_mm: np.ndarray
    modality: str
    timestamps_s: np.ndarray
    dynamic_range_db: float
    meta: dict = field(default_factory=dict)
    probe_pose: np.ndarray | None = None
    tip_mm: np.ndarray | None = None
    entry_mm: np.ndarray | None = None
    direction: np.ndarray | None = None
    visible: np.ndarray | None = None
    centerline_mm: np.ndarray | None = None
    tip_3d_mm: np.ndarray | None = None  # 2D modalities: the tip in the probe frame (x, y, z)
    contrast_ratio: np.ndarray | None = None  # Zhao 2013 eq. (9), per frame

    @property
    def n_frames(self) -> int:
        return int(self.images.shape[0])

    @property
    def ndim(self) -> int:
        """Spatial dimensionality of a frame (2 or 3)."""
        return int(self.images.ndim - 1)

    @property
    def has_labels(self) -> bool:
        return self.tip_mm is not None

    def grid(self):
        from ._geometry import Grid

        return Grid(self.images.shape[1:], tuple(self.spacing_mm), tuple(self.origin_mm))

    def as_dict(self) -> dict:
        d = {k: getattr(self, k) for k in REQUIRED + OPTIONAL}
        return {k: v for k, v in d.items() if v is not None}


def _is_frame_array(im) -> bool:
    """An ndarray, or an array-like stack of frames read on access (it has ``shape``,
    ``dtype``, ``ndim``, ``len()`` and indexing by frame, as ``needlenet.io``'s readers give
    for recordings too long to hold in memory)."""
    if isinstance(im, np.ndarray):
        return True
    return all(hasattr(im, a) for a in ("shape", "dtype", "ndim", "__getitem__", "__len__"))


def _err(source: str, key: str, msg: str) -> SequenceFileError:
    return SequenceFileError(f"{source}: key '{key}': {msg}")


def validate_sequence(seq: Sequence, source: str = "sequence") -> Sequence:
    """Check shapes, dtypes and values; return ``seq`` or raise :class:`SequenceFileError`."""
    im = seq.images
    if not _is_frame_array(im) or im.dtype != np.uint8:
        raise _err(source, "images", f"must be a uint8 array, got {getattr(im, 'dtype', type(im))}")
    if im.ndim not in (3, 4):
        raise _err(source, "images", f"must be (T, H, W) or (T, Z, Y, X), got shape {im.shape}")
    T, nd = im.shape[0], im.ndim - 1
    if T < 1 or any(s < 2 for s in im.shape[1:]):
        raise _err(source, "images", f"needs at least one frame of 2+ pixels, got {im.shape}")
    if seq.modality not in MODALITIES:
        raise _err(source, "modality", f"must be one of {MODALITIES}, got {seq.modality!r}")
    if (seq.modality == "volume") != (nd == 3):
        raise _err(source, "modality",
                   f"{seq.modality!r} does not match {nd}D frames of shape {im.shape[1:]}")
    for key in NUMERIC:
        _check_numeric(getattr(seq, key), source, key)
    for key in ("spacing_mm", "origin_mm"):
        v = np.asarray(getattr(seq, key), float)
        if v.shape != (nd,) or not np.all(np.isfinite(v)):
            raise _err(source, key, f"must be {nd} finite numbers, got {_show(v)}")
        if key == "spacing_mm" and np.any(v <= 0):
            raise _err(source, key, f"must be positive, got {_show(v)}")
    ts = np.asarray(seq.timestamps_s, float)
    if ts.shape != (T,) or not np.all(np.isfinite(ts)):
        raise _err(source, "timestamps_s", f"must be {T} finite numbers, got shape {ts.shape}")
    if T > 1 and np.any(np.diff(ts) < 0):
        raise _err(source, "timestamps_s", "must not decrease")
    dr = float(seq.dynamic_range_db)
    if not np.isfinite(dr) or dr <= 0:
        raise _err(source, "dynamic_range_db", f"must be positive, got {dr}")
    if not isinstance(seq.meta, dict):
        raise _err(source, "meta", "must be a JSON object")
    shapes = {
        "probe_pose": (T, 4, 4), "tip_mm": (T, nd), "entry_mm": (T, nd), "direction": (T, nd),
        "visible": (T,), "tip_3d_mm": (T, 3), "contrast_ratio": (T,),
    }
    for key, shape in shapes.items():
        v = getattr(seq, key)
        if v is None:
            continue
        v = np.asarray(v)
        if v.shape != shape:
            raise _err(source, key, f"must have shape {shape}, got {v.shape}")
        if key == "visible":
            if v.dtype != bool:
                raise _err(source, key, f"must be bool, got {v.dtype}")
        elif key not in ("tip_mm", "direction", "contrast_ratio") and not np.all(np.isfinite(v)):
            raise _err(source, key, "must be finite")
        elif key != "visible" and np.any(np.isinf(v)):  # NaN: unknown; infinity: never
            raise _err(source, key, "must be finite, or NaN where unknown (it holds infinity)")
    if seq.direction is not None:
        d = np.asarray(seq.direction, float)
        known = np.isfinite(d).all(axis=1)
        if np.any(~known & ~np.isnan(d).all(axis=1)):
            raise _err(source, "direction", f"frame {int(np.flatnonzero(~known)[0])} is "
                       "partly NaN; a direction is known (finite) or not (all NaN)")
        with np.errstate(over="ignore", invalid="ignore"):
            norm = np.linalg.norm(d[known], axis=1)
        bad = ~((norm > 1e-6) & (norm < 1e6))
        if np.any(bad):
            raise _err(source, "direction", f"frame {int(np.flatnonzero(known)[bad][0])}: a "
                       f"vector of length {float(norm[bad][0]):.3g}; directions are unit "
                       "vectors (NaN where unknown)")
    if seq.centerline_mm is not None:
        c = np.asarray(seq.centerline_mm)
        if c.ndim != 3 or c.shape[0] != T or c.shape[2] not in (2, 3):
            raise _err(source, "centerline_mm", f"must be (T, K, 2 or 3), got {c.shape}")
    if seq.tip_mm is not None:
        # what the metrics of each modality need beside the tip (see needlenet.eval)
        for key in ("visible", "direction") + (("entry_mm",) if nd == 3 else ()):
            if getattr(seq, key) is None:
                raise _err(source, key, "is required when tip_mm is given")
    return seq


NUMERIC = ("spacing_mm", "origin_mm", "timestamps_s", "probe_pose", "tip_mm", "entry_mm",
           "direction", "centerline_mm", "tip_3d_mm", "contrast_ratio")


def _check_numeric(v, source: str, key: str) -> None:
    """``v`` (None: absent) is an array of real numbers (not text, bytes, dates, complex)."""
    if v is None:
        return
    a = np.asarray(v)
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.integer)
                               or np.issubdtype(a.dtype, np.floating)):
        raise _err(source, key, f"must hold real numbers, got dtype {a.dtype}")


def _show(v: np.ndarray) -> str:
    """An array in an error message, on one line."""
    return str(np.asarray(v).tolist())[:120]


def save_sequence(seq: Sequence, path: str | os.PathLike, overwrite: bool = False) -> Path:
    """Validate and write ``seq``; never leaves a partial file and never overwrites unasked."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"output {path}: a sequence file must end in .npz")
    if path.exists() and not overwrite:
        raise FileExistsError(
            f"output {path} exists; pass overwrite=True (--overwrite) to replace it")
    validate_sequence(seq)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"output {path}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise PermissionError(f"output {path}: directory {parent} is not writable")
    arrays = {}
    for k, v in seq.as_dict().items():
        if k == "meta":
            arrays[k] = np.array(json.dumps(v, sort_keys=True))
        elif k == "modality":
            arrays[k] = np.array(v)
        else:
            arrays[k] = np.asarray(v)
    fd, tmp = tempfile.mkstemp(suffix=".npz", dir=parent)
    try:
        with os.fdopen(fd, "wb") as fh, zipfile.ZipFile(fh, "w", zipfile.ZIP_DEFLATED) as zf:
            for k in sorted(arrays):
                # a fixed timestamp: the same sequence always gives the same bytes
                info = zipfile.ZipInfo(f"{k}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                # speckle hardly compresses (deflate keeps 83% of a frame at any level and
                # takes 1.1-1.4 ms per 256 x 256 frame): the images are stored as they are
                info.compress_type = (zipfile.ZIP_STORED if k == "images"
                                      else zipfile.ZIP_DEFLATED)
                with zf.open(info, "w", force_zip64=True) as f:
                    np.lib.format.write_array(f, np.asanyarray(arrays[k]), allow_pickle=False)
        os.chmod(tmp, 0o644)  # mkstemp makes it private
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def _check_member(zf: zipfile.ZipFile, key: str, src: str) -> None:
    """The array header of ``key`` must parse and describe exactly the bytes the archive
    holds for it, so a damaged or forged header is an error before anything is allocated."""
    try:
        info = zf.getinfo(f"{key}.npy")
        with zf.open(info) as fh:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
            else:
                shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
            header_len = fh.tell()
    except Exception as exc:  # a damaged header raises whatever its parser meets
        raise _err(src, key, f"has a damaged array header ({type(exc).__name__}: {exc})"
                   ) from None
    if dtype.hasobject:
        raise _err(src, key, "holds Python objects; a sequence file holds plain arrays")
    need = math.prod(int(n) for n in shape) * dtype.itemsize
    if need != info.file_size - header_len:
        raise _err(src, key, f"its header describes {shape} {dtype} ({need} bytes) but the "
                   f"file holds {info.file_size - header_len} bytes for it")
    # the sizes in the zip directory can be forged too: what a member's compressed bytes can
    # hold bounds what numpy allocates before it reads them (deflate inflates at most
    # ~1032:1, a stored member not at all)
    ratio = {zipfile.ZIP_DEFLATED: _MAX_INFLATION, zipfile.ZIP_STORED: 1}.get(
        info.compress_type)
    if ratio is not None and need > info.compress_size * ratio + 1024:
        raise _err(src, key, f"its header describes {need} bytes, more than its "
                   f"{info.compress_size} compressed bytes can hold; damaged file?")
    if key == "images" and len(shape) in (3, 4):
        frame = math.prod(int(n) for n in shape[1:])
        most = MAX_FRAME_PIXELS[len(shape) - 1]
        if frame > most:
            raise _err(src, key, f"its header describes frames of {tuple(shape[1:])} = "
                       f"{frame:.3g} pixels, more than any ultrasound frame ({most})")


def load_sequence(path: str | os.PathLike) -> Sequence:
    """Read and validate a sequence file; a bad file raises :class:`SequenceFileError`."""
    path = Path(path)
    src = str(path)
    if not path.exists():
        raise FileNotFoundError(f"{src}: no such sequence file")
    try:
        data = np.load(path, allow_pickle=False)
        files = set(data.files)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise SequenceFileError(f"{src}: not a readable .npz file ({exc})") from None
    with data:
        missing = [k for k in REQUIRED if k not in files]
        if missing:
            raise _err(src, missing[0], "is missing")
        kw = {}
        for k in REQUIRED + OPTIONAL:
            if k not in files:
                continue
            _check_member(data.zip, k, src)
            try:
                kw[k] = data[k]
            except (ValueError, zipfile.BadZipFile, OSError, EOFError, zlib.error,
                    MemoryError) as exc:
                raise _err(src, k, f"cannot be read ({exc})") from None
    try:
        kw["modality"] = str(kw["modality"][()])
        kw["dynamic_range_db"] = float(kw["dynamic_range_db"])
        kw["meta"] = json.loads(str(kw["meta"][()]))
    except (ValueError, TypeError, json.JSONDecodeError, RecursionError) as exc:
        raise SequenceFileError(
            f"{src}: scalar keys modality/dynamic_range_db/meta: {exc}") from None
    return validate_sequence(Sequence(**kw), source=src)
