"""Sane physical ranges for what a recording says about itself, checked at the boundary before
anything is allocated or tracked: a file that claims 10^15 pixels, a 1e-6 mm pixel or a frame
rate of 1e300 gets one error naming the file and the field, not a MemoryError, a hang inside
OpenCV or a Kalman filter that divides by zero.

The ranges hold every ultrasound recording: pixels from 5 um (high-frequency microscopy
probes) to 5 mm (a heavily decimated 3D volume), images at most 500 mm across, frame rates
from one frame in 10 s to 1,000 frames/s (ultrafast plane-wave imaging is displayed slower)."""

from __future__ import annotations

import math
import os

import numpy as np

from ._errors import RecordingError

__all__ = ["MAX_GAP_S", "SPACING_RANGE_MM", "MAX_EXTENT_MM", "FRAME_RATE_RANGE_HZ",
           "SPEED_RANGE_MM_S",
           "memory_budget_bytes", "check_allocation", "check_spacing", "check_extent",
           "check_fps", "check_frame_times", "check_meta_numbers", "check_origin",
           "check_transforms", "MAX_POSITION_MM", "MAX_FRAME_PIXELS", "check_frame_shape"]

SPACING_RANGE_MM = (0.005, 5.0)
MAX_EXTENT_MM = 500.0
MAX_POSITION_MM = 1e5  # an image origin or a transform's translation: 100 m from the reference
# the largest frame: 4096 x 4096 pixels (beyond any scanner's, and synth's own limit) or 512^3
# voxels; a header claiming more is damaged, and is refused before its pixels are read
MAX_FRAME_PIXELS = {2: 1 << 24, 3: 1 << 27}
FRAME_RATE_RANGE_HZ = (0.1, 1000.0)
SPEED_RANGE_MM_S = (0.0, 1000.0)  # an insertion speed a robot reports
MAX_GAP_S = 3600.0  # the longest pause between two frames of one recording
DEPTH_RANGE_MM = (0.0, 1000.0)  # a planned depth (Carriere's rotation depth D)


def memory_budget_bytes() -> int:
    """The most one recording's pixels may take: half the machine's physical memory (the
    trackers and the network need the rest)."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        total = 8 << 30
    return int(total) // 2


def check_allocation(shape, itemsize: int, src: str, field: str) -> int:
    """Bytes that ``shape`` of ``itemsize``-byte elements needs (exact, no overflow); raises
    when they exceed :func:`memory_budget_bytes`."""
    n = math.prod(int(s) for s in shape) * int(itemsize)
    budget = memory_budget_bytes()
    if n > budget:
        raise RecordingError(f"{src}: {field} describes {n / 2**30:.3g} GiB of pixels "
                             f"{tuple(int(s) for s in shape)}, more than this machine can hold "
                             f"({budget / 2**30:.3g} GiB); damaged header?")
    return n


def check_frame_shape(shape, src: str, field: str) -> None:
    """One frame's shape (2 or 3 axes) within :data:`MAX_FRAME_PIXELS`."""
    shape = tuple(int(s) for s in shape)
    most = MAX_FRAME_PIXELS.get(len(shape), MAX_FRAME_PIXELS[3])
    n = math.prod(shape)
    if n > most:
        raise RecordingError(f"{src}: {field} describes frames of {shape} = {n:.3g} pixels, "
                             f"more than any ultrasound frame ({most}); damaged header?")


def check_spacing(spacing_mm, src: str, field: str) -> np.ndarray:
    """Pixel spacing (mm per pixel, any number of axes) within :data:`SPACING_RANGE_MM`."""
    sp = np.atleast_1d(np.asarray(spacing_mm, float))
    lo, hi = SPACING_RANGE_MM
    if not np.all(np.isfinite(sp)) or np.any(sp < lo) or np.any(sp > hi):
        raise RecordingError(f"{src}: {field} = {sp.tolist()} mm per pixel is outside "
                             f"{lo}-{hi} mm; give the right one with --spacing MM")
    return sp


def check_extent(shape, spacing_mm, src: str, field: str) -> None:
    """Each image axis spans at most :data:`MAX_EXTENT_MM` (pixels times the spacing)."""
    ext = np.asarray(shape, float) * np.asarray(spacing_mm, float)
    if np.any(ext > MAX_EXTENT_MM):
        raise RecordingError(
            f"{src}: frames of {tuple(int(s) for s in shape)} pixels at {field} "
            f"{np.asarray(spacing_mm, float).tolist()} mm span "
            f"{[round(float(e), 3) for e in ext]} mm; an ultrasound image spans at most "
            f"{MAX_EXTENT_MM:g} mm: check the spacing (--spacing MM)")


def check_fps(fps: float, src: str, field: str = "--fps") -> float:
    """A frame rate within :data:`FRAME_RATE_RANGE_HZ`."""
    lo, hi = FRAME_RATE_RANGE_HZ
    try:
        f = float(fps)
    except (TypeError, ValueError):
        raise RecordingError(f"{src}: {field} = {fps!r} is not a number") from None
    if not (lo <= f <= hi):
        raise RecordingError(f"{src}: {field} = {fps!r} frames/s is outside {lo}-{hi}")
    return f


def check_frame_times(ts: np.ndarray, src: str, field: str) -> None:
    """Frame times whose typical interval (the median of the positive ones) is a frame rate
    within :data:`FRAME_RATE_RANGE_HZ` (repeated times are allowed: a frame grabber may stamp
    two frames alike), with no pause between two frames longer than :data:`MAX_GAP_S`."""
    d = np.diff(np.asarray(ts, float))
    if d.size and float(d.max()) > MAX_GAP_S:
        k = int(np.argmax(d))
        raise RecordingError(f"{src}: {field}: frame {k + 1} comes {float(d[k]):.3g} s after "
                             f"frame {k}, more than {MAX_GAP_S:g} s (one recording); damaged "
                             "frame times? pass the frame rate with --fps N")
    d = d[d > 0]
    if not d.size:
        return
    rate = 1.0 / float(np.median(d))
    lo, hi = FRAME_RATE_RANGE_HZ
    if not (lo <= rate <= hi):
        raise RecordingError(f"{src}: {field}: frames {float(np.median(d)):.3g} s apart "
                             f"({rate:.3g} frames/s), outside {lo}-{hi} frames/s; pass the "
                             "frame rate with --fps N")


_META_NUMBERS = {("params", "speed_mm_s"): SPEED_RANGE_MM_S,
                 ("draw", "speed_mm_s"): SPEED_RANGE_MM_S,
                 ("params", "rotation_depth_mm"): DEPTH_RANGE_MM}


def check_meta_numbers(meta: dict, src: str) -> None:
    """The entries of a sequence's ``meta`` that trackers read (``params``/``draw``: the
    insertion speed, the planned rotation depth) are objects holding finite numbers in range."""
    for section in {s for s, _ in _META_NUMBERS}:
        if section in meta and not isinstance(meta[section], dict):
            raise RecordingError(f"{src}: meta field {section!r} must be a JSON object, got "
                                 f"{type(meta[section]).__name__} {meta[section]!r:.60}")
    for (section, key), (lo, hi) in _META_NUMBERS.items():
        v = meta.get(section, {}).get(key)
        if v is None:
            continue
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) \
            and lo <= v <= hi
        if not ok:
            raise RecordingError(f"{src}: meta field {section}.{key} = {v!r:.60} must be a "
                                 f"number in {lo}-{hi}")


def check_origin(origin_mm, src: str, field: str) -> np.ndarray:
    """An image origin: finite and within :data:`MAX_POSITION_MM` of the reference (a file
    that puts its first pixel 1e308 mm away would overflow every position computed from
    it)."""
    o = np.atleast_1d(np.asarray(origin_mm, float))
    if not np.all(np.isfinite(o)) or np.any(np.abs(o) > MAX_POSITION_MM):
        raise RecordingError(f"{src}: {field} = {o.tolist()} mm is not finite or lies more "
                             f"than {MAX_POSITION_MM:g} mm from the reference")
    return o


def check_transforms(mats: np.ndarray, ok: np.ndarray, src: str, field: str) -> None:
    """4x4 transforms (``(T, 4, 4)``) of the frames marked ``ok``: finite, last row
    ``0 0 0 1``, a rotation part that is invertible and of moderate scale (singular values
    1e-3 to 1e3: rigid, or scaled as an ImageToProbe calibration is) and a translation within
    :data:`MAX_POSITION_MM`. A frame at fault is named (``field`` holds ``NNNN`` for its
    number)."""
    mats = np.asarray(mats, float)
    for i in np.flatnonzero(np.asarray(ok, bool)):
        m = mats[i]
        name = field.replace("NNNN", f"{int(i):04d}")
        if not np.all(np.isfinite(m)):
            raise RecordingError(f"{src}: {name} is not finite")
        if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
            raise RecordingError(f"{src}: {name}: the last row {m[3].tolist()} must be 0 0 0 1 "
                                 "(a rigid or affine transform)")
        sv = np.linalg.svd(m[:3, :3], compute_uv=False)
        if not (sv.min() >= 1e-3 and sv.max() <= 1e3):
            raise RecordingError(f"{src}: {name}: the rotation part is singular or scales by "
                                 f"{sv.max():.3g} (singular values {sv.min():.3g} to "
                                 f"{sv.max():.3g}); expected a rigid transform")
        if np.any(np.abs(m[:3, 3]) > MAX_POSITION_MM):
            raise RecordingError(f"{src}: {name}: translation {m[:3, 3].tolist()} mm lies more "
                                 f"than {MAX_POSITION_MM:g} mm from the reference")
