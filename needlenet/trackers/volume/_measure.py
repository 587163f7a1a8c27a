"""One measurement of the needle in a volume, shared by the three methods: candidates ->
RANSAC -> least squares -> an axis oriented from the entry to the tip -> the tip.

The tip is where the maximum of the feature over the needle's cross-section drops below the
threshold for good (gaps shorter than ``max_gap_mm`` bridged), one needle-image cap
(``tip_cap_mm``) short of the drop. The least squares is repeated on the inliers between the
entry and the tip: the inliers of the infinite line beyond the needle are background. With
learned features the map finds the needle and the B-mode image places it
(:mod:`._placement`).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from ...backends import (
    LineModel,
    PolyCurveModel,
    RansacResult,
    min_sample_distance,
    ransac,
    tip_along_axis,
    within_angle,
)
from ._ambiguity import measurement_ambiguity
from ._geometry import RING_ANGLES, Volume, profile, ring_section, run_out_distance
from ._placement import image_tip, needle_contrast, refine_on_image, tip_on_map
from .params import MeasurementParams, VolumeTrackerParams

__all__ = ["Measurement", "candidates", "fail", "locate", "map_sheet", "measure",
           "median_profile", "needle_run", "threshold"]

# the ring on which a line's map is read for a sheet (mm): past a needle's radius and the
# map's blur, within reach of an interface the line lies in
_SHEET_RING_MM = (2.0, 3.0)
# ... and the least share of the map's level along the axis that counts as evidence there
_SHEET_FLOOR = 0.1
# A tip hint decides the orientation when it projects farther than this fraction of the
# needle's length from its middle.
_HINT_MARGIN = 0.1


@dataclass
class Measurement:
    """A needle found in one volume (mm, point order)."""

    ok: bool
    reason: str | None = None
    model: LineModel | PolyCurveModel | None = None
    entry: np.ndarray | None = None  # where the visible needle starts on the axis
    tip: np.ndarray | None = None
    direction: np.ndarray | None = None  # unit, entry -> tip
    inliers: int = 0
    trials: int = 0
    roi_voxels: int = 0
    a_entry: float = math.nan
    a_tip: float = math.nan
    entry_gap_mm: float = math.nan  # from the visible entry back to the sector's boundary
    # what the volume leaves unknown about the tip (mm^2, :mod:`._ambiguity`)
    ambiguity: np.ndarray | None = None


def fail(reason: str, trials: int = 0, roi_voxels: int = 0, inliers: int = 0) -> Measurement:
    return Measurement(False, reason, trials=trials, roi_voxels=roi_voxels, inliers=inliers)


def threshold(vol: Volume, mp: MeasurementParams) -> float:
    """T_I of eq. (B1): the ``threshold_percentile`` of the feature over the sector, or the
    fixed gray level ``intensity_threshold`` (Zhao Table 3) on [0, 1] features. Learned
    features: ``likelihood_threshold``, the level :func:`measure` applies to them (their map
    is not read, so a map computed on a region only does not change it)."""
    if vol.learned:
        return float(mp.likelihood_threshold)
    if mp.intensity_threshold is not None:
        return float(mp.intensity_threshold) / 255.0
    s = mp.percentile_stride
    sub = vol.values[::s, ::s, ::s][vol.sector[::s, ::s, ::s]]
    if sub.size == 0:
        return math.inf
    return float(np.percentile(sub, mp.threshold_percentile))


def candidates(vol: Volume, region: np.ndarray | None, level: float, mp: MeasurementParams,
               fixed_size: int | None = None):
    """Candidate voxels and their RANSAC weights.

    Classical features: voxels at or above ``level`` (eq. (B1)), or the ``fixed_size``
    brightest (Chatelain eq. (15)); unweighted. Learned features: voxels above the
    likelihood floor, the most likely first, weighted by their likelihood.
    """
    if region is None:
        flat_values = vol.values.reshape(-1)
        in_sector = vol.sector.reshape(-1)
        if vol.learned:
            region = np.flatnonzero((flat_values >= mp.likelihood_floor) & in_sector)
        elif fixed_size is None:
            region = np.flatnonzero((flat_values >= level) & in_sector)
        else:
            region = np.flatnonzero(in_sector)
    values = vol.values.reshape(-1)[region]
    if vol.learned:
        keep = values >= mp.likelihood_floor
        region, values = region[keep], values[keep]
        n = min(mp.max_candidates if fixed_size is None else fixed_size, region.size)
        if n < region.size:
            top = np.argpartition(values, region.size - n)[region.size - n:]
            region, values = region[top], values[top]
        return region, values.astype(float)
    if fixed_size is not None:  # Chatelain eq. (15): the fixed_size brightest voxels
        n = min(fixed_size, region.size)
        top = np.argpartition(values, region.size - n)[region.size - n:] if n else []
        region = region[top]
        values = values[top]
        region = region[values > 0]
        return region, None
    return region[values >= level], None


def _main_piece(a: np.ndarray, gap: float) -> tuple[float, float, int]:
    """The longest run (by count) of sorted coordinates ``a`` without a gap above ``gap``."""
    s = np.sort(a)
    breaks = np.flatnonzero(np.diff(s) > gap)
    starts = np.r_[0, breaks + 1]
    ends = np.r_[breaks, s.size - 1]
    counts = ends - starts + 1
    j = int(np.argmax(counts))
    return float(s[starts[j]]), float(s[ends[j]]), int(counts[j])


def needle_run(profile, a_values, level: float, max_gap: float, a0: float,
               a1: float) -> int | None:
    """Index of the first sample of the run of the profile that overlaps [a0, a1] most.

    Runs are the samples at or above ``level``, joined across gaps shorter than ``max_gap``
    (as :func:`tip_along_axis` joins them); None when no sample reaches the level.
    """
    above = np.greater_equal(profile, level, where=np.isfinite(profile),
                             out=np.zeros(profile.shape, bool))
    on = np.flatnonzero(above)
    if on.size == 0:
        return None
    gap = a_values[on[1:]] - a_values[on[:-1] + 1]  # first sample below to next above
    split = np.flatnonzero((np.diff(on) > 1) & (gap >= max_gap))
    starts = on[np.r_[0, split + 1]]
    ends = on[np.r_[split, on.size - 1]]
    overlap = np.minimum(a_values[ends], a1) - np.maximum(a_values[starts], a0)
    length = a_values[ends] - a_values[starts]
    best = np.lexsort((-length, -overlap))[0]  # most overlap, then longest
    return int(starts[best])


def median_profile(vol: Volume, model, a0: float, a1: float, mp: MeasurementParams) -> float:
    """The median of the map along the axis from ``a0`` to ``a1`` (as :func:`profile`)."""
    step = 0.5 * float(vol.spacing.min())
    a = np.arange(a0, a1 + step, step)
    if a.size == 0:
        return 0.0
    return float(np.median(profile(vol, model, a, mp.profile_radius_mm)))


def map_sheet(vol: Volume, model, a0: float, a1: float, mp: MeasurementParams) -> float:
    """How far the map stands up on two opposite sides of the axis, over its level around it:
    on a ring 2-3 mm around the axis from ``a0`` to ``a1`` (``RING_ANGLES`` directions, each
    averaged along the axis and over the ring's radii, samples inside the sector only), the
    largest level reached on both sides of one direction over the mean of all directions.

    A needle's map is a tube: whatever of it reaches the ring (the map's blur, the point
    spread) reaches it all round, about 1. A line that lies in a sheet of evidence, an
    interface's, has the sheet on two opposite sides and tissue elsewhere: well above 1.
    0 when the ring lies outside the sector or holds no evidence: where it stands on both
    sides, under a tenth of the map's median along the axis (:func:`median_profile`)."""
    step = 0.5 * float(vol.spacing.min())
    a = np.arange(a0, a1 + step, step)
    if a.size == 0:
        return 0.0
    pts = ring_section(model, a, _SHEET_RING_MM)  # radius-major: (radii * RING_ANGLES, K, 3)
    values = vol.sample(vol.values, pts, output=np.float32)
    inside = vol.sample(vol.sector.view(np.uint8), pts, order=0) > 0
    values = np.where(inside, values, np.nan).reshape(-1, RING_ANGLES, a.size)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a direction wholly outside: NaN
        level = np.nanmean(values, axis=(0, 2))
        mean = float(np.nanmean(level))
        half = RING_ANGLES // 2
        both = np.minimum(level[:half], level[half:])  # NaN where a side lies outside
        if not np.isfinite(mean) or mean <= 0 or not np.isfinite(both).any():
            return 0.0
        top = float(np.nanmax(both))
    if top < _SHEET_FLOOR * median_profile(vol, model, a0, a1, mp):
        return 0.0
    return top / mean


def implausible_start(vol: Volume, m: Measurement, p: VolumeTrackerParams,
                      min_likelihood: float, min_contrast: float,
                      max_sheet: float = 0.0) -> str | None:
    """Why a found axis is no needle to start a track on, or None: on a learned map, a median
    likelihood along it below ``min_likelihood`` (the map does not see a needle there: an
    interface's sheet, tissue), or a map that stands up on two opposite sides of it more than
    ``max_sheet`` over its level around it (:func:`map_sheet`: a line lying in a sheet); on a
    classical image, a needle no more than ``min_contrast`` times as bright as the tissue 2-3
    mm around it. 0 turns a test off."""
    if vol.learned and min_likelihood > 0:
        likely = median_profile(vol, m.model, m.a_entry, m.a_tip, p.measurement)
        if likely < min_likelihood:
            return (f"the map does not see a needle there: median likelihood {likely:.2f} < "
                    f"{min_likelihood}")
    if vol.learned and max_sheet > 0:
        sheet = map_sheet(vol, m.model, m.a_entry, m.a_tip, p.measurement)
        if sheet > max_sheet:
            return (f"a line in a sheet of evidence, no needle: the map 2-3 mm from it stands "
                    f"{sheet:.2f} times its mean around it on two opposite sides (> {max_sheet})")
    if not vol.learned and min_contrast > 0:
        contrast = needle_contrast(vol, m.model, m.a_entry, m.a_tip, p.placement)
        if contrast < min_contrast:
            return (f"not brighter than the tissue around it: the image along the fit is "
                    f"{contrast:.2f} times the tissue 2-3 mm away (< {min_contrast})")
    return None


def runs_out(vol: Volume, m: Measurement, margin_mm: float) -> str | None:
    """Why a found needle shows no tip in the volume, or None: its tip lies closer than
    ``margin_mm`` to the sector's boundary along the needle, so its line runs on out of the
    volume (a needle past the far face, or a tissue interface's sheet crossed from face to
    face). 0 turns the test off."""
    if margin_mm <= 0:
        return None
    gap = run_out_distance(vol, m.tip, m.direction, margin_mm)
    if gap < margin_mm:
        return (f"no needle tip in view: the line runs out of the volume, its tip {gap:.1f} mm "
                f"from the sector's boundary (< {margin_mm} mm)")
    return None


def _between(a: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (a >= lo) & (a <= hi)


def locate(vol: Volume, fitted, a0: float, a1: float, level: float, mp: MeasurementParams,
           r_in: float) -> tuple[float, float] | None:
    """Where the needle starts and where its image ends along a fitted axis.

    The profile along the axis is split into runs of samples at or above ``level``, gaps
    shorter than ``max_gap_mm`` bridged (Chatelain II-D: "we discard small intensity gaps");
    the needle is the run that overlaps the inliers [a0, a1] most (a bright structure
    crossing the axis is not). Its end is where the feature "drops below the threshold" for
    good (Zhao App. B), interpolated by :func:`tip_along_axis`.
    """
    step = 0.5 * float(vol.spacing.min())
    span = float(np.linalg.norm(vol.spacing * vol.shape))
    a_values = np.arange(a0 - mp.max_gap_mm - 2.0 * r_in, a0 + span, step)
    prof = profile(vol, fitted, a_values, mp.profile_radius_mm)
    run = needle_run(prof, a_values, level, mp.max_gap_mm, a0, a1)
    if run is None:
        return None
    found = tip_along_axis(prof[run:], a_values[run:], level, mp.max_gap_mm)
    return float(a_values[run]), float(found.position)


def measure(vol: Volume, region: np.ndarray | None, level: float, p: VolumeTrackerParams,
            rng, *, max_trials: int, predicted_direction=None,
            max_angle_deg: float | None = None, fixed_size: int | None = None,
            model: str = "line", order: int = 2, tip_hint=None,
            predicted_tip=None) -> Measurement:
    """One localisation: candidates -> RANSAC -> least squares -> oriented axis -> tip.

    ``region``: flat indices of the ROI/VOI (None: the whole sector); ``level``: T_I of
    eq. (B1) (for learned features the likelihood threshold is used instead);
    ``fixed_size``: take that many brightest voxels instead (Chatelain eq. (15));
    ``model``, ``order``: a line, or a curve of ``order`` control points (Chatelain eq. (3));
    ``predicted_direction``: orients the axis (and, with ``max_angle_deg``, constrains it,
    Chatelain eq. (22)). Without it, the tip is the end of the needle nearer to
    ``tip_hint`` when that point projects clearly off the needle's middle, and otherwise the
    entry is the end nearer to the sector's boundary. ``predicted_tip`` (mm): while tracking,
    where the image's tip is looked for with learned features (:func:`image_tip`).
    """
    mp, lp = p.measurement, p.placement
    roi_voxels = 0 if region is None else int(region.size)
    cand, weights = candidates(vol, region, level, mp, fixed_size)
    pts = vol.points(cand)
    r_in = mp.inlier_radius_mm
    if len(pts) < mp.min_inliers:
        return fail(f"too few candidates: {len(pts)} < {mp.min_inliers}", 0, roi_voxels)
    within = (None if max_angle_deg is None
              else within_angle(predicted_direction, max_angle_deg))  # Chatelain eq. (22)
    res: RansacResult = ransac(
        pts, model, residual_threshold=r_in, weights=weights,
        is_sample_valid=min_sample_distance(mp.min_sample_distance_mm),
        is_model_valid=within, predicted_direction=predicted_direction,
        success_probability=mp.success_probability, max_trials=max_trials,
        batch_size=mp.batch_size, order=order,
        refine_iterations=mp.refine_iterations, rng=rng)  # Zhao App. B, Chatelain II-D
    if not res:
        return fail(f"RANSAC: {res.reason}", res.n_trials, roi_voxels)
    fitted = res.model
    a = fitted.parameter(pts[res.inliers])
    a0, a1, n_in = _main_piece(a, mp.max_gap_mm)  # the needle: the largest piece of inliers
    if n_in < mp.min_inliers:
        return fail(f"too few inliers: {n_in} < {mp.min_inliers}", res.n_trials, roi_voxels,
                    n_in)
    if predicted_direction is None:
        u = fitted.principal_direction
        flip = None
        if tip_hint is not None and a1 > a0:
            f = (float(fitted.parameter(np.asarray(tip_hint, float)[None])[0]) - a0) / (a1 - a0)
            if abs(f - 0.5) > _HINT_MARGIN:
                flip = f < 0.5
        if flip is None:
            # The needle comes in through the sector's boundary, so its entry is the end of
            # the inliers nearer to the boundary along the axis.
            far = float(np.linalg.norm(vol.spacing * vol.shape))
            to_lo = run_out_distance(vol, fitted.points_at(np.array([a0]))[0], -u, far)
            to_hi = run_out_distance(vol, fitted.points_at(np.array([a1]))[0], u, far)
            flip = to_hi < to_lo
        if flip:
            fitted = fitted.oriented(-u)
            a0, a1, n_in = _main_piece(fitted.parameter(pts[res.inliers]), mp.max_gap_mm)
    if vol.learned:
        level = mp.likelihood_threshold
        if mp.likelihood_relative is not None:
            # the needle's own likelihood sets the level (a half-maximum): a learned map's
            # absolute scale varies with the contrast and the scanner, its drop at the tip
            # does not
            level = max(mp.likelihood_floor,
                        mp.likelihood_relative * median_profile(vol, fitted, a0, a1, mp))
    found = locate(vol, fitted, a0, a1, level, mp, r_in)
    if found is None:
        return fail("no sample of the axis reaches the threshold", res.n_trials, roi_voxels,
                    n_in)
    # Local optimisation on the needle itself: least squares on the inliers between the entry
    # and the tip (Zhao App. B minimises eq. (B6) over the inliers; the inliers beyond the
    # needle's ends, along the infinite line, are background).
    a_entry, a_drop = found
    on_needle = res.inliers & _between(fitted.parameter(pts), a_entry - r_in, a_drop + r_in)
    if np.count_nonzero(on_needle) >= mp.min_inliers:
        w = None if weights is None else weights[on_needle]
        try:
            refit = (LineModel.from_inliers(pts[on_needle], w) if model == "line"
                     else PolyCurveModel.from_inliers(pts[on_needle], w, order=fitted.order))
        except ValueError:
            refit = None
        if refit is not None:
            refit = refit.oriented(fitted.principal_direction)
            a_refit = refit.parameter(pts[on_needle])
            again = locate(vol, refit, float(a_refit.min()), float(a_refit.max()), level, mp,
                           r_in)
            if again is not None:
                fitted, (a_entry, a_drop) = refit, again
    if vol.learned and lp.image_refine:
        # the learned map found the needle; the image places its axis and its tip
        if model == "line":
            fitted, a_entry, a_drop = refine_on_image(vol, fitted, a_entry, a_drop, p)
        predicted = None
        if predicted_tip is not None:
            predicted = float(fitted.parameter(np.asarray(predicted_tip, float)[None])[0])
        a_tip = image_tip(vol, fitted, a_entry, a_drop, p, predicted)
        places = [a_drop, a_tip]  # where the map and the image put the tip
    else:
        a_tip = a_drop - mp.tip_cap_mm  # the image of the needle ends one cap beyond its tip
        places = [a_tip]
    if vol.tip is not None and lp.tip_window_mm > 0:
        a_tip = tip_on_map(vol, fitted, a_entry, a_tip, p)
        places.append(a_tip)
    length = a_tip - a_entry
    if length < mp.min_length_mm:
        return fail(f"needle too short: {length:.2f} mm < {mp.min_length_mm} mm", res.n_trials,
                    roi_voxels, n_in)
    entry, tip = fitted.points_at(np.array([a_entry, a_tip]))
    direction = (tip - entry) / np.linalg.norm(tip - entry)
    n_inliers = int(np.count_nonzero(fitted.residuals(pts) < r_in))
    far = float(np.linalg.norm(vol.spacing * vol.shape))
    gap = run_out_distance(vol, entry, -direction, far)
    return Measurement(True, None, fitted, entry, tip, direction, n_inliers, res.n_trials,
                       roi_voxels, a_entry, a_tip, gap, measurement_ambiguity(
                           vol, fitted, a_entry, a_tip, level, places, mp.inlier_radius_mm))
