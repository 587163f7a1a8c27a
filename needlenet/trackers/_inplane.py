"""In-plane needle tracking of Mathiassen et al. 2017 (IEEE TCST 25(3)): the eleven methods of
Table III behind the :class:`Tracker` interface.

| method  | Table III | axis (section II-A)                | tip (section II-B..D)                 |
|---------|-----------|------------------------------------|---------------------------------------|
| df      | 1 DF      | Hough on a segmentation (III-C)    | first gap along the axis              |
| om      | 2 OM      | Algorithm 2, fixed ROI             | argmax h(x)                           |
| om+f    | 3 OM+F    | Algorithm 2, ROI from the last tip | argmax h(x)                           |
| kf      | 4 KF      | Algorithm 2 + KF on theta          | KF with Bayesian candidates (Alg. 4)  |
| kf+f    | 5 KF+F    | feedback ROI + KF on theta         | as kf                                 |
| pf      | 6 PF      | Algorithm 2 + KF on theta          | particle filter on h_pdf (Alg. 5)     |
| pf+f    | 7 PF+F    | feedback ROI + KF on theta         | as pf                                 |
| kfv(+f) | 8, 9      | as kf(+f)                          | KF with the robot's velocity (eq. 19) |
| pfv(+f) | 10, 11    | as pf(+f)                          | PF with the robot's velocity (eq. 23) |

States. ``searching``: every frame runs the detection search (Algorithm 2 without feedback,
over +-5 degrees around the expected insertion angle or, when none is given, over 20-70
degrees) and the needle is taken as found when the shaft contrast along the axis (the mean of
the line echo minus the mean of a tissue band 2-3 mm above it, over the background's spread;
about 0 on tissue and 3-5 on a needle) reaches ``detect_contrast`` over at least
``min_length_mm`` and the echo shows along the axis from the first ray to the tip, not only on
average (:mod:`._inplane_evidence`). Because the fixed ROI's 12 rays span the whole image and
a needle that has just entered meets only two or three of them, the detection searches once
more with the feedback ROI up to the tip it found and keeps the better axis; the filters start
there (the paper starts its method by hand once 10 mm of needle is visible). The needle is
reported from the next frame on, when the detection search finds it there again (within the
tracking search's +-5 degrees of it and ``axis_gate_mm`` of its entry, seen as the tracking
test sees a needle) and the tracking test below sees it; a detection the next
frame does not confirm is dropped and the search runs again. ``tracking``:
each frame measures as its method says; a frame on which the needle is not seen (contrast
below ``keep_contrast``, or no echo along the axis) is not used as a measurement (the filters
only predict) and reports ``lost`` without a tip, and after ``lost_after_frames`` such frames
in a row the tracker forgets its filters and searches again.

The KF on theta (methods 4-11) filters the searched angle; the line at the filtered angle goes
through the centroid of the needle points p_k that lie on the needle (rays up to the last tip
estimate), and the tip features are read along it (Fig. 2: "Axis Est" -> "KF" -> "Tip Est").

Units. The back ends work in the paper's 0.10 mm pixels along the needle axis and seconds, so
that the parameters of section III-B and Table II keep their meaning at any image spacing.
Table II is read in frame units (Delta T = 1 frame): read in seconds, its initial velocity
spread (5 px/s) and velocity noise (0.1 px/s per step) cannot follow an insertion at 50-150 px/s
and the filter lags by several millimetres, while the paper reports a lag of about 1 mm. The
tip filter's candidate selection uses the ``"marginal"`` evidence: eq. (15) as printed depends
on where the axis coordinate starts (here the ROI corner), and lets P(j | x_bar) exceed 1 and
R_k fall below R_MIN; the marginal sum_i P(x_bar | j_i) P(j_i) is the exact Bayes normaliser,
so R_k >= R_MIN as the text intends.

Output. ``tip_mm`` (x, z) on the needle's centre line (the line echo plus the calibrated
``axis_offset_mm`` along v_p for classical features; a learned shaft map is centred already),
``direction`` v_n, ``covariance`` sigma_n^2 v_n v_n^T + sigma_p^2 v_p v_p^T in mm^2 with
sigma_n^2 the tip filter's position variance (R_MIN for OM and DF) and sigma_p^2 the spread of
the needle points across the rays plus the angle's variance times the needle length squared.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from ..backends import (
    MathiassenAngleFilter,
    MathiassenAngleParams,
    MathiassenTipParams,
)
from ..features import (
    PAPER_PX_MM,
    AxisEstimate,
    DFParams,
    FeatureSource,
    Frame,
    MathiassenParams,
    TipWeights,
    axis_vectors,
    ding_fenster,
    estimate_axis,
    load_tip_weights,
    tip_features,
    tip_likelihood,
    tip_map_along_axis,
)
from ._base import NeedleEstimate, Status, Tracker
from ._details import InplaneDetails
from ._inplane_df import DingFensterStep
from ._inplane_evidence import classical_echo_seen, learned_level_reached
from ._inplane_geometry import off_line_mm
from ._inplane_growing import GrowingMarkParams
from ._inplane_tip import TipFiltering, TipStep, mm_to_px

__all__ = ["InplaneParams", "InplaneTracker"]

ENTRY_SIDES = ("auto", "right", "left")
METHODS = ("df", "om", "om+f", "kf", "kf+f", "pf", "pf+f", "kfv", "kfv+f", "pfv", "pfv+f")


@dataclass(frozen=True)
class InplaneParams:
    """Tracker settings; the paper's parameters live in ``axis`` (section III-B), ``angle``
    (the KF on theta) and ``df`` (section III-C); the tip filters take Table II and section
    III-B's PF values (see :meth:`InplaneTracker._make_tip_filter`).

    ``detect_contrast``/``keep_contrast``: shaft contrast to (re)detect and to keep measuring;
    ``lost_after_frames``: frames below ``keep_contrast`` before ``lost``; ``min_length_mm``:
    needle visible from the first ray to the tip needed to detect; ``frame_rate_hz``: None
    takes the rate from the frames' timestamps (20 Hz, the paper's frame grabber, until two
    frames have been seen). ``two_point_start``: without a robot velocity the tip filter
    starts on the frame after the detection, at that frame's maximum of h with the velocity
    of the two measurements (two-point initialisation; a speed above ``max_start_speed_mm_s``
    is taken for an outlier and replaced by 0); otherwise it starts at the detection with
    velocity 0, and with Table II's P_0 and Q the KF then lags for a second or two. All ours;
    the paper starts its method by hand once 10 mm of needle is visible and does not say
    how the velocity starts. ``needle_radius_mm``: the needle's (default Mathiassen's 14 G);
    a learned source that marks the wall facing the probe is moved by it to the centre line.
    ``learned_level``: with a learned source the needle also counts as seen only where its
    shaft probability along the axis averages at least this (the map's decision level; the
    shaft contrast of a clean probability map is large even for a faint response).
    ``echo_z``/``echo_coverage``: with classical features the needle also counts as seen only
    where at least ``echo_coverage`` of the axis's sections (first ray to tip, and of its half
    at the entry) stand ``echo_z`` noise SDs out of the tissue (:mod:`._inplane_evidence`).
    A frame on which the needle is not seen reports ``lost`` without a tip while the filters
    predict through it; after ``lost_after_frames`` such frames the track is forgotten.
    ``axis_gate_mm``: how far from a needle's entry its axis may pass on the next frame (the
    confirmation of a detection; DF's track, :mod:`._inplane_df`); ``growing``: how a line off
    the axis of a needle that left must grow for DF to take it.
    ``entry_side``: the paper's needle enters at the top right; ``"left"`` mirrors every frame
    (and the estimates back) for a needle from the left, and ``"auto"`` detects on both and
    keeps the side where the needle stands out more, deciding again at each detection.
    """

    axis: MathiassenParams = field(default_factory=MathiassenParams)
    angle: MathiassenAngleParams = field(default_factory=MathiassenAngleParams)
    df: DFParams = field(default_factory=DFParams)
    detect_contrast: float = 1.5
    keep_contrast: float = 1.0
    lost_after_frames: int = 3
    min_length_mm: float = 3.0
    frame_rate_hz: float | None = None
    evidence: str = "marginal"
    pf_particles: int = 200
    two_point_start: bool = True
    max_start_speed_mm_s: float = 30.0
    needle_radius_mm: float = 1.054  # 14 G (2.108 mm outer diameter)
    entry_side: str = "auto"
    learned_level: float = 0.5
    # a section of the axis (2s+1 samples) shows the echo at 2 noise SDs of the line-minus-
    # band difference on tissue, the level at which the line tracker takes a pixel for echo;
    # about 5% of sections of arbitrary axes on needle-free frames reach it, never a majority
    echo_z: float = 2.0
    # a straight needle's echo runs along its whole length (Algorithm 1's premise); half of
    # the axis (and of its entry half) leaves room for faint stretches and a tip estimate
    # ahead of the needle; the learned map's decision level, read as a share of the axis
    echo_coverage: float = 0.5
    # a needle pivots at its entry, which moves well under a millimetre between frames; 2 mm
    # leaves room for a 1-degree angle step over a 45 mm axis (0.8 mm) and a 14 G needle's width
    axis_gate_mm: float = 2.0
    growing: GrowingMarkParams = field(default_factory=GrowingMarkParams)

    def __post_init__(self) -> None:
        if self.entry_side not in ENTRY_SIDES:
            raise ValueError(f"entry_side must be one of {', '.join(ENTRY_SIDES)}, got "
                             f"{self.entry_side!r}")
        if not self.needle_radius_mm >= 0:
            raise ValueError(f"needle_radius_mm must be >= 0, got {self.needle_radius_mm}")
        if self.keep_contrast > self.detect_contrast:
            raise ValueError("keep_contrast must not exceed detect_contrast")
        if self.lost_after_frames < 1:
            raise ValueError("lost_after_frames must be >= 1")
        if self.frame_rate_hz is not None and not self.frame_rate_hz > 0:
            raise ValueError(f"frame_rate_hz must be positive, got {self.frame_rate_hz}")
        if not 0.0 < self.axis_gate_mm <= 100.0:
            raise ValueError(f"axis_gate_mm must lie in (0, 100] mm, got {self.axis_gate_mm}")
        if not self.echo_z > 0 or not 0.0 < self.echo_coverage <= 1.0:
            raise ValueError(f"need echo_z > 0 and 0 < echo_coverage <= 1, got {self.echo_z}, "
                             f"{self.echo_coverage}")


def _mirror_estimate(est: NeedleEstimate, grid) -> NeedleEstimate:
    """An estimate made on left-right mirrored frames, in the frames' own coordinates: x ->
    x_first + x_last - x for points, the x component of directions negated."""
    x_sum = 2.0 * float(grid.origin_mm[1]) + (grid.shape[1] - 1) * float(grid.spacing_mm[1])
    flip = np.array([-1.0, 1.0])

    def point(p):
        return None if p is None else np.array([x_sum - p[0], p[1]], float)

    cov = None if est.covariance is None else est.covariance * np.outer(flip, flip)
    return replace(est, tip_mm=point(est.tip_mm),
                   direction=None if est.direction is None else est.direction * flip,
                   covariance=cov, axis_point_mm=point(est.axis_point_mm),
                   details=replace(est.details, mirrored=True))


class InplaneTracker(DingFensterStep, TipFiltering, Tracker):
    """Mathiassen 2017's in-plane trackers (Table III).

    Parameters
    ----------
    method : one of ``df om om+f kf kf+f pf pf+f kfv kfv+f pfv pfv+f``
    features : FeatureSource, default :class:`IntensityFeatures`
        Its ``shaft`` map is searched for the axis; a ``tip`` map, when the source has one,
        replaces the five tip features as h(x).
    expected_angle_deg : float or None
        Insertion angle to the skin the searches centre on (+-5 degrees, section III-C). None:
        the detection searches 20-70 degrees and the tracker then centres on what it found.
    params : InplaneParams
    rng, seed : Generator, int or None
        Random source of the particle filters (``seed`` is an alias of ``rng``).
    weights : TipWeights, path or None
        The weights of h(x); None loads ``needlenet/data/mathiassen_weights.json`` (loaded at
        construction for classical sources, raising FileNotFoundError with the command that
        makes it when missing; a learned source with a tip map does not need it).
    """

    modality = "inplane"
    methods = METHODS

    def __init__(self, method: str = "kf+f", features: FeatureSource | None = None, *,
                 expected_angle_deg: float | None = None, params: InplaneParams | None = None,
                 rng: np.random.Generator | int | None = None, seed: int | None = None,
                 weights: TipWeights | str | None = None):
        self.params = InplaneParams() if params is None else params
        if expected_angle_deg is not None:
            lo, hi = self.params.axis.full_range_deg
            if not lo <= float(expected_angle_deg) <= hi:
                raise ValueError(f"expected_angle_deg must lie in [{lo}, {hi}], "
                                 f"got {expected_angle_deg}")
        self.expected_angle_deg = None if expected_angle_deg is None else float(
            expected_angle_deg)
        self._weights_arg = weights
        self._weights: TipWeights | None = None
        super().__init__(method, features, rng=rng, seed=seed)
        if self.features.kind == "classical":
            self.tip_weights()  # fail here, not on the first frame, when the file is missing
        self.feedback = method.endswith("+f")
        self.filter_kind = method[:2] if method[:2] in ("kf", "pf") else None
        self.use_velocity = method.startswith(("kfv", "pfv"))
        self._history: deque = deque(maxlen=self.params.axis.delta_frames)
        self._last_t: float | None = None
        self._dt: float | None = None
        self._mirrored = self.params.entry_side == "left"
        self._forget_departed()

    # ------------------------------------------------------------------ state

    def reset(self) -> None:
        """Forget the needle (filters, feedback tip, angle); the next frame searches."""
        super().reset()
        self._clear_track()
        if hasattr(self, "_history"):
            self._history.clear()
            self._forget_departed()

    def _clear_track(self) -> None:
        self._tip_filter = None
        self._angle_filter: MathiassenAngleFilter | None = None
        self._tip_along_mm: float | None = None
        self._theta_ref: float | None = None
        self._misses = 0
        self._first_fix: tuple[float, float] | None = None
        self._confirming = False
        self._df_line: tuple[np.ndarray, np.ndarray] | None = None  # DF: entry, direction
        self._df_reported = False

    def tip_weights(self) -> TipWeights:
        """The weights of h(x), loaded on first use."""
        if self._weights is None:
            w = self._weights_arg
            self._weights = w if isinstance(w, TipWeights) else load_tip_weights(w)
        return self._weights

    # ------------------------------------------------------------------ one frame

    def _step(self, frame: Frame) -> NeedleEstimate:
        if frame.grid.ndim != 2:
            raise ValueError(f"InplaneTracker needs 2-D images, got a {frame.grid.ndim}-D grid")
        self._update_dt(frame.t)
        lik = self.features.likelihood(frame)
        shaft = np.asarray(lik.shaft, dtype=np.float32)
        previous = self._history[0] if self._history else None  # I_{k-delta}, eq. (8)
        if previous is not None and previous.shape != shaft.shape:
            self._history.clear()
            previous = None
        try:
            if self._tip_along_mm is not None:  # a track, possibly through unseen frames
                est = self._track(frame, *self._oriented(shaft, previous, lik.tip))
            else:
                est = self._detect_either_side(frame, shaft, previous, lik.tip)
        finally:
            if lik.tip is None:
                self._history.append(shaft.copy())
        return _mirror_estimate(est, frame.grid) if self._mirrored else est

    def _oriented(self, *maps):
        """The maps as the paper's geometry wants them: mirrored for a needle from the left."""
        if not self._mirrored:
            return maps
        return tuple(None if m is None else np.asarray(m)[:, ::-1] for m in maps)

    def _detect_either_side(self, frame, shaft, previous, tip_map) -> NeedleEstimate:
        """Detection on the side ``entry_side`` names; with ``"auto"`` on both (the frames as
        they are and mirrored), keeping the side whose needle has the larger shaft contrast
        (the paper's own detection measure; for DF, the larger Hough value)."""
        side = self.params.entry_side
        if side != "auto":
            return self._detect(frame, *self._oriented(shaft, previous, tip_map))
        if self.method == "df":  # DF's own measure: the Hough votes of its axis
            votes = []
            centre = self.expected_angle_deg if self.expected_angle_deg is not None else \
                self._theta_ref
            for mirrored in (False, True):
                self._mirrored = mirrored
                res = ding_fenster(self._oriented(shaft)[0], frame.grid, centre, self.params.df)
                votes.append(res.votes if res else -1)
            self._mirrored = bool(np.argmax(votes))
            return self._detect(frame, *self._oriented(shaft, previous, tip_map))
        found = []
        for mirrored in (False, True):
            self._mirrored = mirrored
            cand = self._find(frame, *self._oriented(shaft, previous, tip_map))
            found.append(cand)
        # a side whose needle is too short to detect does not compete
        scores = [c[4] if c[3] - float(c[0].rays_mm[0]) >= self.params.min_length_mm
                  else -np.inf for c in found]
        best = int(np.argmax(scores))
        self._mirrored = bool(best)
        return self._commit_detection(frame, *self._oriented(shaft, previous, tip_map),
                                      found[best])

    def _update_dt(self, t: float) -> None:
        if self.params.frame_rate_hz is not None:
            self._dt = 1.0 / self.params.frame_rate_hz
        elif self._last_t is not None and t > self._last_t and self._dt is None:
            self._dt = float(t - self._last_t)
        self._last_t = float(t)

    @property
    def dt_s(self) -> float:
        return self._dt if self._dt is not None else 1.0 / 20.0

    def _search_range(self, detecting: bool = False) -> dict:
        """The angles Algorithm 2 searches: around the track's angle, or for a detection
        (``detecting``, or no track) around the expected angle or over the full range."""
        if self._theta_ref is not None and not detecting:
            centre = self._theta_ref
            if self._angle_filter is not None:
                centre = self._angle_filter.theta_deg
            return {"theta_centre_deg": centre}
        if self.expected_angle_deg is not None:
            return {"theta_centre_deg": self.expected_angle_deg}
        return {"theta_range_deg": self.params.axis.full_range_deg}

    def _measure(self, image, previous, tip_map, grid, axis: AxisEstimate):
        """Tip features and h(x) along the axis (Algorithm 3)."""
        if tip_map is not None:
            return tip_map_along_axis(image, np.asarray(tip_map, np.float32), grid, axis,
                                      self.params.axis)
        feats = tip_features(image, previous, grid, axis, self.params.axis)
        return feats, tip_likelihood(feats, self.tip_weights().weights)

    def _offset_mm(self, tip_map) -> float:
        """Line echo to centre line along v_p: the calibrated offset for classical features;
        the needle's radius for a learned source that marks the wall facing the probe."""
        if tip_map is None:
            return self.tip_weights().axis_offset_mm
        if getattr(self.features, "target_reference", "centerline") == "wall":
            return self.params.needle_radius_mm
        return 0.0

    def _tip_positions_mm(self, feats, tip_map) -> np.ndarray:
        """Where each sample of h(x) puts the tip: x plus the fitted ``tip_offset_mm``."""
        shift = 0.0 if tip_map is not None else self.tip_weights().tip_offset_mm
        return feats.x_mm + shift

    # detection --------------------------------------------------------------------------

    def _detect(self, frame, image, previous, tip_map) -> NeedleEstimate:
        if self.method == "df":
            return self._df(frame, image, previous, tip_map, detecting=True)
        return self._commit_detection(frame, image, previous, tip_map,
                                      self._find(frame, image, previous, tip_map))

    def _find(self, frame, image, previous, tip_map):
        """Algorithm 2's axis and the tip along it on one frame, searched as a detection is:
        (axis, feats, h, x_tip, contrast)."""
        p = self.params
        grid = frame.grid
        axis = estimate_axis(image, grid, p.axis, **self._search_range(detecting=True))
        feats, h = self._measure(image, previous, tip_map, grid, axis)
        x_tip = float(self._tip_positions_mm(feats, tip_map)[int(np.argmax(h))])
        first = float(axis.rays_mm[0])
        contrast = feats.shaft_contrast(first, x_tip)
        if x_tip - first >= p.min_length_mm:
            # the fixed ROI spans the image while a short needle meets only a few of its rays:
            # search again with rays from the corner to the tip just found (the "+F" ROI)
            fine = estimate_axis(image, grid, p.axis, theta_centre_deg=axis.theta_deg,
                                 tip_along_mm=x_tip)
            feats_f, h_f = self._measure(image, previous, tip_map, grid, fine)
            x_tip_f = float(self._tip_positions_mm(feats_f, tip_map)[int(np.argmax(h_f))])
            contrast_f = feats_f.shaft_contrast(first, x_tip_f)
            if contrast_f >= contrast:
                axis, feats, h, x_tip, contrast = fine, feats_f, h_f, x_tip_f, contrast_f
        return axis, feats, h, x_tip, contrast

    def _commit_detection(self, frame, image, previous, tip_map, found) -> NeedleEstimate:
        """Start tracking on ``found`` (:meth:`_find`'s result) when it is a needle."""
        p = self.params
        axis, feats, h, x_tip, contrast = found
        first = float(axis.rays_mm[0])
        seen, cover = self._needle_seen(feats, first, x_tip)
        if contrast < p.detect_contrast or x_tip - first < p.min_length_mm or not seen:
            details = InplaneDetails(contrast, theta_measured_deg=axis.theta_deg,
                                     echo_coverage=cover)
            return NeedleEstimate(t=frame.t, status=self.status, reason="no needle found",
                                  details=details)
        self._start_track(axis, x_tip, frame)
        return self._unconfirmed(frame, contrast, axis.theta_deg, cover)

    def _start_track(self, axis: AxisEstimate, x_tip_mm: float, frame: Frame) -> None:
        self._clear_track()
        self._theta_ref = axis.theta_deg if self.expected_angle_deg is None else \
            self.expected_angle_deg
        self._detected_axis = axis
        if self.filter_kind is not None:
            self._angle_filter = MathiassenAngleFilter(self.params.angle, axis.theta_deg)
            velocity = self._velocity_px_s(frame)
            if velocity is None and self.params.two_point_start:
                self._first_fix = (x_tip_mm, float(frame.t))  # the filter starts next frame
            else:
                self._tip_filter = self._make_tip_filter(float(mm_to_px(x_tip_mm)), velocity)
        self._tip_along_mm = x_tip_mm
        self._confirming = True

    def _unconfirmed(self, frame, contrast: float, theta_deg: float,
                     cover: float | None) -> NeedleEstimate:
        """A detection's own frame: the track starts, and the needle is reported once it is
        found again on the next frame (a tissue line that passes every single-frame test on
        one frame rarely does so on the next, or loses the search to a needle in view)."""
        return NeedleEstimate(t=frame.t, status=self.status,
                              reason="needle found; reported when seen on the next frame",
                              details=InplaneDetails(contrast, theta_measured_deg=theta_deg,
                                                     echo_coverage=cover))

    def _found_again(self, frame, image, previous, tip_map) -> tuple[bool, float, float | None]:
        """Whether the detection search, run again on the frame after a detection, finds the
        detected needle there, seen as the tracking test sees it: its axis within the tracking
        search's angles of the detected one and passing within ``axis_gate_mm`` of its entry
        (a tissue line the search took while no needle was in view gives way to a needle that
        is); with its shaft contrast and echo coverage."""
        p = self.params
        axis, feats, _, x_tip, contrast = self._find(frame, image, previous, tip_map)
        first = float(axis.rays_mm[0])
        seen, cover = self._needle_seen(feats, first, x_tip)
        before = self._detected_axis
        off = off_line_mm(before.point_mm(float(before.rays_mm[0])), axis.point_mm(0.0),
                          axis.direction)
        again = (seen and contrast >= p.keep_contrast and off <= p.axis_gate_mm
                 and abs(axis.theta_deg - before.theta_deg) <= p.axis.search_half_range_deg)
        return again, contrast, cover

    def _not_confirmed(self, frame, contrast: float, cover: float | None) -> NeedleEstimate:
        """The frame after a detection does not show the needle: the detection is dropped."""
        self._clear_track()
        return NeedleEstimate(t=frame.t, status=self.status,
                              reason="the needle found on the frame before is not seen",
                              details=InplaneDetails(contrast, echo_coverage=cover))

    # tracking ---------------------------------------------------------------------------

    def _track(self, frame, image, previous, tip_map) -> NeedleEstimate:
        p = self.params
        grid = frame.grid
        if self.method == "df":
            return self._df(frame, image, previous, tip_map, detecting=False)
        if self._confirming:
            again, contrast, cover = self._found_again(frame, image, previous, tip_map)
            if not again:
                return self._not_confirmed(frame, contrast, cover)
        tip_along = self._tip_along_mm if self.feedback else None
        axis = estimate_axis(image, grid, p.axis, tip_along_mm=tip_along,
                             **self._search_range())
        theta_measured = axis.theta_deg
        angle_before = None if self._angle_filter is None else self._angle_filter.copy()
        if self._angle_filter is not None:
            theta_kf = self._angle_filter.step(axis.theta_deg)  # Algorithm 4, line 16
            axis = axis.rotated(theta_kf, upto_mm=self._tip_along_mm)
        feats, h = self._measure(image, previous, tip_map, grid, axis)
        first = float(axis.rays_mm[0])
        upto = max(self._tip_along_mm, first + p.min_length_mm)
        contrast = feats.shaft_contrast(first, upto)
        seen, cover = self._needle_seen(feats, first, upto)
        seen = seen and contrast >= p.keep_contrast
        if not seen:  # no needle, no angle measured: the KF on theta keeps its estimate
            self._angle_filter = angle_before
            if self._confirming:
                return self._not_confirmed(frame, contrast, cover)
        confirmed_now, self._confirming = self._confirming, False
        self._misses = 0 if seen else self._misses + 1
        if self._misses >= p.lost_after_frames:
            self._clear_track()
            return NeedleEstimate(t=frame.t, status=Status.LOST,
                                  reason=f"no needle seen for {p.lost_after_frames} frames",
                                  details=InplaneDetails(contrast, echo_coverage=cover))
        step = self._tip_step(self._tip_positions_mm(feats, tip_map), h, seen, frame)
        self._tip_along_mm = step.along_mm
        if not seen:  # the filters predict through the frame; it reports no needle
            return NeedleEstimate(t=frame.t, status=Status.LOST,
                                  reason="no needle seen on this frame",
                                  details=InplaneDetails(contrast, coasting=True,
                                                         echo_coverage=cover))
        return self._estimate(frame, axis, step, h, feats, contrast, tip_map, theta_measured,
                              detected=confirmed_now, coverage=cover)

    def _needle_seen(self, feats, x_from_mm: float, x_to_mm: float
                     ) -> tuple[bool, float | None]:
        """Whether the needle's echo shows along the axis in [x_from, x_to] (see
        :mod:`._inplane_evidence`), and for classical features the share of its sections that
        show it."""
        p = self.params
        if self.features.kind == "learned":
            return learned_level_reached(feats, x_from_mm, x_to_mm, p.learned_level), None
        step = float(feats.x_mm[1] - feats.x_mm[0]) if len(feats.x_mm) > 1 else 1.0
        n = 2 * max(1, int(round(p.axis.ray_half_width_mm / step))) + 1  # 2s+1, eq. (1)
        return classical_echo_seen(feats, x_from_mm, x_to_mm, n, p.echo_z, p.echo_coverage)

    # output -----------------------------------------------------------------------------

    @staticmethod
    def _covariance(theta_deg: float, var_n_px2: float, var_p_mm2: float,
                    var_theta_deg2: float, length_mm: float) -> np.ndarray:
        """sigma_n^2 v_n v_n^T + sigma_p^2 v_p v_p^T in mm^2."""
        vn, vp = axis_vectors(theta_deg)
        var_n = var_n_px2 * PAPER_PX_MM**2
        var_p = var_p_mm2 + np.deg2rad(np.sqrt(var_theta_deg2)) ** 2 * max(length_mm, 0.0) ** 2
        return var_n * np.outer(vn, vn) + var_p * np.outer(vp, vp)

    def _estimate(self, frame, axis: AxisEstimate, step: TipStep, h, feats, contrast: float,
                  tip_map, theta_measured_deg: float, detected: bool = False,
                  coverage: float | None = None) -> NeedleEstimate:
        offset = self._offset_mm(tip_map)
        x_tip, var_px2 = step.along_mm, step.var_px2
        tip = axis.point_mm(x_tip, offset)
        if var_px2 is None:
            var_px2 = float(MathiassenTipParams().r_min_px2)  # OM: R_MIN
        n_rays = max(len(axis.points_mm), 1)
        var_p = float(np.var(axis.points_mm)) / n_rays + 1.0 / 12.0 * float(
            min(frame.grid.spacing_mm)) ** 2
        var_theta = self._angle_filter.variance_deg2 if self._angle_filter is not None else \
            self.params.angle.r_theta_deg2
        cov = self._covariance(axis.theta_deg, var_px2, var_p, var_theta,
                               x_tip - float(axis.rays_mm[0]))
        at_end = x_tip >= float(feats.x_mm[-1]) - self.params.axis.region_length_mm
        return NeedleEstimate(
            t=frame.t, status=Status.TRACKING, tip_mm=tip, direction=axis.direction,
            covariance=cov, axis_point_mm=axis.point_mm(0.0, offset),
            details=InplaneDetails(
                contrast, theta_measured_deg=theta_measured_deg, theta_deg=axis.theta_deg,
                p_p_mm=axis.p_p_mm + offset, tip_along_mm=x_tip, h_peak=float(np.max(h)),
                h_max=axis.h_max, n_rays=int(len(axis.rays_mm)),
                tip_at_image_edge=bool(at_end), detected=detected, velocity=step.velocity,
                candidates=step.candidates, measurement_accepted=step.accepted,
                tip_velocity_mm_s=step.velocity_mm_s, tip_measurement_mm=step.measurement_mm,
                echo_coverage=coverage))
