"""Geometry of the `line` tracker's segments against the frame: whether a segment runs on a
line, which of its ends is the entry, and how far a point lies from the edge of the imaged
region (:mod:`._margins`)."""

from __future__ import annotations

import numba
import numpy as np

from .._sampling import remap_points
from ..backends import NeedleLine
from ..features import Frame
from ._margins import imaged_region

__all__ = ["on_line", "behind_on_line", "entry_to_tip", "sample_grid", "imaged_region",
           "distance_to_edge", "AROUND"]


def off_line_mm(point: np.ndarray, line_point: np.ndarray, direction: np.ndarray) -> float:
    """Distance (mm) of ``point`` from the line through ``line_point`` along the unit
    ``direction``."""
    d = np.asarray(point, float) - np.asarray(line_point, float)
    return float(abs(d[0] * direction[1] - d[1] * direction[0]))


def on_line(seg: NeedleLine, point: np.ndarray, direction: np.ndarray, window_deg: float,
             window_mm: float) -> bool:
    """Whether ``seg`` runs within ``window_deg`` of the line (``point``, ``direction``) with
    its midpoint within ``window_mm`` of it."""
    cos = abs(float(seg.direction @ direction))
    mid = 0.5 * (seg.start_mm + seg.end_mm)
    return cos >= np.cos(np.deg2rad(window_deg)) and off_line_mm(mid, point, direction) <= \
        window_mm


def behind_on_line(seg: NeedleLine, ref: NeedleLine, direction: np.ndarray,
                   window_mm: float) -> bool:
    """Whether both ends of ``seg`` lie within ``window_mm`` of ``ref``'s line and ``seg``
    reaches no further along ``direction`` than ``ref`` does: a piece of the same straight
    needle behind the end ``ref`` shows (its angle, from a short piece, is not compared)."""
    d = np.asarray(direction, float)
    ends = (seg.start_mm, seg.end_mm)
    if max(off_line_mm(e, ref.start_mm, ref.direction) for e in ends) > window_mm:
        return False
    return max(float(e @ d) for e in ends) <= max(float(ref.start_mm @ d),
                                                  float(ref.end_mm @ d)) + window_mm


def entry_to_tip(seg: NeedleLine, frame: Frame, min_angle_deg: float,
                  valid: np.ndarray) -> NeedleLine:
    """``seg`` from its entry end to its tip end: the deeper end is the tip of a segment that
    descends by ``min_angle_deg`` or more; else the entry is the end nearer the edge of the
    imaged region."""
    d = seg.direction
    if abs(d[1]) >= np.sin(np.deg2rad(min_angle_deg)):
        return seg if d[1] > 0 else seg.reversed()
    a = distance_to_edge(valid, frame, seg.start_mm, -d)
    b = distance_to_edge(valid, frame, seg.end_mm, d)
    return seg if a <= b else seg.reversed()


def sample_grid(values: np.ndarray, grid, pts: np.ndarray) -> np.ndarray:
    """Bilinear samples of a map on ``grid`` at points (N, 2) in mm; 0 outside."""
    idx = grid.points_to_index(pts)  # (N, 2) as (row, col)
    return remap_points(values, idx[:, 1], idx[:, 0])


AROUND = np.stack([np.cos(np.linspace(0, 2 * np.pi, 24, endpoint=False)),
                    np.sin(np.linspace(0, 2 * np.pi, 24, endpoint=False))], -1)


def distance_to_edge(valid: np.ndarray, frame: Frame, start: np.ndarray,
                      direction: np.ndarray, step_mm: float = 0.2,
                      max_mm: float = 200.0) -> float:
    """How far (mm) from ``start`` the imaged region ends along ``direction`` (2,), or along
    the nearest of several directions (D, 2): the first of the samples every ``step_mm`` at
    which a direction's nearest pixel lies outside ``valid`` or the frame (``max_mm`` when
    none does)."""
    dirs = np.ascontiguousarray(np.asarray(direction, float).reshape(-1, 2))
    s = np.arange(0.0, max_mm, step_mm)
    g = frame.grid
    k = _first_outside(np.asarray(valid, bool), np.asarray(start, float), dirs, s,
                       float(g.origin_mm[0]), float(g.origin_mm[1]),
                       float(g.spacing_mm[0]), float(g.spacing_mm[1]))
    return float(s[k]) if k < s.size else float(max_mm)


@numba.njit(cache=True, nogil=True)
def _first_outside(valid, start, dirs, s, oz, ox, dz, dx):  # pragma: no cover - compiled
    """The least sample index j over the directions at which the point start + s[j] * d
    rounds (half to even, as np.rint) to a pixel outside ``valid`` or the frame; s.size
    when none does. Each direction is marched only as far as the best found so far."""
    h, w = valid.shape
    best = s.size
    for a in range(dirs.shape[0]):
        for j in range(best):
            x = start[0] + s[j] * dirs[a, 0]
            z = start[1] + s[j] * dirs[a, 1]
            r = np.rint((z - oz) / dz)
            c = np.rint((x - ox) / dx)
            if not (0 <= r < h and 0 <= c < w) or not valid[int(r), int(c)]:
                best = j
                break
    return best
