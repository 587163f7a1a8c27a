"""What each tracker reports of one frame beyond the shared :class:`NeedleEstimate` fields:
one frozen dataclass per tracker (in-plane :class:`InplaneDetails` and :class:`LineDetails`,
:class:`AxialDetails`, :class:`VolumeDetails`), on ``NeedleEstimate.details``.

JSON. :meth:`EstimateDetails.to_json` writes each field under its own name, so that the keys
of ``needlenet track --json`` are the field names. A field without a default is always
written (``null`` when None); a field with a default (None or False) is left out while it
holds it, so a key appears only on the frames where the tracker has that value.
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields

import numpy as np

__all__ = ["AxialDetails", "AxialModel", "EstimateDetails", "InplaneDetails", "LineDetails",
           "VolumeDetails"]


def _json_value(v):
    """A value as JSON writes it: arrays as lists of floats rounded to 6 decimals, numpy
    scalars as Python numbers, anything else as it is."""
    if isinstance(v, np.ndarray):
        return np.asarray(v, float).round(6).tolist()
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return v


@dataclass(frozen=True)
class EstimateDetails:
    """Base of the per-tracker details; see the module's doc for what :meth:`to_json`
    writes. A field holding another ``EstimateDetails`` writes that one's keys in place."""

    def to_json(self) -> dict:
        out: dict = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, EstimateDetails):
                out.update(v.to_json())
            elif f.default is MISSING or v is not f.default:
                out[f.name] = _json_value(v)
        return out


@dataclass(frozen=True)
class InplaneDetails(EstimateDetails):
    """Mathiassen 2017's in-plane methods (:class:`InplaneTracker`). Positions "along the
    axis" are x of ``AxisEstimate.point_mm``: mm along v_n from the ROI's anchor A."""

    shaft_contrast: float
    # shaft contrast along the axis on this frame (line echo minus the tissue above it, over
    # the background's spread; about 0 on tissue, 3-5 on a needle); DF: 0 without an axis
    theta_measured_deg: float | None = None
    # the axis angle Algorithm 2 measured on this frame, before the KF on theta (degrees)
    theta_deg: float | None = None
    # the angle of the reported axis to the skin (after the KF on theta), degrees
    p_p_mm: float | None = None
    # the reported centre line's offset from the ROI's top edge along v_p (mm)
    tip_along_mm: float | None = None
    # the reported tip along the axis (mm)
    h_peak: float | None = None
    # the maximum of the tip likelihood h(x) along the axis
    h_max: float | None = None
    # Algorithm 2's best smoothed histogram value H_max
    n_rays: int | None = None
    # rays of the ROI the axis was searched on
    tip_at_image_edge: bool | None = None
    # the tip lies within one tip region of the last sample along the axis (the image's end)
    hough_votes: int | None = None
    # DF: the Hough value of its axis
    detected: bool = False
    # the first frame reported after a detection (found on the frame before, seen again here)
    coasting: bool = False
    # no needle seen on this frame (no tip): the filters predict through it
    velocity: str | None = None
    # kfv/pfv: why the velocity methods used the image only on this frame
    candidates: int | None = None
    # KF: tip candidates of eq. (12) offered to the filter
    measurement_accepted: bool | None = None
    # the tip filter used this frame's measurement (KF: a candidate in the gate; PF: h(x)
    # weighted the particles)
    tip_velocity_mm_s: float | None = None
    # the tip filter's velocity along the axis (mm/s)
    tip_measurement_mm: float | None = None
    # KF: the accepted candidate along the axis (mm)
    mirrored: bool = False
    # the needle enters from the left: the frames were mirrored for the paper's geometry and
    # the estimate mirrored back
    echo_coverage: float | None = None
    # classical features: share of the axis's sections, first ray to tip, whose line echo
    # stands out of the tissue noise (the needle is seen at InplaneParams.echo_coverage)


@dataclass(frozen=True)
class LineDetails(EstimateDetails):
    """The line tracker (:class:`LineTracker`) on a frame where it found the needle."""

    entry_mm: np.ndarray
    # where the segment enters, on the needle's centre line (x, z) mm; the estimate's
    # axis_point_mm
    theta_deg: float
    # the segment's angle below the horizontal, degrees, whichever side it comes from
    tip_velocity_mm_s: np.ndarray
    # the Kalman filter's tip velocity (x, z), mm/s
    shaft_support: float
    # the segment's mean evidence (probability, or SDs above the tissue for classical maps)
    segment_length_mm: float
    # length of the supported segment (mm)
    tip_measurement_mm: np.ndarray
    # this frame's tip measurement before the filter (x, z) mm
    tip_from_tip_map: bool
    # the measurement was moved to the tip map's maximum
    measurement_accepted: bool | None = None
    # the measurement passed the filter's chi-square gate; None on the frame the filter starts
    restarted: bool = False
    # the filter restarted at the measurement after reinit_after_rejects rejections in a row
    tip_at_echo_end: bool = False
    # the learned measurement was moved back to where the needle's echo ends in the image
    tip_spread_mm: float = 0.0
    # how far apart along the line the places the frame offered for the tip lie (mm)
    tip_from_motion: bool = False
    # the map showed no needle line; the tip is where echo was gained since the frame before


@dataclass(frozen=True)
class AxialModel(EstimateDetails):
    """Carriere 2016's bicycle model after a frame's update (section IV). Parameters NaN and
    shape None before the particle filter runs (the first ``warmup_depth_mm``)."""

    R_mm: float
    # radius of curvature R, the particles' mean (mm)
    theta0_deg: float
    # initial angle theta_0 in the (u, v) plane, the particles' mean (degrees)
    phi_deg: float
    # angle phi of the u axis in the first slice's (x, z) plane, from the PCA of the
    # accepted centres (degrees)
    R_sd_mm: float
    # the particles' spread of R (mm)
    theta0_sd_deg: float
    # the particles' spread of theta_0 (degrees)
    shape_v_mm: np.ndarray | None
    # depths v of the predicted whole needle, from origin_depth_mm to final_depth_mm (mm)
    shape_u_mm: np.ndarray | None
    # the predicted deflection u at those depths (mm)
    origin_xz_mm: np.ndarray | None
    # the (u, v) plane's origin (the first centre) in this frame's probe (x, z), mm
    u_axis_xz: np.ndarray | None
    # the plane's u axis in this frame's probe (x, z), unit
    origin_depth_mm: float
    # depth v of the origin (mm); NaN before the first centre
    rotation_depth_mm: float | None
    # D, where the filter stops and the predicted needle turns (mm); None: never
    pf_updates: int
    # particle-filter updates so far


@dataclass(frozen=True)
class AxialDetails(EstimateDetails):
    """Carriere 2016's axial tracker (:class:`AxialTracker`) on one slice."""

    depth_mm: float
    # depth v of this slice along the insertion (mm)
    ncc_peak: float
    # the NCC peak of the template match; NaN when none was made (detection)
    predicted_u_mm: float
    # the model's u at this slice before the slice's own update (mm); NaN without a model
    outlier: bool
    # the match was rejected: not fed to the filter; the slice is reported at the ROI's
    # centre for up to max_coast_frames such slices in a row, then lost
    roi_source: str | None
    # where the ROI was centred: "previous" (the last centre) or "model" (its prediction);
    # None on a slice searched by the detector
    score: float
    # robust score of the smoothed feature at the match or detection: (value - median) /
    # (1.4826 MAD) over the slice
    model: AxialModel
    # the bicycle model after this slice (its keys are written in place)
    image_ms: float
    # time spent on the image (feature, match, detection), ms (Carriere's Table II)
    filter_ms: float
    # time spent on the particle filter, ms


@dataclass(frozen=True)
class VolumeDetails(EstimateDetails):
    """The volume trackers (:class:`VolumeTracker`: ransac, roi-rk, chatelain) on one
    volume."""

    inliers: int
    # RANSAC inliers of this volume's measurement (0 without one)
    ransac_trials: int
    # minimal samples RANSAC drew, initialisation included
    roi_voxels: int
    # voxels of the ROI/VOI searched; 0 for the whole volume
    alpha_deg: float | None = None
    # Zhao 2013 eq. (4) alpha of the reported direction (degrees)
    beta_deg: float | None = None
    # Zhao 2013 eq. (4) beta of the reported direction (degrees)
    measured_tip_mm: np.ndarray | None = None
    # this volume's measured tip before the Kalman filter (x, y, z) mm
