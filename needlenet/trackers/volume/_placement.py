"""The B-mode image places a learned map's needle: the axis refitted on the image in
narrowing tubes (across the beam; along it the map's depth stands, as a needle's echo comes
from its wall facing the probe), the tip at the change point of the image along the axis where
that change is clear, and a learned tip channel's peak. Also the needle's contrast to the tissue
around it, which Chatelain's tracker checks before it starts on classical features.
"""

from __future__ import annotations

import math

import numpy as np

from ...backends import LineModel
from ._geometry import (
    RING_MIN_SAMPLES,
    Volume,
    cross_section,
    cylinder,
    profile,
    ring_section,
    section_mean,
)
from .params import LearnedPlacementParams, VolumeTrackerParams

__all__ = ["axis_change", "image_tip", "needle_contrast", "refine_on_image", "tip_on_map"]

# The tissue that needle_contrast compares the needle with: a ring this far from the axis.
_CONTRAST_RING_MM = (2.0, 3.0)


def refine_on_image(vol: Volume, fitted: LineModel, a_entry: float, a_drop: float,
                    p: VolumeTrackerParams) -> tuple[LineModel, float, float]:
    """A straight axis refitted on the image in narrowing tubes around ``fitted`` between the
    entry and the drop (1 mm beyond each): weighted total least squares of the voxels above
    the tube's ``image_refine_percentile``, each weighted by its excess (Zhao App. B's local
    optimisation, on the image's needle voxels). Returns the axis, oriented as ``fitted``,
    with the entry and the drop carried onto it; ``fitted`` unchanged when a tube holds
    too few voxels above the level (``min_inliers``)."""
    lp, min_inliers = p.placement, p.measurement.min_inliers
    u = fitted.principal_direction
    entry_pt, drop_pt = fitted.points_at(np.array([a_entry, a_drop]))
    image = vol.image.reshape(-1)
    model = fitted
    for radius in lp.image_refine_radii_mm:
        start = model.points_at(np.array([model.parameter(entry_pt[None])[0]]))[0]
        length = float(model.parameter(drop_pt[None])[0] - model.parameter(entry_pt[None])[0])
        idx = cylinder(vol, start, model.principal_direction, float(radius),
                       (-1.0, length + 1.0))
        if idx.size < min_inliers:
            break
        values = image[idx].astype(float)
        w = np.maximum(values - np.percentile(values, lp.image_refine_percentile), 0.0)
        if np.count_nonzero(w) < min_inliers:
            break
        model = LineModel.from_inliers(vol.points(idx), w).oriented(u)
    if model is not fitted and lp.image_refine_keep_depth:
        v = model.principal_direction
        mid = 0.5 * (entry_pt + drop_pt)
        gap = mid - model.points_at(model.parameter(mid[None]))[0]  # map axis - image axis
        depth = np.array([0.0, 0.0, 1.0]) - v[2] * v
        if np.linalg.norm(depth) > 1e-6:
            depth /= np.linalg.norm(depth)
            model = LineModel(model.origin + (gap @ depth) * depth, v)
    a = model.parameter(np.stack([entry_pt, drop_pt]))
    return model, float(a[0]), float(a[1])


def image_tip(vol: Volume, fitted, a_entry: float, a_drop: float, p: VolumeTrackerParams,
              predicted: float | None = None) -> float:
    """The tip along the axis from the image: the change point of the image's profile along
    the axis (:func:`axis_change`), the position within ``image_tip_search_mm`` of the
    likelihood's drop ``a_drop`` (while tracking, within ``image_tip_track_search_mm`` of the
    filter's predicted tip, ``predicted``; and at least one window beyond the entry) that
    maximises the mean of the profile over ``image_tip_window_mm`` behind it minus the mean
    over the same length ahead, less ``image_tip_cap_mm``.

    The change stands only when it is clear: the step is at least ``image_tip_min_effect``
    times the pooled standard deviation of the profile within the two windows. Otherwise,
    or when no position has a quarter of a window of profile inside the sector on each side,
    the likelihood's drop less ``tip_cap_mm`` is the tip: a map that sees a needle the image
    does not show keeps its own tip."""
    lp = p.placement
    fallback = a_drop - p.measurement.tip_cap_mm
    step = 0.5 * float(vol.spacing.min())
    w = max(1, int(round(lp.image_tip_window_mm / step)))
    middle, search = a_drop, lp.image_tip_search_mm
    if predicted is not None:  # tracking: the filter's predicted tip is the better prior
        middle, search = predicted, lp.image_tip_track_search_mm
    lo = max(middle - search, a_entry + lp.image_tip_window_mm)
    hi = middle + search
    if hi <= lo:
        return fallback
    a = np.arange(lo - w * step, hi + (w + 1) * step, step)
    found = axis_change(vol, fitted, a, w, lp)
    if found is None:
        return fallback
    k, effect = found
    if not effect >= lp.image_tip_min_effect:
        return fallback
    boundary = a[k] - 0.5 * step  # between samples k - 1 and k
    return float(boundary) - lp.image_tip_cap_mm


def axis_change(vol: Volume, fitted, a: np.ndarray, w: int,
                lp: LearnedPlacementParams) -> tuple[int, float] | None:
    """The largest drop of the image's profile along the axis at ``a`` (mm, evenly spaced):
    ``(k, effect)``, the drop between samples ``k - 1`` and ``k`` of the mean over the ``w``
    samples behind minus the mean over the ``w`` ahead, and that drop in pooled standard
    deviations of the profile within the two windows. The profile is the mean over the axis
    and six lines ``image_tip_radius_mm`` around it, less (``image_tip_background_mm``) the
    mean over a ring of lines around the needle. None when no boundary has a quarter of a
    window of profile inside the sector on each side."""
    prof, valid = section_mean(vol, cross_section(fitted, a, lp.image_tip_radius_mm), 1)
    if lp.image_tip_background_mm is not None:
        # the needle's excess over the tissue around it: a change of the tissue's brightness
        # along the axis (the tip entering a brighter region) is not the needle's end
        ring, ring_valid = section_mean(vol, ring_section(fitted, a, lp.image_tip_background_mm),
                                        RING_MIN_SAMPLES)
        valid &= ring_valid
        prof = np.where(valid, prof - ring, 0.0)

    def csum(x):
        return np.concatenate([[0.0], np.cumsum(x)])

    s1, s2, cnt = csum(prof), csum(prof * prof), csum(valid.astype(float))
    c = np.arange(w, a.size - w + 1)  # boundary before sample c
    nb, na = cnt[c] - cnt[c - w], cnt[c + w] - cnt[c]
    ok = (nb >= max(1.0, 0.25 * w)) & (na >= max(1.0, 0.25 * w))
    if not ok.any():
        return None
    nb_, na_ = np.maximum(nb, 1.0), np.maximum(na, 1.0)
    mb, ma = (s1[c] - s1[c - w]) / nb_, (s1[c + w] - s1[c]) / na_
    change = np.where(ok, mb - ma, -np.inf)
    k = int(np.argmax(change))
    var = ((s2[c[k]] - s2[c[k] - w]) - nb[k] * mb[k] ** 2
           + (s2[c[k] + w] - s2[c[k]]) - na[k] * ma[k] ** 2) / (nb[k] + na[k])
    sd = math.sqrt(max(var, 0.0))
    if sd > 0.0:
        return int(c[k]), float(change[k] / sd)
    return int(c[k]), (math.inf if change[k] > 0 else 0.0)  # a noiseless profile


def needle_contrast(vol: Volume, model, a0: float, a1: float,
                    lp: LearnedPlacementParams) -> float:
    """The median along the axis from ``a0`` to ``a1`` of the image's mean over the needle's
    cross-section (``image_tip_radius_mm``) over its mean on a ring 2-3 mm around it
    (``_CONTRAST_RING_MM``); NaN-free: 0 where no position has both inside the sector."""
    step = 0.5 * float(vol.spacing.min())
    a = np.arange(a0, a1 + step, step)
    core, v1 = section_mean(vol, cross_section(model, a, lp.image_tip_radius_mm), 1)
    ring, v2 = section_mean(vol, ring_section(model, a, _CONTRAST_RING_MM), RING_MIN_SAMPLES)
    ok = v1 & v2
    if not ok.any():
        return 0.0
    return float(np.median(core[ok] / np.maximum(ring[ok], 1e-3)))


def tip_on_map(vol: Volume, fitted, a_entry: float, a_tip: float,
               p: VolumeTrackerParams) -> float:
    """The tip along the fitted axis from a learned tip channel: the maximum of the tip map
    (over the needle's cross-section, as :func:`profile`) within ``tip_window_mm`` of the
    tip where the shaft likelihood drops, refined by a parabola through its neighbours. The
    drop stands when the tip map has no clear peak there (below ``tip_min``)."""
    lp = p.placement
    step = 0.5 * float(vol.spacing.min())
    a = np.arange(max(a_tip - lp.tip_window_mm, a_entry), a_tip + lp.tip_window_mm + step, step)
    if a.size < 3:
        return a_tip
    prof = profile(vol, fitted, a, p.measurement.profile_radius_mm, vol.tip)
    k = int(np.argmax(prof))
    if prof[k] < lp.tip_min:
        return a_tip
    if 0 < k < a.size - 1:
        y0, y1, y2 = prof[k - 1], prof[k], prof[k + 1]
        den = y0 - 2.0 * y1 + y2
        if den < 0:
            return float(a[k] + 0.5 * step * (y0 - y2) / den)
    return float(a[k])
