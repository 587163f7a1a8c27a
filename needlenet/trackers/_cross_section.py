"""Pixel-level measurements of a needle's cross-section in an axial slice, shared by Carriere's
tracker and the servo loop's image measurement: sub-pixel peaks, the upper edge of the echo,
the covariance of a template-match peak."""

from __future__ import annotations

import numpy as np

__all__ = ["below_top_edge", "bilinear", "odd_px", "peak_covariance", "subpixel_peak"]


def odd_px(length_mm: float, spacing_mm: float) -> int:
    """The odd number of pixels nearest ``length_mm`` (at least 3): a window with a centre."""
    n = max(int(round(length_mm / spacing_mm)), 3)
    return n if n % 2 else n + 1


def bilinear(a: np.ndarray, rc: np.ndarray) -> float:
    """Bilinear value of ``a`` at (row, col) ``rc``, clamped to the array."""
    r = float(np.clip(rc[0], 0, a.shape[0] - 1))
    c = float(np.clip(rc[1], 0, a.shape[1] - 1))
    r0, c0 = min(int(r), a.shape[0] - 2), min(int(c), a.shape[1] - 2)
    fr, fc = r - r0, c - c0
    q = a[r0:r0 + 2, c0:c0 + 2]
    return float((1 - fr) * ((1 - fc) * q[0, 0] + fc * q[0, 1])
                 + fr * ((1 - fc) * q[1, 0] + fc * q[1, 1]))


def subpixel_peak(S: np.ndarray, idx: tuple[int, int]) -> np.ndarray:
    """Parabolic vertex offset of a 2-D maximum along each axis (0 at a border)."""
    out = np.zeros(2)
    for ax in range(2):
        if 0 < idx[ax] < S.shape[ax] - 1:
            lo = list(idx)
            hi = list(idx)
            lo[ax] -= 1
            hi[ax] += 1
            a, b, c = float(S[tuple(lo)]), float(S[idx]), float(S[tuple(hi)])
            den = a - 2 * b + c
            if den < 0:
                out[ax] = float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))
    return out


def below_top_edge(F: np.ndarray, center: np.ndarray, background: float,
                    radius_px: float) -> np.ndarray:
    """One needle radius below the upper edge of the echo above ``center`` (row, col).

    The echo of an axial needle is its upper wall followed by a reverberation (comet) tail;
    where the maximum of the smoothed map falls depends on the contrast. Along the column
    through ``center`` (the mean of three columns), the brightest sample at or above it is
    taken as the wall; the edge is where the column, going up from there, falls half way
    down to ``background`` (linear interpolation). ``center`` is returned unchanged when no
    edge lies within four radii, or when the column has no echo above ``background`` (a flat
    column, e.g. at the image's edge: no edge to find, and no division by a zero step).
    """
    r0 = min(max(int(round(center[0])), 0), F.shape[0] - 1)
    c = min(max(int(round(center[1])), 1), F.shape[1] - 2)
    top = max(r0 - int(np.ceil(4 * radius_px)), 0)
    col = F[top:r0 + 1, c - 1:c + 2].mean(axis=1)[::-1]  # upwards from the centre
    k0 = int(np.argmax(col))
    if not float(col[k0]) > background:  # no echo above the background (a flat column)
        return np.asarray(center, dtype=float)
    level = background + 0.5 * (float(col[k0]) - background)
    below = np.flatnonzero(col[k0 + 1:] < level)
    if below.size == 0:
        return np.asarray(center, dtype=float)
    k = k0 + 1 + int(below[0])  # col[k - 1] >= level > col[k], so the step is > 0
    frac = (float(col[k - 1]) - level) / (float(col[k - 1]) - float(col[k]))
    edge = r0 - (k - 1 + frac)
    return np.array([edge + radius_px, float(center[1])])


def peak_covariance(s: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """(x, z) covariance in mm^2 from the curvature of the NCC peak of the score map ``s``:
    per axis (1 - peak) / |second difference| px^2, at least 1/12 px^2 (a pixel's
    quantisation)."""
    i, j = np.unravel_index(int(np.argmax(s)), s.shape)
    var = np.full(2, 1.0 / 12.0)  # (row, col)
    for ax, (lo, hi) in enumerate((((i - 1, j), (i + 1, j)), ((i, j - 1), (i, j + 1)))):
        if min(lo) >= 0 and hi[0] < s.shape[0] and hi[1] < s.shape[1]:
            d2 = s[lo] - 2 * s[i, j] + s[hi]
            if d2 < 0:
                var[ax] = max((1.0 - s[i, j]) / -d2, 1.0 / 12.0)
    var_mm = var * spacing**2
    return np.diag([var_mm[1], var_mm[0]])  # (x, z)
