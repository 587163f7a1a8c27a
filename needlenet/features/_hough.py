"""The "DF" baseline of Mathiassen 2017 (section III-C): Ding and Fenster's Hough-transform
needle segmentation (Med. Phys. 30(8), 2003) as Mathiassen et al. implemented it.

1. Segment the image by a threshold (:func:`segment`).
2. Hough transform of the segmented pixels with a coarse-fine search over the angle, limited to
   +-5 degrees of the expected insertion angle; the axis with the highest Hough value wins
   (:func:`hough_axis`, with :func:`skimage.transform.hough_line`), placed in the middle of
   the segmented band (:func:`peak_centre`).
3. Read the segmented image along that axis from the entry, close its gaps with a morphological
   close of a 21 px structuring element, and put the tip at the first gap
   (:func:`first_gap_tip`).

Angles are insertion angles to the skin in the probe frame (mm), the needle entering at the
top right and going down-left as in :mod:`._mathiassen`; they are converted to the image's
pixel axes through the grid, so anisotropic spacings work.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from skimage.transform import hough_line

from synth import Grid

__all__ = ["DFParams", "DFResult", "segment", "hough_axis", "peak_centre", "first_gap_tip",
           "ding_fenster"]


@dataclass(frozen=True)
class DFParams:
    """``threshold_sd``: the segmentation keeps pixels brighter than mean + k sd of the image
    (ours; Ding and Fenster threshold adaptively and Mathiassen et al. do not give theirs).
    ``half_range_deg``: +-5 degrees around the expected angle (section III-C); without an
    expected angle ``full_range_deg`` is searched, as Ding and Fenster search all angles.
    ``coarse_step_deg`` 1 degree, then ``fine_step_deg`` 0.1 degree within
    +-``fine_half_range_deg`` of the coarse best (ours: one coarse step). ``close_mm``: the
    closing's structuring element, 21 px of 0.10 mm (section III-C). ``min_run_mm``: the
    shortest run of needle pixels accepted as a needle (ours)."""

    threshold_sd: float = 2.0
    half_range_deg: float = 5.0
    full_range_deg: tuple[float, float] = (20.0, 70.0)
    coarse_step_deg: float = 1.0
    fine_step_deg: float = 0.1
    fine_half_range_deg: float = 1.0
    close_mm: float = 2.1
    min_run_mm: float = 2.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.threshold_sd):
            raise ValueError(f"DFParams.threshold_sd must be finite, got {self.threshold_sd}")
        for name in ("half_range_deg", "coarse_step_deg", "fine_step_deg",
                     "fine_half_range_deg"):
            v = getattr(self, name)
            if not 0.0 < v <= 90.0:
                raise ValueError(f"DFParams.{name} must lie in (0, 90] degrees, got {v}")
        for name in ("close_mm", "min_run_mm"):
            v = getattr(self, name)
            if not 0.0 < v <= 100.0:
                raise ValueError(f"DFParams.{name} must lie in (0, 100] mm, got {v}")
        lo, hi = self.full_range_deg
        if not 0.0 <= lo < hi <= 90.0:
            raise ValueError(f"DFParams.full_range_deg must lie in [0, 90], got "
                             f"{self.full_range_deg}")


@dataclass(frozen=True)
class DFResult:
    """False-valued when no needle was found (``reason`` says why).

    ``theta_deg`` insertion angle; ``direction`` unit (x, z) from the entry to the tip;
    ``entry_mm`` where the axis enters the image; ``tip_mm`` the first gap; ``votes`` the Hough
    value of the axis; ``profile`` the closed segmentation along the axis from the entry."""

    found: bool
    reason: str = ""
    theta_deg: float = float("nan")
    direction: np.ndarray | None = None
    entry_mm: np.ndarray | None = None
    tip_mm: np.ndarray | None = None
    votes: int = 0
    profile: np.ndarray | None = field(default=None, repr=False)

    def __bool__(self) -> bool:
        return self.found


def segment(image: np.ndarray, params: DFParams | None = None) -> np.ndarray:
    """Boolean mask of the pixels brighter than mean + ``threshold_sd`` sd."""
    p = DFParams() if params is None else params
    im = np.asarray(image, dtype=np.float32)
    mu, sd = float(im.mean()), float(im.std())
    return im > mu + p.threshold_sd * sd


def _pixel_direction(theta_deg, grid: Grid) -> np.ndarray:
    """Unit (col, row) direction of the axis at insertion angle ``theta_deg`` (mm space)."""
    t = np.deg2rad(np.asarray(theta_deg, dtype=float))
    dz, dx = grid.spacing_mm
    d = np.stack([-np.cos(t) / dx, np.sin(t) / dz], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _normal_angles(theta_deg, grid: Grid) -> np.ndarray:
    """skimage's line x cos(phi) + y sin(phi) = rho (x = col, y = row): phi of each axis."""
    d = _pixel_direction(theta_deg, grid)
    return np.arctan2(-d[..., 0], d[..., 1])  # (cos phi, sin phi) = (d_row, -d_col)


def hough_axis(mask: np.ndarray, grid: Grid, thetas_deg) -> tuple[float, float, int]:
    """The highest Hough value over the given insertion angles: ``(theta_deg, rho_px, votes)``
    with the line {(col, row): col cos(phi) + row sin(phi) = rho}."""
    thetas = np.atleast_1d(np.asarray(thetas_deg, dtype=float))
    acc, _, dists = hough_line(mask, theta=_normal_angles(thetas, grid))
    i, j = np.unravel_index(int(np.argmax(acc)), acc.shape)
    return float(thetas[j]), peak_centre(acc[:, j], dists), int(acc[i, j])


def peak_centre(votes: np.ndarray, dists: np.ndarray) -> float:
    """The axis of a segmented band: every line through a band several pixels thick and
    parallel to it gets about the same vote, so the accumulator's maximum is a plateau across
    rho, and its first bin is the band's edge. The centre of the plateau is taken: the
    vote-weighted mean rho of the run above half the maximum that holds it, read on the votes
    summed over pairs of neighbouring bins (a digital line's pixels alternate between
    neighbouring rho bins)."""
    v = np.asarray(votes, dtype=float)
    smooth = np.convolve(v, np.ones(2), mode="same")
    k = int(np.argmax(smooth))
    below = np.flatnonzero(smooth < 0.5 * smooth[k])
    lo = int(below[below < k].max()) + 1 if np.any(below < k) else 0
    hi = int(below[below > k].min()) - 1 if np.any(below > k) else v.size - 1
    lo = max(lo - 1, 0)  # smooth[i] sums bins i - 1 and i
    w = v[lo:hi + 1]
    return float((w * dists[lo:hi + 1]).sum() / w.sum()) if w.sum() > 0 else float(dists[k])


def _line_samples(grid: Grid, theta_deg: float, rho: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel positions (col, row) every pixel along the line inside the image, from the entry
    end (where it comes in at the top or right) towards the tip."""
    d = _pixel_direction(theta_deg, grid)
    phi = float(_normal_angles(theta_deg, grid))
    foot = rho * np.array([np.cos(phi), np.sin(phi)])
    hi = np.array([grid.shape[1] - 1, grid.shape[0] - 1], dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (0.0 - foot) / d, (hi - foot) / d
    t_lo = np.max(np.where(d != 0, np.minimum(t1, t2), -np.inf))
    t_hi = np.min(np.where(d != 0, np.maximum(t1, t2), np.inf))
    if not t_hi > t_lo:
        return np.zeros((0, 2)), d
    t = np.arange(np.ceil(t_lo), np.floor(t_hi) + 1)
    return foot[None] + t[:, None] * d[None], d


def first_gap_tip(values: np.ndarray, close_px: int) -> tuple[int, int] | None:
    """Close the gaps of a boolean profile with a ``close_px`` structuring element and return
    ``(start, end)`` of its first run of True: the tip is at ``end``, the first gap. None if
    the profile holds no True."""
    v = np.asarray(values, dtype=bool)
    if not v.any():
        return None
    k = max(1, int(close_px))
    # pad so that the closing does not erode the ends of the profile
    closed = ndimage.binary_closing(np.pad(v, k), structure=np.ones(k, dtype=bool))[k:-k]
    start = int(np.argmax(closed))
    gaps = np.flatnonzero(~closed[start:])
    end = start + (int(gaps[0]) - 1 if gaps.size else closed.size - 1 - start)
    return start, end


def ding_fenster(image: np.ndarray, grid: Grid, expected_angle_deg: float | None = None,
                 params: DFParams | None = None, mask: np.ndarray | None = None) -> DFResult:
    """Needle axis and tip of one image by the DF method (section III-C)."""
    p = DFParams() if params is None else params
    if grid.ndim != 2:
        raise ValueError(f"DF works on 2-D images, got a {grid.ndim}-D grid")
    m = segment(image, p) if mask is None else np.asarray(mask, dtype=bool)
    if not m.any():
        return DFResult(False, "the segmentation is empty")
    if expected_angle_deg is None:
        lo, hi = p.full_range_deg
    else:
        lo, hi = expected_angle_deg - p.half_range_deg, expected_angle_deg + p.half_range_deg
    coarse = np.arange(lo, hi + 1e-9, p.coarse_step_deg)
    theta, _, _ = hough_axis(m, grid, coarse)
    n = int(round(p.fine_half_range_deg / p.fine_step_deg))
    fine = theta + p.fine_step_deg * np.arange(-n, n + 1)
    fine = fine[(fine >= lo - 1e-9) & (fine <= hi + 1e-9)]  # stay within the searched range
    theta, rho, votes = hough_axis(m, grid, fine)
    pts, _ = _line_samples(grid, theta, rho)
    if len(pts) < 2:
        return DFResult(False, "the axis misses the image", theta, votes=votes)
    idx = np.rint(pts).astype(int)
    profile = m[idx[:, 1], idx[:, 0]]
    step = float(min(grid.spacing_mm))
    close_px = max(1, int(round(p.close_mm / step))) | 1
    run = first_gap_tip(profile, close_px)
    direction = np.array([-np.cos(np.deg2rad(theta)), np.sin(np.deg2rad(theta))])
    entry = grid.index_to_points(pts[0, ::-1])
    if run is None:
        return DFResult(False, "no segmented pixel on the axis", theta, direction, entry,
                        votes=votes, profile=profile)
    start, end = run
    length_mm = float(np.linalg.norm(grid.index_to_points(pts[end, ::-1]) -
                                     grid.index_to_points(pts[start, ::-1])))
    if length_mm < p.min_run_mm:
        return DFResult(False, f"the first run along the axis is {length_mm:.1f} mm long",
                        theta, direction, entry, votes=votes, profile=profile)
    tip = grid.index_to_points(pts[end, ::-1])
    return DFResult(True, "", theta, direction, entry, tip, votes, profile)
