"""Carriere 2016: track the needle's cross-section in axial (transverse) slices and predict the
whole needle's shape with the bicycle model fitted by the particle filter.

Per frame (section II): the feature map (the variance image of eq. 1 for the classical source,
the learned cross-section likelihood otherwise, whose templates are cut from the variance image
weighted by the likelihood: ``learned_template``); NCC template matching of an h x w template in
a 2h x 2w region of interest centred on the previous centre for the first 10 mm and on the
bicycle model's prediction afterwards; the template is cut again around every new centre.
Per frame (section IV): the centres, placed in one fixed frame by the probe poses, give the
plane angle phi by PCA and the in-plane points (v, u); the particle filter over (R, theta_0)
runs steps 3-9 once per frame after 10 mm and stops at the rotation depth D (step 10); the
mean parameters predict the whole needle, turned by 180 degrees at D (eqs. 3-4).

Where the paper leaves things open, or where we depart from it (each is a field of
:class:`AxialParams`):

* Detection. The paper's user clicks the first centre. Here it is the strongest compact
  spot of the feature map smoothed by a Gaussian of the needle's radius (a needle cut across
  is a spot; an interface cut across is a line: the map ``detect_lateral_mm`` either side of
  a spot stays below ``detect_compact`` of it), which on a classical map must stand out of
  the slice's other compact spots by ``detect_ratio`` (on PyMUST's phased-array slices the
  best of the speckle's spots scores 18-25, its next 1-3% less), and is accepted when its
  robust score (max - median) / (1.4826 MAD) reaches ``detect_score`` (15: needle-free slices of the
  simulator score below 10 on a homogeneous background and up to 13-16 among the bright
  structures of an inhomogeneous one; needles score above 30 at a contrast ratio of 2 and
  12-20 at 1.5), and for learned sources when the smoothed probability reaches
  ``min_peak``. For classical features the point is then moved to one radius below the
  upper edge of the echo (``detect_anchor``): the maximum lies 0.1-0.5 mm off the shaft's
  axis depending on the contrast (the bright upper wall, or a saturated reverberation tail
  below it), the edge plus a radius 0.2 mm above it at every contrast tried. The same
  detector finds the needle again after it was lost.
* h x w = 3 mm x 3 mm (11 x 11 px at 0.3 mm), about twice the 18 G needle's 1.27 mm: the
  template holds the echo's upper edge and the start of its tail. The ROI is 2h x 2w, a
  search range of +-1.8 mm around its centre.
* Template update with drift correction (Matthews, Ishikawa & Baker 2004, "The template
  update problem"). The paper's template, cut again around every new centre, lets the
  centre random-walk along the echo: in the simulator (128 x 128, D = 60/80 mm, paper's
  filter) the mean tracking error grows from 0.23 to 0.6-0.9 mm and the mean tip prediction
  error from 0.05-1.5 to 0.65-3.3 mm. The first template is therefore aligned near each
  match and its alignment kept when it lies within ``drift_tolerance_mm``;
  ``drift_correction=False`` is the paper's plain update.
* Outliers: a match is rejected when its NCC peak is below ``ncc_min`` or it jumps more than
  ``max_jump_mm`` (+ ``max_slope`` per mm of depth) from the last accepted centre; a rejected
  frame is reported at the ROI's centre (``details.outlier``), is not fed to the
  filter and does not update the template; after ``max_coast_frames`` rejections in a row the
  needle is ``lost``. It is lost at once when the matched place no longer stands out of the
  smoothed map (robust score below ``lost_score``): the cross-section vanished, e.g. the
  slice passed the tip; or when it is no compact spot (the match slid onto an interface).
  While lost (or searching) every frame runs the detector; a centre found again is the
  needle only where the model expects it (within the jump allowed since the last centre):
  a spot elsewhere, once the needle has been seen, is tissue and the frame stays ``lost``.
* The ROI is centred on the model's prediction (the paper), except when that prediction lies
  more than ``max_jump_mm`` from the previous centre: a model that far off (early, or long
  after D) would put the needle outside the ROI, so the previous centre is used instead
  (``details.roi_source``).
* Learned sources, while tracking, run the network only on the box the step reads around the
  ROI plus the source's context (``learned_roi``, :mod:`._axial_maps`): the paper's ROI is
  all the tracker looks at once it tracks. Detection and re-detection read the whole slice.
* phi is re-estimated by PCA from all accepted centres at every frame (the paper computes it
  at 10 mm, where a needle of R = 1500 mm has deflected by 0.03 mm and PCA returns noise), the
  history is projected again, and the u axis is oriented so that the deflection is positive
  (the prior R ~ N(1500, 600) has almost no negative radii); phi is frozen at D.
* Depth v of a slice: the probe pose's translation along its elevation axis, signed by the
  direction the slices move (``insertion_sign``); without poses, frame k since the reset lies
  at (k + 1) ``step_mm``. The origin of the (u, v) plane is the first centre (section IV).
  ``rotation_depth_mm`` (D) and ``final_depth_mm`` are depths on that same axis (for the
  axial scenario: from the entry point). The filter's particles are drawn (step 1) once the
  first 10 mm are in.

The paper's filter barely learns R (see :class:`~needlenet.backends._bicycle.
CarriereParticleFilter`): the per-point arg-min of steps 4-5 is dominated by theta_0.
``filter_update="lsq"`` (the default) keeps steps 1-9 but then moves the particle cloud
(translating it, spread unchanged) onto the maximum a posteriori least-squares fit of
(theta_0, 1/R) to all observed points, the paper's prior a Gaussian prior; ``"paper"`` is the
paper's filter alone. In the simulator (128 x 128, 0.5 mm slices, prediction at 100 mm from
D = 60 or 80 mm) the paper's filter predicts the tip within 0.05-0.16 mm for radii near its
prior mean of 1500 mm but 1.1-1.5 mm for R = 800 mm (its R stays near 1500 mm); "lsq"
predicts it within 0.01-0.04 mm in both cases.

Reported per frame: ``tip_mm`` = the cross-section centre (x, z) in the probe frame (where
the shaft crosses the slice, the sequence file's axial label); ``direction`` = the unit (x, z)
component of the predicted shaft tangent at the slice, i.e. the deflection axis signed by
du/dv (the sequence file's axial ``direction``), ``None`` before the model exists;
``covariance`` (x, z) mm^2 from the curvature of the NCC peak (a heuristic: (1 - peak) /
|d2 NCC / dpx^2| per axis, at least 1/12 px^2; on a wall-referenced map plus the centre's depth
below the wall, :meth:`AxialParams.centre_covariance`); ``details`` an :class:`AxialDetails`:
the slice's depth, match and timings (Carriere's Table II split), and the bicycle model after
the slice's update (``predicted_u_mm``: its prediction for the slice before, the ROI's centre).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from synth import invert_rigid

from ..backends import (
    CarriereParticleFilter,
    RngLike,
    UpdateOutcome,
    fit_plane_angle_pca,
    match_template_roi,
)
from ..features import FeatureSource, Frame
from ._axial_maps import SliceGeometry, SliceMaps, region_box, slice_geometry, slice_maps
from ._axial_params import AxialParams
from ._base import NeedleEstimate, Status, Tracker
from ._cross_section import (
    below_top_edge,
    bilinear,
    compact_spots,
    is_compact,
    local_peak,
    peak_covariance,
    subpixel_peak,
)
from ._details import AxialDetails, AxialModel
from ._margins import inner_region

__all__ = ["AxialParams", "AxialTracker", "map_fit_bicycle"]


def map_fit_bicycle(v, u, prior_theta0_deg=(0.0, 5.0), prior_radius_mm=(1500.0, 600.0),
                    measurement_sd_mm=0.1) -> tuple[float, float]:
    """Maximum a posteriori (R [mm], theta_0 [deg]) of the bicycle path through the origin.

    The circle of eqs. (3)-(4) through (0, 0) with heading theta_0 and signed radius R obeys
    u cos(theta_0) - v sin(theta_0) = (u^2 + v^2) / (2 R) exactly, i.e.
    u = tan(theta_0) v + kappa' (u^2 + v^2) / 2 with kappa' = 1 / (R cos theta_0): linear in
    (tan theta_0, kappa'). The fit is the linear least squares with measurement sd
    ``measurement_sd_mm`` and Gaussian priors tan(theta_0) ~ N(tan mu, sd in rad) and
    1/R ~ N(1/mu_R, sd_R / mu_R^2) (the paper's prior, by the delta method).
    """
    v = np.asarray(v, dtype=float)
    u = np.asarray(u, dtype=float)
    A = np.stack([v, 0.5 * (u * u + v * v)], axis=1)
    mu_t = np.tan(np.deg2rad(prior_theta0_deg[0]))
    sd_t = max(np.deg2rad(prior_theta0_deg[1]), 1e-9)
    mu_k = 1.0 / prior_radius_mm[0]
    sd_k = max(prior_radius_mm[1] / prior_radius_mm[0] ** 2, 1e-12)
    w = 1.0 / measurement_sd_mm**2
    H = w * (A.T @ A) + np.diag([1.0 / sd_t**2, 1.0 / sd_k**2])
    b = w * (A.T @ u) + np.array([mu_t / sd_t**2, mu_k / sd_k**2])
    t, k = np.linalg.solve(H, b)
    theta0 = np.arctan(t)
    kappa = k * np.cos(theta0)
    kappa = np.copysign(max(abs(kappa), 1e-6), kappa)  # |R| <= 1e6 mm: straight enough
    return float(1.0 / kappa), float(np.rad2deg(theta0))


class _ReprojectedPF(CarriereParticleFilter):
    """The back end's filter fed the whole history at every frame, because phi (and so every
    u) is re-estimated by PCA each frame; steps 3-9 then run once, as in the paper."""

    def update_history(self, v: np.ndarray, u: np.ndarray) -> UpdateOutcome:
        self._v = v[:-1].tolist()
        self._u = u[:-1].tolist()
        return self.update(float(v[-1]), float(u[-1]))


@dataclass
class _Track:
    """What the tracker knows between frames (reset with the tracker)."""

    frame0_pose: np.ndarray | None = None  # probe pose of the first frame: the fixed frame F0
    eps_first: float | None = None  # elevation coordinate of that frame
    sign: int = 1
    sign_known: bool = False
    n_frames: int = 0
    template: np.ndarray | None = None  # cut around the last centre (the paper's update)
    first_template: np.ndarray | None = None  # cut at the detection (drift correction)
    last_xz_f0: np.ndarray | None = None  # last accepted centre, (x, z) in F0
    last_eps: float = np.nan  # elevation coordinate of the last accepted centre
    misses: int = 0
    origin_xz: np.ndarray | None = None  # origin of the (u, v) plane, (x, z) in F0
    origin_eps: float = np.nan
    xz: list = field(default_factory=list)  # accepted centres, (x, z) in F0
    eps: list = field(default_factory=list)  # their elevation coordinates
    pf: _ReprojectedPF | None = None
    phi: float = np.nan  # angle of the u axis in F0's (x, z) plane
    frozen: bool = False  # the filter stopped at D

    @property
    def origin_depth(self) -> float:
        return self.sign * self.origin_eps


class AxialTracker(Tracker):
    """Carriere 2016's axial tracker; see the module docstring for the method and choices.

    Parameters
    ----------
    method : "carriere"
    features : FeatureSource, optional
        Default :class:`~needlenet.features.VarianceFeatures` (eq. 1).
    params : AxialParams, optional
    rng : np.random.Generator | int | None
        Seeds the particle filter (``seed`` is the same, for the command line).
    """

    modality = "axial"
    methods = ("carriere",)

    def __init__(self, method: str = "carriere", features: FeatureSource | None = None,
                 params: AxialParams | None = None, rng: RngLike = None,
                 seed: int | None = None):
        self.params = AxialParams() if params is None else params
        self._planned_rotation_mm: float | None = None
        self._geometry_key: tuple | None = None
        self._geometry_cache: SliceGeometry | None = None
        super().__init__(method, features, rng=rng, seed=seed)

    def run(self, seq, progress=None) -> list[NeedleEstimate]:
        """Track a :class:`synth.Sequence` from a reset. Without ``rotation_depth_mm`` in the
        parameters, the depth at which the sequence's protocol turns the bevel
        (``seq.meta["params"]["rotation_depth_mm"]``) is used: the paper takes D as known
        ("given that the depth of needle rotation is known", section IV)."""
        self.reset()
        meta = seq.meta.get("params", {}) if isinstance(seq.meta, dict) else {}
        planned = meta.get("rotation_depth_mm")
        self._planned_rotation_mm = None if planned is None else float(planned)
        try:
            return super().run(seq, progress)
        finally:
            self._planned_rotation_mm = None

    @property
    def rotation_depth_mm(self) -> float | None:
        """D in use: the parameter, else the sequence's planned rotation depth (``run``)."""
        D = self.params.rotation_depth_mm
        return self._planned_rotation_mm if D is None else D

    @classmethod
    def default_features(cls) -> FeatureSource:
        from ..features import VarianceFeatures

        return VarianceFeatures()

    def reset(self) -> None:
        super().reset()
        self._track = _Track()

    # -- geometry ----------------------------------------------------------------------------
    def _frame_geometry(self, frame: Frame) -> tuple[float, np.ndarray, np.ndarray]:
        """The slice's coordinate along the elevation axis (its depth is ``sign`` times it;
        the sign is known once the slices have moved, and every depth is computed from the
        stored coordinates so that it stays consistent), and the transforms F_k -> F0 and
        F0 -> F_k."""
        tr, p = self._track, self.params
        pose = frame.probe_pose
        if pose is None:
            eps = p.step_mm * (tr.n_frames + 1)
            if tr.frame0_pose is None:
                tr.frame0_pose = np.eye(4)
                tr.eps_first = 0.0
            # without poses the slices are stacked along +y of the first frame
            to_f0 = np.eye(4)
            to_f0[1, 3] = eps - p.step_mm
            return eps, to_f0, invert_rigid(to_f0)
        pose = np.asarray(pose, dtype=float)
        eps = float(pose[:3, 3] @ pose[:3, 1])  # translation along the elevation axis
        if tr.frame0_pose is None:
            tr.frame0_pose = pose
            tr.eps_first = eps
            tr.sign = 1 if p.insertion_sign is None else p.insertion_sign
            tr.sign_known = p.insertion_sign is not None
        if not tr.sign_known and abs(eps - tr.eps_first) > 1e-6:
            tr.sign = 1 if eps > tr.eps_first else -1  # the slices move along the insertion
            tr.sign_known = True
        to_f0 = invert_rigid(tr.frame0_pose) @ pose
        return eps, to_f0, invert_rigid(to_f0)

    # -- model -------------------------------------------------------------------------------
    def _u_axis_f0(self) -> np.ndarray:
        return np.array([np.cos(self._track.phi), np.sin(self._track.phi)])

    def _model_ready(self) -> bool:
        tr = self._track
        return tr.pf is not None and tr.pf.n_updates > 0 and np.isfinite(tr.phi)

    def _turns(self) -> tuple[float, ...]:
        D = self.rotation_depth_mm
        tr = self._track
        if D is None or not self.params.bevel_turn or D <= tr.origin_depth:
            return ()
        return (D - tr.origin_depth,)

    def _predict_u(self, depths) -> np.ndarray:
        tr = self._track
        v = np.atleast_1d(np.asarray(depths, dtype=float)) - tr.origin_depth
        return tr.pf.predict_shape(v, self._turns())

    def _update_filter(self) -> None:
        """Steps 2-10 of section IV with phi from PCA over all accepted centres."""
        tr, p = self._track, self.params
        if tr.frozen:
            return
        xz = np.asarray(tr.xz)
        v = tr.sign * (np.asarray(tr.eps) - tr.origin_eps)
        if v.max() < p.warmup_depth_mm:
            return
        if tr.pf is None:  # step 1, once the insertion's direction is known
            D = self.rotation_depth_mm
            D = np.inf if D is None else D - tr.origin_depth
            tr.pf = _ReprojectedPF(replace(p.pf, warmup_depth_mm=p.warmup_depth_mm,
                                           rotation_depth_mm=D), rng=self.rng)
        d = xz - tr.origin_xz
        phi = fit_plane_angle_pca(np.column_stack([xz[:, 0], xz[:, 1], v]))  # section IV
        if np.sum(d @ np.array([np.cos(phi), np.sin(phi)])) < 0:
            phi += np.pi  # orient u so that the deflection is positive
        tr.phi = phi
        u = d @ self._u_axis_f0()  # eq. (5) inverted
        outcome = tr.pf.update_history(v, u)
        if outcome and p.filter_update == "lsq":
            used = (v > 0) & (v <= tr.pf.params.rotation_depth_mm)
            pf_p = tr.pf.params
            R, th = map_fit_bicycle(v[used], u[used], (pf_p.mu_theta0_deg, pf_p.sigma_theta0_deg),
                                    (pf_p.mu_radius_mm, pf_p.sigma_radius_mm),
                                    p.measurement_sd_mm)
            shift = np.array([R, th]) - tr.pf.mu
            tr.pf.particles = tr.pf.particles + shift  # the cloud moved onto the fit
            tr.pf.mu = tr.pf.mu + shift
        tr.frozen = tr.pf.stopped

    # -- image -------------------------------------------------------------------------------
    def _geometry(self, frame: Frame) -> SliceGeometry:
        """The step's constants for this slice's shape and spacing (kept for the next slice)."""
        key = (frame.image.shape, tuple(frame.grid.spacing_mm), id(self.features))
        if self._geometry_key != key:
            self._geometry_cache = slice_geometry(frame.grid.spacing_mm, self.params,
                                                  self.features)
            self._geometry_key = key
        return self._geometry_cache

    def _maps(self, frame: Frame, g: SliceGeometry, roi_rc: np.ndarray | None = None
              ) -> SliceMaps:
        """The slice's maps (:func:`~._axial_maps.slice_maps`): over the whole slice, or for a
        learned source with ``learned_roi`` and an ROI centre ``roi_rc``, from the network run
        on the box the tracking step reads (:func:`~._axial_maps.roi_reach_px`) plus the
        source's context."""
        p = self.params
        learned = self._is_learned()
        template = p.learned_template if learned else None
        box = None
        if roi_rc is not None and learned and p.learned_roi:
            box = region_box(frame.image.shape, roi_rc, g.half_px, g.context_px, g.align)
        return slice_maps(self.features, frame, g.sigma_px, p.score_floor, template, box,
                          g.context_px)

    def _is_learned(self) -> bool:
        return getattr(self.features, "kind", "") == "learned"

    def _wall_offset_rc(self, spacing) -> np.ndarray:
        """From a wall-referenced map's maximum to the needle's centre (rows, cols)."""
        if getattr(self.features, "target_reference", "centerline") == "wall":
            return np.array([self.params.needle_radius_mm / float(spacing[0]), 0.0])
        return np.zeros(2)

    def _refine_on_map(self, F: np.ndarray, center: np.ndarray, spacing) -> np.ndarray:
        """The likelihood's centroid above half its maximum within one radius of the match
        (in map coordinates: the wall offset is taken off and put back)."""
        off = self._wall_offset_rc(spacing)
        c = np.asarray(center, float) - off
        half = np.maximum(np.ceil(self.params.needle_radius_mm / np.asarray(spacing)), 1)
        lo = np.maximum(np.floor(c - half).astype(int), 0)
        hi = np.minimum(np.ceil(c + half).astype(int) + 1, F.shape)
        if np.any(hi - lo < 2):
            return center
        win = F[lo[0]:hi[0], lo[1]:hi[1]].astype(float)
        w = np.maximum(win - 0.5 * float(win.max()), 0.0)
        if w.sum() <= 0:
            return center
        rr, cc = np.mgrid[lo[0]:hi[0], lo[1]:hi[1]]
        return np.array([(rr * w).sum(), (cc * w).sum()]) / w.sum() + off

    def _min_peak(self) -> float:
        if self.params.min_peak is not None:
            return self.params.min_peak
        return 0.3 if getattr(self.features, "kind", "") == "learned" else 0.0

    def _anchor(self) -> str:
        a = self.params.detect_anchor
        if a == "auto":
            return "peak" if getattr(self.features, "kind", "") == "learned" else "top_edge"
        return a

    def _correct_drift(self, F: np.ndarray, m, g: SliceGeometry, spacing: np.ndarray):
        """Matthews, Ishikawa & Baker 2004's template update with drift correction: align the
        first template near the match of the updated one and keep that alignment when it lies
        within ``drift_tolerance_mm``; otherwise the updated template's match stands."""
        tr, p = self._track, self.params
        half = tuple(int(n) for n in np.asarray(g.size) // 2 + g.drift_px + 1)
        m0 = match_template_roi(F, tr.first_template, m.center, half)
        if np.linalg.norm((m0.center - m.center) * spacing) <= p.drift_tolerance_mm:
            return m0._replace(peak=m.peak)  # the NCC peak stays the paper's
        return m

    def _cut_template(self, F: np.ndarray, center: np.ndarray, size: tuple[int, int]):
        # cv2 centres are (x = col, y = row); the patch centre lands on the sub-pixel centre
        return cv2.getRectSubPix(F, (size[1], size[0]), (float(center[1]), float(center[0])))

    # -- the step ----------------------------------------------------------------------------
    def _step(self, frame: Frame) -> NeedleEstimate:
        p, tr = self.params, self._track
        t0 = time.perf_counter()
        eps, to_f0, from_f0 = self._frame_geometry(frame)
        depth = tr.sign * eps
        tr.n_frames += 1
        grid = frame.grid
        spacing = np.asarray(grid.spacing_mm, dtype=float)  # (row, col) = (z, x)
        g = self._geometry(frame)
        size = g.size

        def to_f0_xz(rc):
            xz = grid.index_to_points(np.asarray(rc, dtype=float))
            q = to_f0[:3, :3] @ np.array([xz[0], 0.0, xz[1]]) + to_f0[:3, 3]
            return q[[0, 2]]

        def from_f0_rc(xz_f0):
            q = from_f0[:3, :3] @ np.array([xz_f0[0], 0.0, xz_f0[1]]) + from_f0[:3, 3]
            return grid.points_to_index(q[[0, 2]])

        # the model's prediction for this slice, before its own update
        pred_u = float(self._predict_u([depth])[0]) if self._model_ready() else np.nan
        pred_xz = (tr.origin_xz + pred_u * self._u_axis_f0()) if np.isfinite(pred_u) else None
        ncc_peak, score, roi_source, outlier, reason = np.nan, np.nan, None, False, None
        status, center, cov = self.status, None, None
        maps = None
        accepted = detected = False
        if status == Status.TRACKING and tr.template is not None:
            prev_rc = from_f0_rc(tr.last_xz_f0)
            roi_rc, roi_source = prev_rc, "previous"  # the first 10 mm
            if pred_xz is not None and depth - tr.origin_depth >= p.warmup_depth_mm:
                pred_rc = from_f0_rc(pred_xz)
                if np.linalg.norm((pred_rc - prev_rc) * spacing) <= p.max_jump_mm:
                    roi_rc, roi_source = pred_rc, "model"
            maps = self._maps(frame, g, roi_rc)
            M = maps.M  # what the NCC templates are cut from
            m = None
            try:
                m = match_template_roi(M, tr.template, roi_rc, size)  # section II: NCC in ROI
                if p.drift_correction:
                    m = self._correct_drift(M, m, g, spacing)
            except ValueError as exc:  # ROI off the image, or a constant template
                reason = str(exc)
            if m is not None:
                ncc_peak = m.peak
                s_at = bilinear(maps.S, m.center)
                score = (s_at - maps.med) / maps.scale
                jump = float(np.linalg.norm(to_f0_xz(m.center) - tr.last_xz_f0))
                allowed = p.max_jump_mm + p.max_slope * abs(eps - tr.last_eps)
                if score < p.lost_score or s_at < self._min_peak():
                    status = Status.LOST  # the cross-section vanished
                    reason = f"no cross-section at the match (score {score:.1f})"
                elif not is_compact(maps.S, m.center, maps.med, maps.scale, spacing,
                                    p.detect_lateral_mm, p.detect_compact):
                    status = Status.LOST  # the match slid onto a line: an interface
                    reason = "the match lies on a line across the slice, not a cross-section"
                elif m.peak < p.ncc_min:
                    reason = f"NCC peak {m.peak:.2f} < {p.ncc_min}"
                elif jump > allowed:
                    reason = f"jump {jump:.2f} mm > {allowed:.2f} mm"
                else:
                    center, accepted = m.center, True
                    cov = peak_covariance(m.score, spacing)
                    if (p.learned_peak_refine and self._is_learned()
                            and p.learned_template == "map"):
                        center = self._refine_on_map(maps.F, center, spacing)
            if status == Status.TRACKING and not accepted:
                outlier = True
                tr.misses += 1
                if tr.misses > p.max_coast_frames:
                    status = Status.LOST
                else:  # reported at the ROI's centre, not fed, template kept
                    center = roi_rc
                    cov = np.diag(np.full(2, (0.5 * p.max_jump_mm) ** 2))
        if status != Status.TRACKING or tr.template is None:
            # (re-)detection: the maximum of the smoothed map replaces the user's click
            if maps is None or maps.valid is not None:  # detection reads the whole slice
                maps = self._maps(frame, g)
            center, score, why = self._detect(frame, maps, spacing)
            if center is None:
                status = Status.SEARCHING if status == Status.TRACKING else status
                if reason is None:
                    reason = why
            else:
                reason = None
                status, accepted, detected = Status.TRACKING, True, True
                cov = np.diag(np.full(2, (0.5 * p.needle_radius_mm) ** 2))
                if tr.last_xz_f0 is not None:  # found again: the needle only where expected
                    ref = pred_xz if pred_xz is not None else tr.last_xz_f0
                    allowed = p.max_jump_mm + p.max_slope * abs(eps - tr.last_eps)
                    off = float(np.linalg.norm(to_f0_xz(center) - ref))
                    if off > allowed:
                        status, accepted, detected = Status.LOST, False, False
                        reason = (f"a spot {off:.1f} mm from the needle's path (allowed "
                                  f"{allowed:.1f} mm): not the needle")
                        center, cov = None, None
        t_image = time.perf_counter()

        if accepted:
            tr.misses = 0
            tr.template = self._cut_template(maps.M, center, size)  # updated every frame
            if detected:
                tr.first_template = tr.template
            xz0 = to_f0_xz(center)
            tr.last_xz_f0, tr.last_eps = xz0, eps
            if tr.origin_xz is None:  # section IV: the first point is the origin of (u, v)
                tr.origin_xz, tr.origin_eps = xz0, eps
            if not tr.frozen and depth >= tr.origin_depth:
                tr.xz.append(xz0)
                tr.eps.append(eps)
                self._update_filter()
        elif status != Status.TRACKING:
            tr.template = None
        t_filter = time.perf_counter()

        model, direction = self._model(depth, from_f0)
        details = AxialDetails(depth_mm=depth, ncc_peak=ncc_peak, predicted_u_mm=pred_u,
                               outlier=outlier, roi_source=roi_source, score=score, model=model,
                               image_ms=(t_image - t0) * 1e3,
                               filter_ms=(t_filter - t_image) * 1e3)
        tip = None if center is None else grid.index_to_points(center)
        if tip is not None and self._wall_offset_rc(spacing)[0] > 0:  # a centre below a wall
            cov = cov + p.centre_covariance()
        return NeedleEstimate(t=frame.t, status=status, tip_mm=tip,
                              direction=direction if tip is not None else None,
                              covariance=cov if tip is not None else None, reason=reason,
                              details=details)

    def _detect(self, frame: Frame, maps: SliceMaps, spacing
                ) -> tuple[np.ndarray | None, float, str]:
        """The strongest compact spot of the smoothed feature map inside the imaged region
        (less ``mask_edge_mm``), when it stands out of the map (``detect_score``) and, on a
        classical map, of the slice's other compact spots (``detect_ratio``; see
        :func:`compact_spots`; a learned probability has an absolute level, ``min_peak``,
        and marks an interface in spots as bright as a faint needle's); placed one radius
        below the echo's upper edge (classical) or at the map's own maximum near the spot
        (learned). Returns (centre or None, its robust score, why there is none)."""
        p = self.params
        F, S = maps.F, maps.S
        inner = inner_region(frame, p.mask_edge_mm)
        if not inner.all():
            S = np.where(inner, S, np.float32(maps.med))
        spots, z = compact_spots(S, maps.med, maps.scale, spacing, p.detect_lateral_mm,
                                 p.detect_compact, p.detect_separation_mm)
        if not spots:
            return None, float(z.max()), "no cross-section: no compact spot on the map"
        idx, score = spots[0], float(z[spots[0]])
        if score < p.detect_score:
            return None, score, f"no cross-section (score {score:.1f} < {p.detect_score})"
        if float(S[idx]) < self._min_peak():
            return None, score, (f"no cross-section (smoothed peak {float(S[idx]):.2f} < "
                                 f"{self._min_peak():g})")
        if not self._is_learned() and len(spots) > 1 and \
                score < p.detect_ratio * max(float(z[spots[1]]), 0.0):
            return None, score, (f"no cross-section: the best spot (score {score:.1f}) does "
                                 f"not stand out of the next ({float(z[spots[1]]):.1f})")
        center = np.asarray(idx, dtype=float) + subpixel_peak(S, idx)
        if self._anchor() == "top_edge":
            return below_top_edge(F, center, float(F.mean()),
                                  p.needle_radius_mm / float(spacing[0])), score, ""
        if self._is_learned():  # its own mode: the map is drawn at the needle's scale already
            center = local_peak(F, idx, np.ceil(p.needle_radius_mm / spacing))
        # a map of the wall facing the probe: the centre lies a radius deeper (+z)
        return center + self._wall_offset_rc(spacing), score, ""

    def _model(self, depth: float, from_f0: np.ndarray) -> tuple[AxialModel, np.ndarray | None]:
        """The model after this frame's update (parameters, whole shape), and the needle's
        direction at this slice (None before the model exists)."""
        tr, p = self._track, self.params
        origin_depth = tr.origin_depth if tr.origin_xz is not None else np.nan
        pf_updates = 0 if tr.pf is None else tr.pf.n_updates
        if not self._model_ready():
            nan = np.nan
            return AxialModel(R_mm=nan, theta0_deg=nan, phi_deg=nan, R_sd_mm=nan,
                              theta0_sd_deg=nan, shape_v_mm=None, shape_u_mm=None,
                              origin_xz_mm=None, u_axis_xz=None, origin_depth_mm=origin_depth,
                              rotation_depth_mm=self.rotation_depth_mm,
                              pf_updates=pf_updates), None
        R = from_f0[:3, :3]
        o = R @ np.array([tr.origin_xz[0], 0.0, tr.origin_xz[1]]) + from_f0[:3, 3]
        e = R @ np.array([np.cos(tr.phi), 0.0, np.sin(tr.phi)])
        v_end = max(p.final_depth_mm, depth)
        n = max(int(np.ceil((v_end - tr.origin_depth) / p.shape_step_mm)), 1) + 1
        shape_v = np.linspace(tr.origin_depth, v_end, n)
        u = self._predict_u(np.concatenate([shape_v, [depth - 0.25, depth + 0.25]]))
        axis = e[[0, 2]] / max(float(np.linalg.norm(e[[0, 2]])), 1e-12)
        model = AxialModel(
            R_mm=tr.pf.radius_mm, theta0_deg=tr.pf.theta0_deg,
            phi_deg=float(np.rad2deg(np.arctan2(np.sin(tr.phi), np.cos(tr.phi)))),
            R_sd_mm=float(tr.pf.sigma[0]), theta0_sd_deg=float(tr.pf.sigma[1]),
            shape_v_mm=shape_v, shape_u_mm=u[:-2], origin_xz_mm=o[[0, 2]], u_axis_xz=axis,
            origin_depth_mm=origin_depth, rotation_depth_mm=self.rotation_depth_mm,
            pf_updates=pf_updates)
        return model, axis * (1.0 if u[-1] >= u[-2] else -1.0)  # sign of du/dv
