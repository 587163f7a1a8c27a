"""Pixel-level measurements of a needle's cross-section in an axial slice, shared by Carriere's
tracker and the servo loop's image measurement: sub-pixel peaks, the upper edge of the echo,
the covariance of a template-match peak."""

from __future__ import annotations

import numpy as np

__all__ = ["below_top_edge", "bilinear", "compact_spots", "is_compact", "local_peak", "odd_px",
           "peak_covariance", "subpixel_peak"]

MAX_SPOTS = 64  # the strongest local maxima a slice is searched for spots


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


def local_peak(F: np.ndarray, idx: tuple[int, int], half_px) -> np.ndarray:
    """The sub-pixel maximum (row, col) of ``F`` within ``half_px`` (rows, cols) of ``idx``.

    A learned map is a likelihood of where the wall lies, drawn at the needle's scale; its
    mode is the estimate. The map smoothed again at the needle's radius (which finds the spot
    and scores it) has its maximum pulled towards whatever the map marks beside the wall: the
    comet tail below it."""
    h = np.maximum(np.asarray(half_px, dtype=int), 1)
    lo = np.maximum(np.asarray(idx) - h, 0)
    hi = np.minimum(np.asarray(idx) + h + 1, F.shape)
    win = F[lo[0]:hi[0], lo[1]:hi[1]]
    j = np.unravel_index(int(np.argmax(win)), win.shape)
    peak = (int(lo[0] + j[0]), int(lo[1] + j[1]))
    return np.asarray(peak, dtype=float) + subpixel_peak(F, peak)


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


def compact_spots(S: np.ndarray, med: float, scale: float, spacing, lateral_mm: float,
                  compact: float, separation_mm: float) -> tuple[list[tuple[int, int]],
                                                                  np.ndarray]:
    """The compact spots of a smoothed feature map ``S`` (rows depth, columns lateral), the
    strongest first, each farther than ``separation_mm`` from a stronger one; and the robust
    score map z = (S - ``med``) / ``scale``.

    A spot is a local maximum with z > 0 whose score ``lateral_mm`` either side of it (the
    larger of the two sides inside the map) is below ``compact`` times its own: a needle cut
    across is a spot the needle's width widened by the lateral beam, and a tissue interface
    cut across is a line along which the map stays high. Among the ``MAX_SPOTS`` strongest
    compact maxima."""
    from scipy import ndimage

    sp = np.asarray(spacing, dtype=float)
    z = (np.asarray(S, dtype=np.float64) - med) / scale
    size = tuple(max(3, 2 * int(round(0.5 * separation_mm / float(v))) + 1) for v in sp)
    peaks = (S == ndimage.maximum_filter(S, size=size)) & (z > 0)
    rr, cc = np.nonzero(peaks)
    k = max(int(round(lateral_mm / float(sp[1]))), 1)
    w = S.shape[1]
    left = np.where(cc - k >= 0, z[rr, np.clip(cc - k, 0, w - 1)], -np.inf)
    right = np.where(cc + k < w, z[rr, np.clip(cc + k, 0, w - 1)], -np.inf)
    keep = np.maximum(left, right) < compact * z[rr, cc]
    rr, cc = rr[keep], cc[keep]
    top = np.argsort(-z[rr, cc], kind="stable")[:MAX_SPOTS]
    rr, cc = rr[top], cc[top]
    spots: list[tuple[int, int]] = []
    taken = np.zeros((0, 2))
    for r, c in zip(rr, cc, strict=True):  # at most MAX_SPOTS: non-maximum suppression
        here = np.array([r, c], float) * sp
        if taken.size and np.min(np.hypot(*(taken - here).T)) <= separation_mm:
            continue
        spots.append((int(r), int(c)))
        taken = np.vstack([taken, here])
    return spots, z


def is_compact(S: np.ndarray, center_rc, med: float, scale: float, spacing, lateral_mm: float,
               compact: float) -> bool:
    """Whether the smoothed map ``S`` at ``center_rc`` (row, col; sub-pixel) is a compact spot
    as :func:`compact_spots` reads one: its score ``lateral_mm`` either side (the larger side
    inside the map) below ``compact`` times its own."""
    r, c = (float(v) for v in center_rc)
    k = lateral_mm / float(np.asarray(spacing, dtype=float)[1])
    here = (bilinear(S, np.array([r, c])) - med) / scale
    sides = [(bilinear(S, np.array([r, c + d])) - med) / scale
             for d in (-k, k) if 0.0 <= c + d <= S.shape[1] - 1]
    return not sides or max(sides) < compact * here
