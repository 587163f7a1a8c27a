"""The per-slice maps of Carriere's axial tracker (:class:`~._axial.AxialTracker`): the feature
map, its smoothing at the needle's scale with the robust location and scale of the smoothed
map, and the image the NCC templates are cut from; over the whole slice, or over a box around
the ROI where a learned source runs its network only there.

While the tracker tracks it reads the maps only near the ROI: the NCC search window, the drift
correction's window around the match, the template cut around the new centre and the smoothed
map at the match (:func:`roi_reach_px`). A learned source then runs on that box plus its
``margin_mm`` of context (``LearnedFeatures.likelihood(frame, roi)``); inside the box the maps
differ from the whole slice's only by the context left out. Detection and re-detection read
the whole slice.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from ..backends import variance_image
from ._cross_section import odd_px

__all__ = ["SliceGeometry", "SliceMaps", "region_box", "roi_reach_px", "slice_geometry",
           "slice_maps"]


@dataclass(frozen=True)
class SliceMaps:
    """The maps of one slice, float32 on the slice's grid.

    ``F`` the feature map, ``S`` it smoothed by a Gaussian of the needle's radius, ``med`` and
    ``scale`` the robust location and scale of ``S``, ``M`` the image the NCC templates are cut
    from; ``valid`` the box (row, col slices) where they hold, None for the whole slice (0
    outside the box)."""

    F: np.ndarray
    S: np.ndarray
    med: float
    scale: float
    M: np.ndarray
    valid: tuple[slice, slice] | None


class SliceGeometry(NamedTuple):
    """Constants of the tracking step for slices of one shape and spacing, in pixels."""

    size: tuple[int, int]  # the NCC template, h x w (odd)
    sigma_px: float  # the Gaussian of the needle's radius that smooths the feature map
    drift_px: np.ndarray  # (rows, cols) the drift correction's tolerance
    half_px: np.ndarray  # (rows, cols) half-size of the box the step reads (roi_reach_px)
    context_px: tuple[int, int]  # the source's margin_mm of context (0: none)
    align: int  # the network's input multiple: where its strides line up with the slice's


def slice_geometry(spacing, params, features) -> SliceGeometry:
    """:class:`SliceGeometry` for slices at ``spacing`` (row, col mm) under ``params``
    (:class:`~._axial_params.AxialParams`) and a source whose ``margin_mm`` and ``multiple``
    are read where it has them."""
    spacing = np.asarray(spacing, dtype=float)
    size = tuple(odd_px(params.template_mm, s) for s in spacing)
    sigma = params.needle_radius_mm / float(spacing.mean())
    drift = np.maximum(np.rint(params.drift_tolerance_mm / spacing), 1).astype(int)
    refine = np.ceil(params.needle_radius_mm / spacing).astype(int)
    margin = float(getattr(features, "margin_mm", 0.0))
    context = tuple(int(np.ceil(margin / s)) for s in spacing)
    return SliceGeometry(size, sigma, drift, roi_reach_px(size, drift, sigma, refine), context,
                         int(getattr(features, "multiple", 1)))


def blur_radius_px(sigma_px: float) -> int:
    """Samples on each side that OpenCV's Gaussian of ``sigma_px`` reads on a float image (its
    kernel has round(8 sigma + 1) | 1 taps), plus one."""
    return (int(round(8.0 * sigma_px + 1.0)) | 1) // 2 + 1


def roi_reach_px(size: tuple[int, int], drift_px: np.ndarray, sigma_px: float,
                 refine_px: np.ndarray) -> np.ndarray:
    """Half-size (rows, cols) of the box around an ROI centre holding every sample the tracking
    step reads: the NCC window is the centre +- ``size`` (the template's size, Carriere's
    2h x 2w), so the match lies within +- (size - size // 2 + 1); around the match it reads the
    drift correction's window (size // 2 + ``drift_px`` + 1), the template cut (size // 2 + 1),
    the smoothed map (the Gaussian's reach, :func:`blur_radius_px`) and the map refinement
    (``refine_px``)."""
    s = np.asarray(size, int)
    around = np.maximum.reduce([s // 2 + np.asarray(drift_px, int) + 1, s // 2 + 1,
                                np.full(2, blur_radius_px(sigma_px)),
                                np.asarray(refine_px, int) + 1])
    return s - s // 2 + 1 + around + 1


def region_box(shape, center_rc, half_px, context_px, align: int) -> tuple[slice, slice]:
    """Rows and columns within ``half_px`` of ``center_rc`` (rounded), clipped to ``shape``.

    The start is moved down so that it lies ``context_px`` past a multiple of ``align`` (or
    ``context_px`` from the slice's edge): the box with its context then starts where the
    network's strides line up with the whole slice's, so that its output samples lie where the
    whole slice's do."""
    c = np.rint(np.asarray(center_rc, float)).astype(int)
    out = []
    for n, ci, h, k in zip(shape, c, np.asarray(half_px, int), np.asarray(context_px, int),
                           strict=True):
        lo = max(ci - h, 0)
        if lo > k and align > 1:
            lo = (lo - k) // align * align + k
        out.append(slice(lo, int(min(max(ci + h + 1, lo + 1), n))))
    return tuple(out)


def _robust(S: np.ndarray, floor: float) -> tuple[float, float]:
    """Median and 1.4826 MAD of every third sample (at least ``floor``): the map is smooth, and
    the needle covers too little of it to move either."""
    sub = S[::3, ::3]
    med = float(np.median(sub))
    mad = 1.4826 * float(np.median(np.abs(sub - med)))
    return med, max(mad, floor)


def _variance(image: np.ndarray, box) -> np.ndarray:
    """Carriere 2016, eq. (1) on ``box`` of ``image``: (I - mean(I))^2 over the maximum of the
    whole slice's (the whole slice's mean and maximum, as :func:`variance_image`), float64."""
    img = np.asarray(image, dtype=float)
    mean = img.mean()
    peak = max((float(img.max()) - mean) ** 2, (float(img.min()) - mean) ** 2)
    v = (img[box] - mean) ** 2  # eq. (1)
    return v / peak if peak > 0 else np.zeros_like(v)


def template_image(F: np.ndarray, image, mode: str | None, box=None) -> np.ndarray:
    """The image the NCC templates are cut from: ``F`` itself (``mode`` None or "map"), or for
    a learned source the variance image of eq. (1) (``"variance"``) or the image over its
    median (``"texture"``, so that the gain does not matter) weighted by ``F``. With ``box``
    only that part is computed (0 elsewhere), with the whole slice's mean, maximum or
    median."""
    if mode in (None, "map"):
        return F
    if mode == "variance":
        if box is None:
            return np.ascontiguousarray(F * variance_image(image), dtype=np.float32)
        part = F[box] * _variance(image, box)
    else:
        im = np.asarray(image, dtype=np.float32)
        level = np.float32(max(float(np.median(im[::2, ::2])), 1.0))
        if box is None:
            return np.ascontiguousarray(F * (im / level), dtype=np.float32)
        part = F[box] * (im[box] / level)
    M = np.zeros(F.shape, np.float32)
    M[box] = part
    return M


def slice_maps(features, frame, sigma_px: float, floor: float, template: str | None,
               box=None, context_px=(0, 0)) -> SliceMaps:
    """The maps of ``frame`` from ``features``: over the whole slice, or (``box``, rows and
    columns) from one run of the source on the box plus its context (``context_px``, the
    source's ``margin_mm`` in pixels). The smoothing and the robust statistics then cover that
    context too (where the maps hold); the template image covers the box.

    ``sigma_px``: the Gaussian's sigma in pixels (the needle's radius); ``floor``: the least
    robust scale; ``template``: :func:`template_image`'s ``mode``."""
    if box is None:
        F = np.ascontiguousarray(features.likelihood(frame).shaft, dtype=np.float32)
        S = cv2.GaussianBlur(F, (0, 0), sigma_px)
        med, scale = _robust(S, floor)
        return SliceMaps(F, S, med, scale, template_image(F, frame.image, template), None)
    F = np.asarray(features.likelihood(frame, box).shaft, dtype=np.float32)
    valid = tuple(slice(max(b.start - m, 0), min(b.stop + m, n))
                  for b, m, n in zip(box, context_px, F.shape, strict=True))
    S = np.zeros(F.shape, np.float32)
    S[valid] = cv2.GaussianBlur(np.ascontiguousarray(F[valid]), (0, 0), sigma_px)
    med, scale = _robust(S[valid], floor)
    return SliceMaps(F, S, med, scale, template_image(F, frame.image, template, box), valid)
