"""Mathiassen 2017's needle axis search (IEEE TCST 25(3), section II-A): the parameters of
section III-B in millimetres, the geometry of the rotated ROI, and Algorithms 1 and 2.

- :func:`ray_profiles` and :func:`ray_scores`: one search step's rays through a rotated ROI,
  each averaged over 2s+1 samples along the needle (eq. 1), their derivative (eq. 2) and the
  score of a bright line (eqs. 3-5);
- :func:`axis_search_step`: Algorithm 1 for a batch of angles (histogram, smoothing, the points
  on the needle, their mean p_p);
- :func:`estimate_axis`: Algorithm 2, 1-degree steps then 0.1-degree steps around the best.

The geometry and the frame conventions are described in :mod:`._mathiassen`; the tip features
that read the image along the axis found here are in :mod:`._mathiassen_tip`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

from synth import Grid

from .._sampling import remap_points

__all__ = [
    "PAPER_PX_MM",
    "N_FEATURES",
    "MathiassenParams",
    "AxisEstimate",
    "AxisSteps",
    "roi_anchor_mm",
    "axis_vectors",
    "ray_positions_mm",
    "ray_profiles",
    "ray_scores",
    "axis_search_step",
    "estimate_axis",
]

PAPER_PX_MM = 0.10  # section III-B: "a scale factor of 0.10 mm/pixel"
N_FEATURES = 5


@dataclass(frozen=True)
class MathiassenParams:
    """Section III-B's parameters converted from its 0.10 mm pixels to millimetres, plus the
    ones the paper leaves open (marked "ours").

    Axis search (Algorithm 1 and 2):
    ``ray_length_mm`` 97 px rays; ``ray_half_width_mm`` s = 9 px averaged on each side of a ray
    (eq. 1); ``n_rays`` 12 rays; with feedback ``ray_spacing_mm`` 20 px between rays, at least
    ``min_rays`` 3 and at most ``max_ray_spacing_mm`` 45 px apart; ``roi_corner_left_mm`` 40 px
    left of the image's top-right corner. ``roi_corner_down_mm``: the paper puts the corner
    20 px down; synth's needle pierces the skin 0-3 mm beside the probe, so its upper wall
    passes 0.7-4 mm below the top edge at the corner's x and a corner 2 mm down would leave it
    outside the ROI for the shallow entries: ours is 0 (the top edge).
    ``score_window_mm`` w_max of eqs. (4)-(5) (ours: 5 px; a line echo up to 2 (w_max + 1)
    thick scores, and the reverberations 0.8 mm below the wall fall outside the window).
    ``bin_mm`` the histogram's bin width, N_bins = l_ray / bin (ours: one 0.1 mm pixel; on
    synth sequences 0.5 mm bins leave the angle 1-3 degrees off because many angles put the
    needle's points in the same bins); ``peak_window_bins`` 3 bins on each side of the best
    (Algorithm 1, line 28).
    ``coarse_step_deg``/``fine_step_deg``/``fine_half_range_deg``: Algorithm 2's 1 degree,
    0.1 degree and +-0.5 degree; ``search_half_range_deg``: +-5 degrees around the expected
    angle (section III-C); ``full_range_deg``: the range searched when no angle is expected
    (ours).

    Tip features (eqs. 6-10): ``region_length_mm`` and ``line_half_width_mm`` size the trailing
    and leading regions TR and LR of eq. (7) (ours: 2 mm, the needle width s_n, by 2 x 0.2 mm
    across the line echo); ``sq_length_mm`` x ``sq_width_mm`` the 40 x 20 px kernel K^SQ
    (eq. 9); ``sq_shift_mm`` the shift along -v_n that removes the offset of E_3's peak (the
    paper shifts by s_n = 2 mm for its needle and probe; unshifted, E_3 peaked 1.2 mm beyond
    E_1 on synth training frames, so ours is 1.2 mm); ``gpp_size_mm`` s_y = 89 px of K^G''
    (eq. 10), positive over +-``gpp_zero_mm`` = s_n / 2 = 10 px; ``bevel_shift_mm`` n of
    E_5, how far below the axis K^SQ is read (ours: 10 px, half of K^SQ's width, where its
    negative lobe meets the needle); ``delta_frames`` delta = 10 of eq. (8);
    ``candidate_radius_mm`` M = 10 px of eq. (12).
    """

    ray_length_mm: float = 9.7
    ray_half_width_mm: float = 0.9
    n_rays: int = 12
    ray_spacing_mm: float = 2.0
    min_rays: int = 3
    max_ray_spacing_mm: float = 4.5
    roi_corner_left_mm: float = 4.0
    roi_corner_down_mm: float = 0.0
    score_window_mm: float = 0.5
    bin_mm: float = 0.1
    peak_window_bins: int = 3
    coarse_step_deg: float = 1.0
    fine_step_deg: float = 0.1
    fine_half_range_deg: float = 0.5
    search_half_range_deg: float = 5.0
    full_range_deg: tuple[float, float] = (20.0, 70.0)
    region_length_mm: float = 2.0
    line_half_width_mm: float = 0.2
    sq_length_mm: float = 4.0
    sq_width_mm: float = 2.0
    sq_shift_mm: float = 1.2
    gpp_size_mm: float = 8.9
    gpp_zero_mm: float = 1.0
    bevel_shift_mm: float = 1.0
    delta_frames: int = 10
    candidate_radius_mm: float = 1.0
    # background band for the shaft contrast (ours): 2-3 mm above the line echo, where only
    # tissue is (below it lie the reverberations and the shadow)
    background_band_mm: tuple[float, float] = (-3.0, -2.0)

    def __post_init__(self) -> None:
        for name in ("ray_length_mm", "ray_half_width_mm", "ray_spacing_mm",
                     "max_ray_spacing_mm", "score_window_mm", "bin_mm", "coarse_step_deg",
                     "fine_step_deg", "region_length_mm", "sq_length_mm", "sq_width_mm",
                     "gpp_size_mm", "gpp_zero_mm", "candidate_radius_mm"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"MathiassenParams.{name} must be positive, got {v}")
            if name.endswith("_mm") and v > _MAX_MM:
                raise ValueError(f"MathiassenParams.{name} must be at most {_MAX_MM:g} mm, "
                                 f"got {v}")
        for name in ("sq_shift_mm", "bevel_shift_mm", "roi_corner_left_mm",
                     "roi_corner_down_mm"):
            v = getattr(self, name)
            if not 0.0 <= v <= _MAX_MM:
                raise ValueError(f"MathiassenParams.{name} must lie in 0-{_MAX_MM:g} mm, "
                                 f"got {v}")
        if not 1 <= self.min_rays <= self.n_rays:
            raise ValueError(f"need 1 <= min_rays <= n_rays, got {self.min_rays}, {self.n_rays}")
        if self.peak_window_bins < 0 or self.delta_frames < 1:
            raise ValueError("need delta_frames >= 1 and peak_window_bins >= 0")
        lo, hi = self.full_range_deg
        if not 0.0 < lo < hi < 90.0:
            raise ValueError(f"full_range_deg must lie in (0, 90), got {self.full_range_deg}")
        # the tip features' strip across the axis spans +-gpp_size_mm / 2 (K^G''): it must hold
        # the background band and the K^SQ kernel's width
        need = 2.0 * max(abs(self.background_band_mm[0]), abs(self.background_band_mm[1]),
                         0.5 * self.sq_width_mm)
        if self.gpp_size_mm < need:
            raise ValueError(f"MathiassenParams.gpp_size_mm must be at least {need:g} mm (the "
                             f"strip across the axis holds the background band "
                             f"{tuple(self.background_band_mm)} mm and the K^SQ kernel's "
                             f"{self.sq_width_mm:g} mm), got {self.gpp_size_mm}")


_MAX_MM = 100.0  # no distance of the search or the features spans more of an image


# --------------------------------------------------------------------------- geometry


def _step_mm(grid: Grid) -> float:
    """Sample step: one image pixel (the finer axis when the grid is anisotropic)."""
    return float(min(grid.spacing_mm))


def _n(mm: float, step: float) -> int:
    """A length in mm as a whole number of samples (at least 1)."""
    return max(1, int(round(mm / step)))


def roi_anchor_mm(grid: Grid, params: MathiassenParams) -> np.ndarray:
    """The ROI's top corner A (x, z) in mm: left of and below the image's top-right corner."""
    if grid.ndim != 2:
        raise ValueError(f"Mathiassen's search works on 2-D images, got a {grid.ndim}-D grid")
    z0, x0 = grid.origin_mm
    x_right = x0 + (grid.shape[1] - 1) * grid.spacing_mm[1]
    return np.array([x_right - params.roi_corner_left_mm, z0 + params.roi_corner_down_mm])


def axis_vectors(theta_deg) -> tuple[np.ndarray, np.ndarray]:
    """v_n = (-cos theta, sin theta) (entry to tip) and v_p = (sin theta, cos theta), each of
    shape (..., 2) in (x, z)."""
    t = np.deg2rad(np.asarray(theta_deg, dtype=float))
    c, s = np.cos(t), np.sin(t)
    return np.stack([-c, s], axis=-1), np.stack([s, c], axis=-1)


def _axis_length_mm(grid: Grid, anchor: np.ndarray, theta_deg: float, offset_mm: float,
                    margin_mm: float = 0.0) -> float:
    """How far the line A + offset v_p + x v_n (x >= 0) stays inside the image."""
    vn, vp = axis_vectors(theta_deg)
    p0 = anchor + offset_mm * vp
    z0, x0 = grid.origin_mm
    lo = np.array([x0, z0]) + margin_mm
    hi = np.array([x0 + (grid.shape[1] - 1) * grid.spacing_mm[1],
                   z0 + (grid.shape[0] - 1) * grid.spacing_mm[0]]) - margin_mm
    with np.errstate(divide="ignore", invalid="ignore"):
        t_lo = (lo - p0) / vn
        t_hi = (hi - p0) / vn
    t_exit = np.where(vn > 0, t_hi, np.where(vn < 0, t_lo, np.inf))
    return float(max(0.0, np.min(t_exit)))


def ray_positions_mm(length_mm: float, params: MathiassenParams, feedback: bool) -> np.ndarray:
    """Positions r_k of the rays along v_n from the ROI's corner (Algorithm 1, lines 2-3).

    The first ray sits s from the corner so that its averaging region starts there; the rays
    cover ``length_mm`` (the distance from the first ray to the estimated tip, l_needle) with
    spacing l_needle / N_rays. Without feedback N_rays = 12 over the whole ROI. With feedback
    N_rays = l_needle / 20 px rounded, kept within [3, 12], and the spacing capped at 45 px
    (section III-B).
    """
    p = params
    first = p.ray_half_width_mm
    length = max(float(length_mm) - first, p.min_rays * 1e-3)
    if feedback:
        n = int(np.clip(round(length / p.ray_spacing_mm), p.min_rays, p.n_rays))
        spacing = min(length / n, p.max_ray_spacing_mm)
    else:
        n, spacing = p.n_rays, length / p.n_rays
    return first + spacing * np.arange(n)


def _remap(image: np.ndarray, grid: Grid, x_mm: np.ndarray, z_mm: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at points (x_mm, z_mm), two 2-D arrays of one shape
    (section III-B: "we use bilinear interpolation"). Points outside take the nearest border
    pixel."""
    (dz, dx), (z0, x0) = grid.spacing_mm, grid.origin_mm
    col = ((x_mm - x0) / dx).astype(np.float32, copy=False)
    row = ((z_mm - z0) / dz).astype(np.float32, copy=False)
    return cv2.remap(image, col, row, interpolation=cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def _as_float_image(image: np.ndarray) -> np.ndarray:
    im = np.asarray(image)
    if im.ndim != 2:
        raise ValueError(f"expected a 2-D feature image, got shape {im.shape}")
    return np.ascontiguousarray(im, dtype=np.float32)


# --------------------------------------------------------------------------- Algorithm 1


def _w(params: MathiassenParams, step: float) -> int:
    """W = w_max + 1 samples: eq. (4) sums R^Delta over w = 0..w_max."""
    return _n(params.score_window_mm, step) + 1


def ray_profiles(image: np.ndarray, grid: Grid, anchor_mm, thetas_deg, rays_mm,
                 params: MathiassenParams) -> np.ndarray:
    """R(r_k, y) of eq. (1) for every angle, ray and position across the ray.

    Returns (n_angles, n_rays, n_y + 2W): each ray is sampled from W samples above the ROI to
    W below it (W = w_max + 1), so that eqs. (4)-(5) are defined over the whole ROI. Each
    value is the mean of 2s+1 bilinear samples along v_n centred on the ray.
    """
    im = _as_float_image(image)
    step = _step_mm(grid)
    thetas = np.atleast_1d(np.asarray(thetas_deg, dtype=float))
    rays = np.asarray(rays_mm, dtype=float)
    s = _n(params.ray_half_width_mm, step)
    W = _w(params, step)
    n_y = _n(params.ray_length_mm, step)
    along = (rays[:, None] + step * np.arange(-s, s + 1)[None, :]).astype(np.float32)
    across = (step * np.arange(-W, n_y + W)).astype(np.float32)
    vn, vp = axis_vectors(thetas)
    vn, vp = vn.astype(np.float32), vp.astype(np.float32)
    # points A + (r_k + i) v_n + y v_p, shape (angles, rays, 2s+1, y), built directly as the
    # image's fractional column and row (one pass over the samples instead of two)
    (dz, dx), (z0, x0) = grid.spacing_mm, grid.origin_mm
    ax, az = (float(v) for v in np.asarray(anchor_mm, dtype=float))
    a_ = along[None, :, :, None]
    y_ = across[None, None, None, :]
    col = np.float32((ax - x0) / dx) + a_ * (vn[:, 0] / np.float32(dx))[:, None, None, None] \
        + y_ * (vp[:, 0] / np.float32(dx))[:, None, None, None]
    row = np.float32((az - z0) / dz) + a_ * (vn[:, 1] / np.float32(dz))[:, None, None, None] \
        + y_ * (vp[:, 1] / np.float32(dz))[:, None, None, None]
    samples = remap_points(im, col, row, cv2.BORDER_REPLICATE)
    return samples.mean(axis=2)  # eq. (1): 1/(2s+1) sum_i I(i, y)


def ray_scores(R: np.ndarray, w_max: int) -> np.ndarray:
    """Score S(r_k, y) of a bright line (eqs. 2-5) along the last axis of ``R``.

    R^Delta(y) = R(y+1) - R(y) (eq. 2), so the sums of eqs. (4)-(5) telescope:
    S_lead(y) = sum_{w=0}^{w_max} R^Delta(y+w) = R(y+W) - R(y) and
    S_lag(y) = sum_{w=0}^{w_max} R^Delta(y-w-1) = R(y) - R(y-W), W = w_max + 1.
    S = S_lag - S_lead - |S_lag + S_lead| (eq. 3) = 2 min(R(y) - R(y-W), R(y) - R(y+W)): high
    only where y is brighter than both W above and W below, i.e. on a line, not an edge.
    Returns the scores for y = W .. n-1-W (length n - 2W).
    """
    R = np.asarray(R)
    W = int(w_max) + 1
    if R.shape[-1] <= 2 * W:
        raise ValueError(f"rays of {R.shape[-1]} samples are too short for w_max = {w_max}")
    centre = R[..., W:-W]
    s_lead = R[..., 2 * W:] - centre  # eq. (4), telescoped sum of eq. (2)
    s_lag = centre - R[..., :-2 * W]  # eq. (5)
    return s_lag - s_lead - np.abs(s_lag + s_lead)  # eq. (3)


@dataclass(frozen=True)
class AxisSteps:
    """Algorithm 1 for a batch of angles: ``h_max`` (n_angles,), ``p_p_mm`` (n_angles,) the
    mean position of the needle points across the ROI (mm from its top edge along v_p),
    ``points_mm`` (n_angles, n_rays) the points p_k, ``scores`` (n_angles, n_rays) S at them."""

    thetas_deg: np.ndarray
    h_max: np.ndarray
    p_p_mm: np.ndarray
    points_mm: np.ndarray
    scores: np.ndarray


@lru_cache(maxsize=32)
def _bin_matrix(n_y: int, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """One-hot (n_y, n_bins) of b = floor(N_bins y / l_ray) (Algorithm 1, line 18) and the
    first y of every bin (plus n_y)."""
    b = (n_bins * np.arange(n_y)) // n_y
    onehot = np.zeros((n_y, n_bins), dtype=np.float32)
    onehot[np.arange(n_y), b] = 1.0
    starts = np.searchsorted(b, np.arange(n_bins + 1))
    return onehot, starts


def axis_search_step(image: np.ndarray, grid: Grid, thetas_deg, rays_mm,
                     params: MathiassenParams, anchor_mm=None) -> AxisSteps:
    """Algorithm 1 (AXISSEARCHSTEP) at every angle of ``thetas_deg`` with rays at ``rays_mm``."""
    p = params
    step = _step_mm(grid)
    anchor = roi_anchor_mm(grid, p) if anchor_mm is None else np.asarray(anchor_mm, float)
    thetas = np.atleast_1d(np.asarray(thetas_deg, dtype=float))
    R = ray_profiles(image, grid, anchor, thetas, rays_mm, p)  # eq. (1)
    S = ray_scores(R, _w(p, step) - 1)  # eqs. (2)-(5), (angles, rays, n_y)
    n_y = S.shape[-1]
    n_bins = min(n_y, _n(p.ray_length_mm, p.bin_mm))
    onehot, starts = _bin_matrix(n_y, n_bins)
    H = S.sum(axis=1) @ onehot  # lines 15-21: H(b) += S(r_k, y)
    Hs = H.copy()  # lines 22-24: H_S(b) = H(b) + H(b-1)/2 + H(b+1)/2
    Hs[:, 1:] += 0.5 * H[:, :-1]
    Hs[:, :-1] += 0.5 * H[:, 1:]
    b_max = np.argmax(Hs, axis=1)  # line 26
    h_max = Hs[np.arange(len(thetas)), b_max]
    lo = starts[np.clip(b_max - p.peak_window_bins, 0, n_bins)]  # line 28: b_max +- 3 bins
    hi = starts[np.clip(b_max + p.peak_window_bins + 1, 0, n_bins)]
    y = np.arange(n_y)
    inside = (y[None, :] >= lo[:, None]) & (y[None, :] < hi[:, None])
    masked = np.where(inside[:, None, :], S, -np.inf)
    pk = np.argmax(masked, axis=2)  # line 28: p_k = argmax_y S(r_k, y)
    score = np.take_along_axis(S, pk[..., None], axis=2)[..., 0]
    points = pk * step
    return AxisSteps(thetas, h_max.astype(float), points.mean(axis=1),  # line 31: mean(p_k)
                     points.astype(float), score.astype(float))


@dataclass(frozen=True)
class AxisEstimate:
    """Algorithm 2's result: the needle's line echo {A + p_p v_p + x v_n}.

    ``theta_deg`` insertion angle to the skin; ``p_p_mm`` offset of the line from the ROI's
    top edge; ``h_max`` the best smoothed histogram value H_max; ``rays_mm`` r_k and
    ``points_mm`` p_k at the chosen angle, ``scores`` S(r_k, p_k); ``anchor_mm`` A.
    """

    theta_deg: float
    p_p_mm: float
    h_max: float
    anchor_mm: np.ndarray
    rays_mm: np.ndarray = field(repr=False)
    points_mm: np.ndarray = field(repr=False)
    scores: np.ndarray = field(repr=False)

    @property
    def direction(self) -> np.ndarray:
        """v_n, unit (x, z), from the entry towards the tip."""
        return axis_vectors(self.theta_deg)[0]

    @property
    def normal(self) -> np.ndarray:
        """v_p, unit (x, z), pointing into the tissue."""
        return axis_vectors(self.theta_deg)[1]

    def point_mm(self, x_mm, offset_mm: float = 0.0) -> np.ndarray:
        """(x, z) mm of the point x along the axis, ``offset_mm`` further along v_p."""
        vn, vp = axis_vectors(self.theta_deg)
        x = np.asarray(x_mm, dtype=float)[..., None]
        return self.anchor_mm + (self.p_p_mm + offset_mm) * vp + x * vn

    def rotated(self, theta_deg: float, upto_mm: float | None = None) -> AxisEstimate:
        """The line at angle ``theta_deg`` through the centroid of the needle points p_k (to
        apply a filtered angle, Algorithm 4 line 16). ``upto_mm``: only the rays up to that
        position along the axis (those on the needle) make the centroid."""
        vn, vp = axis_vectors(self.theta_deg)
        rel = self.points_mm[:, None] * vp + self.rays_mm[:, None] * vn  # p_k - A
        use = np.ones(len(rel), bool) if upto_mm is None else self.rays_mm <= upto_mm
        if not use.any():
            use[0] = True
        vn2, vp2 = axis_vectors(theta_deg)
        across = rel @ vp2
        return AxisEstimate(float(theta_deg), float(across[use].mean()), self.h_max,
                            self.anchor_mm, rel @ vn2, across, self.scores)


def estimate_axis(image: np.ndarray, grid: Grid, params: MathiassenParams | None = None, *,
                  theta_centre_deg: float | None = None, half_range_deg: float | None = None,
                  theta_range_deg: tuple[float, float] | None = None,
                  tip_along_mm: float | None = None) -> AxisEstimate:
    """Algorithm 2 (ESTIMATEAXIS): Algorithm 1 over theta in 1-degree steps, then in
    0.1-degree steps within +-0.5 degree of the best; the pair (theta, p_p) with the highest
    H_max wins.

    The coarse range is ``theta_centre_deg +- half_range_deg`` (default +-5 degrees, section
    III-C), or ``theta_range_deg`` (default ``params.full_range_deg`` when no centre is given).
    ``tip_along_mm`` turns on feedback (the "+F" ROI): the rays span from the ROI corner to
    that tip estimate; without it 12 rays span the ROI up to the image's edge.
    """
    p = MathiassenParams() if params is None else params
    anchor = roi_anchor_mm(grid, p)
    if theta_centre_deg is not None:
        half = p.search_half_range_deg if half_range_deg is None else float(half_range_deg)
        lo, hi = theta_centre_deg - half, theta_centre_deg + half
        centre = float(theta_centre_deg)
    else:
        lo, hi = p.full_range_deg if theta_range_deg is None else theta_range_deg
        centre = 0.5 * (lo + hi)
    if tip_along_mm is None:
        length = _axis_length_mm(grid, anchor, centre, 0.5 * p.ray_length_mm)
        rays = ray_positions_mm(length, p, feedback=False)
    else:
        rays = ray_positions_mm(float(tip_along_mm), p, feedback=True)
    n_coarse = int(np.floor((hi - lo) / p.coarse_step_deg + 1e-9)) + 1
    coarse = lo + p.coarse_step_deg * np.arange(n_coarse)  # lines 2-4
    st = axis_search_step(image, grid, coarse, rays, p, anchor)
    theta_max = coarse[int(np.argmax(st.h_max))]  # lines 5-6
    n_fine = int(round(p.fine_half_range_deg / p.fine_step_deg))
    fine = theta_max + p.fine_step_deg * np.arange(-n_fine, n_fine + 1)  # lines 7-9
    st = axis_search_step(image, grid, fine, rays, p, anchor)
    k = int(np.argmax(st.h_max))  # lines 10-12
    return AxisEstimate(float(fine[k]), float(st.p_p_mm[k]), float(st.h_max[k]), anchor,
                        rays, st.points_mm[k], st.scores[k])
