"""Parameters of the volume trackers, one class per concern, composed by
:class:`VolumeTrackerParams`.

Each field says what it means, its unit and why it has its default; the measurements behind
the defaults (seeds, failure rates, timings) are in ``docs/notes/volume-tracker.md``.
:class:`VolumeTrackerParams` takes and reads every field under its own name too
(``VolumeTrackerParams(max_trials=200).max_trials``), as ``needlenet track --param NAME=VALUE``
sets it; ``GROUP.NAME`` (``measurement.max_trials``) names the same field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import ClassVar

import numpy as np

from ...backends import InsertionParams
from ...features import FrangiParams

__all__ = ["ChatelainParams", "LearnedPlacementParams", "MeasurementParams", "RoiRkParams",
           "VolumeTrackerParams"]


def _check_positive(owner, names) -> None:
    for name in names:
        value = getattr(owner, name)
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{type(owner).__name__}.{name} must be finite and > 0, "
                             f"got {value}")


def _check_non_negative(owner, names) -> None:
    for name in names:
        value = getattr(owner, name)
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{type(owner).__name__}.{name} must be finite and >= 0, "
                             f"got {value}")


def _check_integers(owner, lows) -> None:
    for name, low in lows:
        value = getattr(owner, name)
        if isinstance(value, bool) or int(value) != value or value < low:
            raise ValueError(f"{type(owner).__name__}.{name} must be an integer >= {low}, "
                             f"got {value!r}")


@dataclass(frozen=True)
class MeasurementParams:
    """One measurement in a volume, shared by the three methods: candidates, RANSAC (Zhao
    2013 App. B, Chatelain 2013 II-D), least squares, the tip where the feature drops.

    Attributes
    ----------
    threshold_percentile : float
        T_I of eq. (B1) as a percentile of the imaged sector's voxels: Zhao's "99% of the
        voxels are from the background" (voxels outside the sector are 0, not tissue).
    intensity_threshold : float or None
        A fixed T_I in gray levels (0-255) instead of the percentile, as Zhao's Table 3 varies
        it from 60 to 100 (classical features only). None: the percentile.
    percentile_stride : int
        T_I is estimated on every ``stride``-th voxel per axis: 2 keeps ~10^5 voxels of a
        128^3 volume, plenty for a percentile, at 1/8 of the cost.
    inlier_radius_mm : float
        r of eq. (B5) (Chatelain's f0, eq. (19)), "the expected radius of the needle in the
        image": the 0.5 mm radius plus half a voxel diagonal of a 128^3 volume.
    min_sample_distance_mm : float
        d_min of App. B (Zhao gives none): 2 mm, as two points closer than four needle radii
        fix the direction poorly.
    max_trials : int
        J_max: Zhao caps RANSAC at 50 trials "to limit the processing time".
    init_max_trials : int
        The cap where the inlier ratio is lowest: roi-rk's initialisation, Chatelain's fit
        after an insertion and in its VOI. Ours: 1000.
    entry_margin_mm : float
        A needle found at initialisation must start this close to the sector's boundary (Zhao:
        "inserted from the outside"); 5 mm, as a moving phantom carries the entry ~4 mm in.
    success_probability : float
        eta of eq. (B8) (1 - epsilon of Chatelain eq. (21)).
    batch_size : int
        Hypotheses drawn and scored at once; eq. (B8)'s adaptive count is checked between
        batches, so small batches stop early.
    refine_iterations : int
        Least-squares refinements of RANSAC's winner (local optimisation, eq. (B6)).
    min_inliers : int
        Fewer inliers (or candidates) than this and no needle is found.
    min_length_mm : float
        Shortest visible needle (entry to tip, mm) that counts as a needle.
    max_gap_mm : float
        Gaps along the axis shorter than this are bridged when looking for the tip (Chatelain
        II-D: "we discard small intensity gaps"); they also split the inliers into pieces.
    profile_radius_mm : float
        The profile along the axis is the maximum over the axis and six lines this far from
        it (half a needle radius), so one dark needle voxel or a sub-voxel axis error is no drop.
    tip_cap_mm : float
        The needle's image ends this far beyond its tip: Zhao's needle ends in a cap of one
        radius (eq. (9)), which the profile's interpolation stretches by ~0.1 mm. 0.6 mm.
    likelihood_threshold : float
        Learned features: likelihood above which a voxel is needle when
        ``likelihood_relative`` is None.
    likelihood_floor : float
        Learned features: voxels below this likelihood never become candidates.
    likelihood_relative : float or None
        Learned features: the tip is where the likelihood drops below this fraction of its
        median along the fitted needle (a half-maximum: a map's scale varies, its drop does not).
    max_candidates : int
        Learned features: at most this many candidates, the most likely ones.
    """

    threshold_percentile: float = 99.0
    intensity_threshold: float | None = None
    percentile_stride: int = 2
    inlier_radius_mm: float = 0.75
    min_sample_distance_mm: float = 2.0
    max_trials: int = 50
    init_max_trials: int = 1000
    entry_margin_mm: float = 5.0
    success_probability: float = 0.99
    batch_size: int = 16
    refine_iterations: int = 2
    min_inliers: int = 10
    min_length_mm: float = 3.0
    max_gap_mm: float = 1.0
    profile_radius_mm: float = 0.25
    tip_cap_mm: float = 0.6
    likelihood_threshold: float = 0.5
    likelihood_floor: float = 0.05
    likelihood_relative: float | None = 0.5
    max_candidates: int = 20_000

    def __post_init__(self):
        _check_positive(self, ("inlier_radius_mm", "min_length_mm", "profile_radius_mm"))
        _check_non_negative(self, ("min_sample_distance_mm", "max_gap_mm", "tip_cap_mm",
                                   "entry_margin_mm"))
        if not 0.0 < self.threshold_percentile < 100.0:
            raise ValueError(f"threshold_percentile must be in (0, 100), "
                             f"got {self.threshold_percentile}")
        if not 0.0 <= self.success_probability < 1.0:
            raise ValueError(f"success_probability must be in [0, 1), "
                             f"got {self.success_probability}")
        _check_integers(self, (("percentile_stride", 1), ("max_trials", 1),
                               ("init_max_trials", 1), ("batch_size", 1),
                               ("refine_iterations", 0), ("min_inliers", 2),
                               ("max_candidates", 2)))
        if not 0.0 < self.likelihood_floor <= self.likelihood_threshold < 1.0:
            raise ValueError("need 0 < likelihood_floor <= likelihood_threshold < 1")


@dataclass(frozen=True)
class LearnedPlacementParams:
    """Learned features: the map finds the needle, the B-mode image places its axis and tip.

    Attributes
    ----------
    image_refine : bool
        Refit the map's straight axis on the image in narrowing tubes and take the tip from the
        image's change point (Zhao's local optimisation, eq. (B6), on the image's voxels).
    image_refine_radii_mm : tuple of float
        Radii of the successive tubes (mm), widest first: the first catches an axis a few
        tenths of a millimetre off, the last (~1.5 needle radii) keeps tissue out of the fit.
    image_refine_percentile : float
        Voxels above this percentile of a tube pull the axis, each by its excess: the needle
        fills a small part of the widest tube.
    image_refine_keep_depth : bool
        The image moves the axis across the beam only; along the depth (z) the map's position
        stands, as a needle's echo comes from its wall facing the probe, a radius above its axis.
    image_tip_radius_mm : float
        The image along the axis is averaged over the axis and six lines this far from it
        (about the needle's radius).
    image_tip_window_mm : float
        The change point maximises the image's mean over this length behind it minus the mean
        over this length ahead.
    image_tip_search_mm : float
        The change point is looked for within this distance of the map's likelihood drop,
        which can fall short of the tip where the contrast is low.
    image_tip_track_search_mm : float
        While roi-rk or chatelain track, within this distance of the filter's predicted tip
        instead: the ROI's prior along the axis, as eq. (1) gives it across. 6 mm.
    image_tip_cap_mm : float
        The image's change point lies this far beyond the tip (the echo spreads past the end):
        0.35 mm, calibrated on training seeds.
    image_tip_min_effect : float
        The change stands only when it is this many pooled standard deviations of the profile
        in its two windows; otherwise the map's drop does. 1.5, from training seeds.
    image_tip_background_mm : (float, float) or None
        Inner and outer radius (mm) of a ring of lines whose mean, the tissue beside the
        needle, is subtracted from the profile, so a change of the tissue is no tip. None: raw.
    tip_window_mm : float
        With a learned tip channel: move the tip to the tip map's maximum within this distance
        of the shaft's drop. 0 (off): the shipped 3D model's tip channel is not accurate enough.
    tip_min : float
        The tip map's maximum must reach this likelihood to move the tip.
    """

    image_refine: bool = True
    image_refine_radii_mm: tuple[float, ...] = (1.5, 1.0, 0.75)
    image_refine_percentile: float = 70.0
    image_refine_keep_depth: bool = True
    image_tip_radius_mm: float = 0.5
    image_tip_window_mm: float = 4.0
    image_tip_search_mm: float = 8.0
    image_tip_track_search_mm: float = 6.0
    image_tip_cap_mm: float = 0.35
    image_tip_min_effect: float = 1.5
    image_tip_background_mm: tuple[float, float] | None = (2.0, 3.0)
    tip_window_mm: float = 0.0
    tip_min: float = 0.3

    def __post_init__(self):
        _check_positive(self, ("image_tip_radius_mm", "image_tip_window_mm",
                               "image_tip_search_mm", "image_tip_min_effect",
                               "image_tip_track_search_mm"))
        _check_non_negative(self, ("tip_window_mm", "image_tip_cap_mm"))
        radii = self.image_refine_radii_mm
        if not (isinstance(radii, tuple) and all(
                isinstance(r, (int, float)) and np.isfinite(r) and r > 0 for r in radii)):
            raise ValueError(f"LearnedPlacementParams.image_refine_radii_mm must be a tuple of "
                             f"finite radii > 0 (mm), got {radii!r}")
        if not 0.0 <= self.image_refine_percentile < 100.0:
            raise ValueError(f"image_refine_percentile must be in [0, 100), "
                             f"got {self.image_refine_percentile}")
        ring = self.image_tip_background_mm
        if ring is not None and not (
                isinstance(ring, tuple) and len(ring) == 2
                and all(isinstance(r, (int, float)) and np.isfinite(r) for r in ring)
                and 0.0 < ring[0] < ring[1]):
            raise ValueError(f"LearnedPlacementParams.image_tip_background_mm must be None or "
                             f"(inner, outer) radii in mm with 0 < inner < outer, got {ring!r}")


@dataclass(frozen=True)
class RoiRkParams:
    """Zhao 2013's ROI-RK: initialisation on the tubularness, a cylindrical ROI around the
    predicted axis (eq. (1)), speckle tracking (eq. (5)) and the Kalman filter of eqs. (2)-(4).

    Attributes
    ----------
    init_attempts : int
        Sequential RANSAC at initialisation: a hypothesis that is no needle inserted from
        outside is set aside with its inliers and RANSAC runs again, this many times at most.
    init_select : str
        Which found needle the initialisation takes: ``"support"``, RANSAC's largest support
        (Zhao); ``"likelihood"`` (learned features), a clearly more likely competitor.
    init_select_ratio : float
        A competitor replaces RANSAC's choice when the map's median along it is more than this
        many times the choice's: a long tissue line can out-support a short, likely needle.
    init_min_likelihood : float
        Learned features: a found axis whose median likelihood is below this is set aside (0:
        no floor). The figure of Chatelain's tracker: an interface, a sheet on the map, gives
        RANSAC a line along it at a likelihood well under a needle's.
    init_min_contrast : float
        Classical features: a found axis whose image is not this many times as bright as the
        tissue 2-3 mm around it is set aside (0: no test); Chatelain's tracker's figure.
    init_max_sheet : float
        Learned features: a found axis whose map stands up more than this on two opposite
        sides of a ring 2-3 mm around it, over the ring's mean (:func:`map_sheet`), is set
        aside (0: no test): a needle is a tube of evidence (about 1), a line lying in an
        interface's sheet is not (1.4-3). Chatelain's tracker's figure.
    init_tip_margin_mm : float
        A found axis whose tip lies closer than this to the sector's boundary along the needle
        is set aside (0: no test): Zhao tracks a tip inside the volume, and a line that runs on
        out of it (a tissue interface's sheet crossed from face to face) shows none. Chatelain's
        tracker's figure, 1.5 mm: beyond the tip cap and a voxel.
    roi_radius_mm : float
        R_ROI of eq. (1) (not given): five needle radii, Zhao's contrast cylinder (eq. (9)),
        wide for the initial axis error and a moving tip, narrow for an inlier ratio > 0.4.
    max_axis_jump_deg : float
        The ROI has lost the needle when the fitted axis turns more than this from the
        predicted one.
    max_axis_shift_mm : float
        ... or passes farther than this from the predicted tip.
    frangi : FrangiParams
        Line filter of the classical initialisation (App. A).
    speckle_kernel_mm : float
        Half size of the kernel region around the tip for speckle tracking (eq. (5)).
    speckle_search_mm : float
        Extra search margin for speckle tracking; bounds the tip's displacement per volume.
    q_angle, q_tip : float
        Process noise of eqs. (2)-(3) on the angles (rad^2/s^3) and the tip (mm^2/s^3); Zhao
        does not report his, ours were tuned by repeated trials as his were.
    r_angle, r_position : float
        Measurement variances of the angles (rad^2) and the tip (mm^2; RANSAC's tip lies
        within 0.1-0.2 mm, so 0.2^2). ransac reports ``r_position * I`` as its covariance.
    r_velocity : float
        Variance of the speckle-tracked tip velocity (mm^2/s^2): large (2^2), as static
        speckle competes with the needle and the tip positions should carry the velocity.
    p0_angle_rate, p0_velocity : float
        Initial variances of the angular rates (rad^2/s^2) and of the tip velocity
        (mm^2/s^2); Zhao starts both at zero.
    rival_check_volumes : int
        While tracking, the initialisation runs again every this many volumes without the
        tracked line's ROI (0: never), looking for a needle that advances while the tracked
        line stands still (a bright tissue line taken at the start).
    rival_advance_mm : float
        How far that needle must have advanced along its axis since it was first seen, while
        the tracked tip moved less than half as far, to take the track over (ten times the tip
        measurement's 0.2 mm noise).
    prove_within_s : float
        A new track whose measured tip has not advanced half ``rival_advance_mm`` along its
        axis within this time is dropped as a still tissue line and its line remembered (0:
        no test): 2 s, two volumes at Zhao's 1 volume/s in which his 1 mm/s needle advances
        2 mm; a needle held still when it is first seen is taken once it moves.
    """

    init_attempts: int = 5
    init_select: str = "likelihood"
    init_select_ratio: float = 1.2
    init_min_likelihood: float = 0.25
    init_min_contrast: float = 1.8
    init_max_sheet: float = 1.3
    init_tip_margin_mm: float = 1.5
    roi_radius_mm: float = 2.5
    max_axis_jump_deg: float = 15.0
    max_axis_shift_mm: float = 2.5
    frangi: FrangiParams = FrangiParams()
    speckle_kernel_mm: float = 1.5
    speckle_search_mm: float = 2.0
    q_angle: float = 1e-3
    q_tip: float = 1.0
    r_angle: float = math.radians(1.0) ** 2
    r_position: float = 0.04
    r_velocity: float = 4.0
    p0_angle_rate: float = math.radians(5.0) ** 2
    p0_velocity: float = 25.0
    rival_check_volumes: int = 4
    rival_advance_mm: float = 2.0
    prove_within_s: float = 2.0

    def __post_init__(self):
        _check_positive(self, ("roi_radius_mm", "max_axis_jump_deg", "max_axis_shift_mm",
                               "speckle_kernel_mm", "q_angle", "q_tip", "r_angle",
                               "r_position", "r_velocity", "p0_angle_rate", "p0_velocity",
                               "init_select_ratio", "rival_advance_mm"))
        _check_non_negative(self, ("speckle_search_mm", "init_min_likelihood",
                                   "init_min_contrast", "init_max_sheet", "init_tip_margin_mm",
                                   "prove_within_s"))
        _check_integers(self, (("init_attempts", 1), ("rival_check_volumes", 0)))
        if self.init_select not in ("support", "likelihood"):
            raise ValueError(f"init_select must be 'support' or 'likelihood', "
                             f"got {self.init_select!r}")


@dataclass(frozen=True)
class ChatelainParams:
    """Chatelain 2013: insertion detection (II-B), a constant-velocity Kalman filter on the
    curve's control points (eqs. (3)-(14)) and RANSAC in a VOI around the prediction (II-D).

    Attributes
    ----------
    insertion : InsertionParams
        Detection (II-B): tau = 110 mm^2 separates a moving needle from a static needle-free
        volume on Zhao volumes; delta = 15 mm, measured to the sector's boundary.
    insertion_candidates_mm3 : float or None
        Size of eq. (1)'s candidate set as a volume, so it means the same at every voxel size:
        2.7 mm^3, the 100 voxels of a 128^3 volume. None: ``insertion.n_candidates``.
    n_control_points : int
        n of eq. (3): 2 for a straight needle, 3 for a flexible one.
    voi_radius_mm : float
        The VOI holds the voxels closer than this to the predicted curve.
    voi_margin_mm : float
        ... extended this far beyond both ends (the tip moves 0.6 mm per volume at 3 mm/s and
        5 volumes/s); a tip farther than this from the prediction is refused.
    voi_candidates_mm3 : float
        Fixed size of eq. (15)'s candidate set as a volume: 10 mm^3, about 11 mm of a
        0.5-mm-radius needle.
    init_voi_radius_mm : float
        Radius of the ball around the detected change where the needle is first fitted.
    max_angle_deg : float
        alpha_0 of eq. (22).
    detection_window : int
        Volumes after a detection during which the needle is looked for.
    start_length_mm : float
        Tracking starts once this much needle is visible ("inserted with a sufficient
        length", II-A; no figure given): a 3 mm piece fixes no direction. 5 mm.
    start_min_likelihood : float
        Learned features: start only on a needle whose median likelihood along the fit reaches
        this (0: no floor), as moving tissue near a face also changes the map.
    start_tip_margin_mm : float
        Start only on a tip at least this far inside the sector along the needle (0: no test):
        a needle running out of the volume shows its exit. 1.5 mm, beyond the cap and a voxel.
    start_min_contrast : float
        Classical features: start only on a needle at least this many times as bright as the
        tissue 2-3 mm around it (0: no test); 1.8 lies between tissue lines and needles.
    start_max_sheet : float
        Learned features: start only on a needle whose map, on a ring 2-3 mm around it, stands
        up on two opposite sides no more than this over the ring's mean (:func:`map_sheet`; 0:
        no test): a needle's evidence is a tube (0.5-1.1 on synth and PyMUST volumes), a line
        lying in an interface's sheet has the sheet on both sides (1.4-3.2). 1.3 lies between.
    q_control : float
        Process noise of the constant-velocity model, eqs. (4)-(9) (mm^2/s^3): allows a
        withdrawal's velocity reversal within a volume or two.
    r_control : float
        Measurement variance of the fitted control points (mm^2).
    p0_control_velocity : float
        Initial variance of the control-point velocities (mm^2/s^2).
    max_coast_volumes : int
        Volumes without a measurement (reported ``lost``) before the state is dropped and the
        tracker waits for a new insertion.
    """

    insertion: InsertionParams = InsertionParams(n_candidates=100, variance_threshold_mm2=110.0,
                                                 distance_threshold_mm=15.0)
    insertion_candidates_mm3: float | None = 2.7
    n_control_points: int = 2
    voi_radius_mm: float = 3.0
    voi_margin_mm: float = 5.0
    voi_candidates_mm3: float = 10.0
    init_voi_radius_mm: float = 20.0
    max_angle_deg: float = 10.0
    detection_window: int = 10
    start_length_mm: float = 5.0
    start_min_likelihood: float = 0.25
    start_tip_margin_mm: float = 1.5
    start_min_contrast: float = 1.8
    start_max_sheet: float = 1.3
    q_control: float = 50.0
    r_control: float = 0.25
    p0_control_velocity: float = 100.0
    max_coast_volumes: int = 2

    def __post_init__(self):
        _check_positive(self, ("start_length_mm", "voi_radius_mm", "voi_candidates_mm3",
                               "init_voi_radius_mm", "max_angle_deg", "q_control",
                               "r_control", "p0_control_velocity"))
        _check_non_negative(self, ("voi_margin_mm", "start_min_likelihood",
                                   "start_tip_margin_mm", "start_min_contrast",
                                   "start_max_sheet"))
        _check_integers(self, (("detection_window", 1), ("max_coast_volumes", 0)))
        if self.insertion_candidates_mm3 is not None and not (
                np.isfinite(self.insertion_candidates_mm3) and self.insertion_candidates_mm3 > 0):
            raise ValueError(f"insertion_candidates_mm3 must be None or finite and > 0, "
                             f"got {self.insertion_candidates_mm3}")
        if self.n_control_points not in (2, 3):
            raise ValueError(f"n_control_points must be 2 or 3, got {self.n_control_points!r}")


_GROUP_CLASSES = {"measurement": MeasurementParams, "placement": LearnedPlacementParams,
                  "roi_rk": RoiRkParams, "chatelain": ChatelainParams}
# every group's field under its own name -> the group that holds it
_GROUP_OF = {f.name: group for group, cls in _GROUP_CLASSES.items() for f in fields(cls)}


@dataclass(frozen=True, init=False)
class VolumeTrackerParams:
    """Parameters of the three volume trackers, in groups.

    Every field of a group is also a keyword and an attribute of its own name:
    ``VolumeTrackerParams(max_trials=200, insertion=...)`` replaces those fields of the
    groups given (or of the defaults), and ``p.max_trials`` reads ``p.measurement.max_trials``.

    Attributes
    ----------
    measurement : MeasurementParams
        Candidates, RANSAC and the tip, shared by the three methods.
    placement : LearnedPlacementParams
        How the image places a learned map's needle.
    roi_rk : RoiRkParams
        Zhao 2013's ROI-RK (initialisation, ROI, speckle tracking, Kalman filter).
    chatelain : ChatelainParams
        Chatelain 2013's insertion detection, VOI and control-point filter.
    default_dt_s : float
        Time step (s) used when the timestamps do not advance.
    """

    measurement: MeasurementParams = MeasurementParams()
    placement: LearnedPlacementParams = LearnedPlacementParams()
    roi_rk: RoiRkParams = RoiRkParams()
    chatelain: ChatelainParams = ChatelainParams()
    default_dt_s: float = 1.0

    # the fields holding groups, whose own fields are settable by their names
    groups: ClassVar[tuple[str, ...]] = tuple(_GROUP_CLASSES)

    def __init__(self, measurement: MeasurementParams | None = None,
                 placement: LearnedPlacementParams | None = None,
                 roi_rk: RoiRkParams | None = None, chatelain: ChatelainParams | None = None,
                 default_dt_s: float = 1.0, **group_fields):
        given = {"measurement": measurement, "placement": placement, "roi_rk": roi_rk,
                 "chatelain": chatelain}
        changes: dict[str, dict] = {}
        for name, value in group_fields.items():
            if name not in _GROUP_OF:
                raise TypeError(f"VolumeTrackerParams got an unexpected keyword argument "
                                f"{name!r}")
            changes.setdefault(_GROUP_OF[name], {})[name] = value
        for group, cls in _GROUP_CLASSES.items():
            value = cls() if given[group] is None else given[group]
            if not isinstance(value, cls):
                raise ValueError(f"VolumeTrackerParams.{group} must be a {cls.__name__}, "
                                 f"got {value!r}")
            if group in changes:
                value = replace(value, **changes[group])
            object.__setattr__(self, group, value)
        object.__setattr__(self, "default_dt_s", default_dt_s)
        _check_positive(self, ("default_dt_s",))

    def __getattr__(self, name: str):
        # only reached for names that are not attributes: a group's field by its own name
        group = _GROUP_OF.get(name)
        if group is None:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        return getattr(object.__getattribute__(self, group), name)
