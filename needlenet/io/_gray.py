"""Pixels of any type as the uint8 gray frames the trackers read."""

from __future__ import annotations

import numpy as np

from ._colour_marks import fill_colour_marks

__all__ = ["to_gray_uint8"]


def to_gray_uint8(arr: np.ndarray, channels: int) -> tuple[np.ndarray, tuple | None, list]:
    """Colour to gray (ITU-R BT.601 luma of R, G, B; 8-bit colour's drawn marks filled in,
    :mod:`._colour_marks`), other types scaled to 0..255; returns
    (frames, the scaled intensity range or None, notes for the user).

    Scaling maps the finite range to 0..255, except that values further beyond the 0.01-99.99
    percentile range than that range is wide (a dead or hot pixel, a 1e6 in float data) are
    clipped instead of compressing every frame to black; pixels that are not finite are shown
    black. Either is reported in the notes."""
    notes: list[str] = []
    if channels >= 3:
        a = arr[..., :3].astype(np.float32)
        luma = a[..., 0] * 0.299 + a[..., 1] * 0.587 + a[..., 2] * 0.114
        if luma.size and float(luma.max()) <= 255.0 and float(luma.min()) >= 0.0:
            gray = np.clip(np.rint(luma), 0, 255).astype(np.uint8)
            if arr.dtype == np.uint8:
                for i in range(len(gray)):
                    gray[i] = fill_colour_marks(gray[i], arr[i])
            return gray, None, notes
        arr = luma
    elif channels == 2:
        arr = arr[..., 0]
    if arr.dtype == np.uint8:
        return np.ascontiguousarray(arr), None, notes
    a = arr.astype(np.float64)
    finite = np.isfinite(a)
    if not finite.all():
        bad = ~finite
        frames = np.flatnonzero(bad.reshape(len(a), -1).any(axis=1))
        notes.append(f"{int(bad.sum())} pixels in {len(frames)} frames (first: frame "
                     f"{int(frames[0])}) are not finite numbers; they are shown black")
    vals = a[finite]
    if not vals.size:
        return np.zeros(a.shape, np.uint8), (0.0, 0.0), notes
    lo, hi = float(vals.min()), float(vals.max())
    p_lo, p_hi = (float(v) for v in np.percentile(vals, [0.01, 99.99]))
    width = p_hi - p_lo
    if width > 0 and (hi - p_hi > width or p_lo - lo > width):
        inlier = (vals >= p_lo - width) & (vals <= p_hi + width)
        lo, hi = float(vals[inlier].min()), float(vals[inlier].max())
        notes.append(f"{int(vals.size - inlier.sum())} pixels lie far outside the "
                     f"recording's intensity range ({lo:.6g} to {hi:.6g}); they are clipped "
                     "to it")
    a = np.where(finite, a, lo)
    if hi <= lo:
        return np.zeros(a.shape, np.uint8), (lo, hi), notes
    return np.rint((np.clip(a, lo, hi) - lo) * (255.0 / (hi - lo))).astype(np.uint8), (lo, hi), \
        notes
