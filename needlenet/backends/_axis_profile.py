"""The tip search along a fitted needle axis (Zhao 2013 Appendix B, Chatelain 2013 section
II-D): :func:`sample_along_axis` reads a map along the axis and :func:`tip_along_axis` finds
where the needle's run of high values ends."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ._fit_checks import _as_vector, _check_positive

__all__ = ["AxisTip", "sample_along_axis", "tip_along_axis"]


def sample_along_axis(image, origin, direction, spacing, t_values, *, cval: float = np.nan):
    """Sample an image or volume along a line by linear interpolation.

    Points are ``origin + t * u`` with ``u = direction / ||direction||``, in physical units
    (mm) and array axis order; they are divided by ``spacing`` to get array indices, so index
    ``i`` along an axis lies at ``i * spacing``. With ``spacing=1`` everything is in array
    index space. Values come from :func:`scipy.ndimage.map_coordinates` (order 1).

    Parameters
    ----------
    image : array, shape (rows, cols) or (d0, d1, d2)
    origin, direction : array, shape (image.ndim,)
    spacing : float or array, shape (image.ndim,)
        Voxel size per axis (> 0).
    t_values : array, shape (K,)
        Distances along the unit direction from ``origin``.
    cval : float
        Value outside the array; NaN by default, which :func:`tip_along_axis` reads as below
        any threshold.

    Returns
    -------
    array, shape (K,)
    """
    img = np.asarray(image, dtype=float)
    if img.ndim not in (2, 3):
        raise ValueError(f"image must be 2D or 3D, got shape {img.shape}")
    o = np.asarray(origin, dtype=float)
    if o.shape != (img.ndim,) or not np.all(np.isfinite(o)):
        raise ValueError(f"origin must be finite with shape ({img.ndim},), got {origin!r}")
    u = _as_vector(direction, img.ndim, "direction")
    sp = np.broadcast_to(np.asarray(spacing, dtype=float), (img.ndim,))
    if not np.all(np.isfinite(sp) & (sp > 0)):
        raise ValueError(f"spacing must be finite and > 0, got {spacing!r}")
    t = np.asarray(t_values, dtype=float)
    if t.ndim != 1 or not np.all(np.isfinite(t)):
        raise ValueError(f"t_values must be a finite 1D array, got shape {t.shape}")
    coords = (o + t[:, None] * u) / sp  # (K, ndim) array indices
    return ndimage.map_coordinates(img, coords.T, order=1, mode="constant", cval=cval)


@dataclass(frozen=True)
class AxisTip:
    """Tip found by :func:`tip_along_axis`; truthy when found.

    Attributes
    ----------
    position : float
        Tip position along the axis (units of ``positions``), with the threshold crossing
        interpolated linearly between the last needle sample and the next; NaN if not found.
    index : int
        Index of the last sample on the needle; -1 if not found.
    reaches_end : bool
        True when the needle does not drop before the last sample: the true tip may lie
        beyond the sampled range.
    reason : str or None
        Why no tip was found; None when found.
    """

    position: float
    index: int
    reaches_end: bool
    reason: str | None = None

    def __bool__(self) -> bool:
        return self.reason is None


def tip_along_axis(values_along_axis, positions_along_axis, threshold: float, max_gap: float):
    """Locate the needle tip as the point where the profile drops below ``threshold`` for good.

    Zhao 2013, Appendix B ("a significant drop below the threshold value is considered as the
    tip position") and Chatelain 2013, II-D ("we discard small intensity gaps"). Walking from
    the entry end (the first sample, smallest position) the needle starts at the first sample
    at or above ``threshold``; a run of samples below the threshold is a *gap*, of length the
    distance from its first sample to the next sample above the threshold. Gaps shorter than
    ``max_gap`` are bridged; the tip is the last needle sample before the first gap of length
    ``>= max_gap`` (or before the end of the profile).

    Parameters
    ----------
    values_along_axis : array, shape (K,)
        Intensity or likelihood profile; NaN (outside the volume) counts as below threshold.
    positions_along_axis : array, shape (K,)
        Strictly increasing positions along the axis, from the entry end.
    threshold : float
    max_gap : float
        Longest gap (in the units of ``positions``) that does not end the needle; >= 0.

    Returns
    -------
    AxisTip
    """
    v = np.asarray(values_along_axis, dtype=float)
    p = np.asarray(positions_along_axis, dtype=float)
    if v.ndim != 1 or v.size == 0:
        raise ValueError(f"values_along_axis must be a non-empty 1D array, got shape {v.shape}")
    if p.shape != v.shape:
        raise ValueError(
            f"positions_along_axis must have the shape of values_along_axis {v.shape}, "
            f"got {p.shape}"
        )
    if not np.all(np.isfinite(p)) or np.any(np.diff(p) <= 0):
        raise ValueError("positions_along_axis must be finite and strictly increasing")
    if not np.isfinite(threshold):
        raise ValueError(f"threshold must be finite, got {threshold}")
    max_gap = _check_positive(max_gap, "max_gap", allow_zero=True)

    above = np.greater_equal(v, threshold, where=np.isfinite(v), out=np.zeros(v.shape, bool))
    on = np.flatnonzero(above)
    if on.size == 0:
        return AxisTip(math.nan, -1, False, "no sample reaches the threshold")
    # Gap between consecutive needle samples on[i] < on[i+1]: from the first sample below the
    # threshold, on[i] + 1, to the next sample above it, on[i+1]; none when they are adjacent.
    has_gap = np.diff(on) > 1
    gap_length = p[on[1:]] - p[on[:-1] + 1]
    ends = np.flatnonzero(has_gap & (gap_length >= max_gap))
    last = int(on[ends[0]] if ends.size else on[-1])
    if last == v.size - 1:
        return AxisTip(float(p[last]), last, True)
    v_last, v_next = v[last], v[last + 1]
    position = p[last]
    if np.isfinite(v_next) and v_last > v_next:  # interpolate the threshold crossing
        position += (v_last - threshold) / (v_last - v_next) * (p[last + 1] - p[last])
    return AxisTip(float(position), last, False)
