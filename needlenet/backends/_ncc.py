"""Normalised cross-correlation: Carriere 2016's variance image and ROI template matching,
and Zhao 2013's 3-D speckle tracking of the needle tip.

* ``variance_image``: Carriere 2016, eq. (1), normalised to [0, 1] by its maximum.
* ``match_template_roi``: Carriere 2016, section II: NCC of the template with the image,
  restricted to a region of interest around the predicted needle position (OpenCV's
  ``TM_CCOEFF_NORMED``, the zero-mean NCC).
* ``speckle_track_3d`` and ``tip_velocity``: Zhao 2013, "Motion estimation", eq. (5): the 3-D
  NCC between a kernel region of the previous volume and a search region of the current one,
  computed as Lewis's fast NCC (FFT numerator, summed-area-table denominator) through
  ``skimage.feature.match_template``; the displacement of the best match over the frame time
  is the tip velocity.

Image and volume indices are (row, col) and (axis 0, axis 1, axis 2); sub-pixel positions are
refined by a three-point parabola through the correlation peak along each axis.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
from skimage.feature import match_template

__all__ = [
    "variance_image",
    "TemplateMatch",
    "match_template_roi",
    "SpeckleMatch",
    "speckle_track_3d",
    "TipVelocity",
    "tip_velocity",
]


def variance_image(image) -> np.ndarray:
    """Carriere 2016, eq. (1): V(px, py) = (I(px, py) - mean(I))^2, divided by its maximum so
    that it lies in [0, 1]. A constant image gives zeros. Returns float64."""
    img = np.asarray(image, dtype=float)
    if img.size == 0:
        raise ValueError("image is empty")
    v = (img - img.mean()) ** 2  # eq. (1)
    peak = v.max()
    if not peak > 0:  # constant image (or NaN): no variance to normalise
        return np.zeros_like(v)
    return v / peak


def _parabolic_offset(minus: float, centre: float, plus: float) -> float:
    """Vertex of the parabola through (-1, minus), (0, centre), (1, plus), clipped to
    [-0.5, 0.5]; 0 where the three points are not a strict maximum (or not finite)."""
    denom = minus - 2.0 * centre + plus
    if not denom < 0:
        return 0.0
    delta = 0.5 * (minus - plus) / denom
    return min(max(delta, -0.5), 0.5) if np.isfinite(delta) else 0.0


def _refine_peak(score: np.ndarray, index: tuple[int, ...]) -> np.ndarray:
    """Sub-sample offset of the peak of ``score`` at ``index`` along each axis (0 on a
    border of the score map, where the parabola has no neighbour). Scalar arithmetic: one
    parabola per axis, a handful of samples."""
    index = tuple(int(i) for i in index)
    offsets = np.zeros(score.ndim)
    centre = float(score[index])
    for ax, i in enumerate(index):
        if 0 < i < score.shape[ax] - 1:
            lo = index[:ax] + (i - 1,) + index[ax + 1:]
            hi = index[:ax] + (i + 1,) + index[ax + 1:]
            offsets[ax] = _parabolic_offset(float(score[lo]), centre, float(score[hi]))
    return offsets


def _half_sizes(half, ndim: int, name: str) -> np.ndarray:
    """``half`` (one non-negative integer, or one per axis) as an int array of ``ndim``."""
    if isinstance(half, (int, np.integer)) and not isinstance(half, bool):
        h = np.full(ndim, int(half))
    elif isinstance(half, tuple) and len(half) == ndim and all(
            isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in half):
        h = np.array(half, dtype=int)
    else:
        f = np.broadcast_to(np.asarray(half), (ndim,)).astype(float)
        if np.any(f != np.round(f)):
            raise ValueError(f"{name} must be non-negative integers, got {half!r}")
        h = f.astype(int)
    if np.any(h < 0):
        raise ValueError(f"{name} must be non-negative integers, got {half!r}")
    return h


class TemplateMatch(NamedTuple):
    """Best NCC match: ``center`` (row, col) in full-image coordinates with sub-pixel
    refinement, the NCC ``peak`` value in [-1, 1], the ``score`` map over the ROI window
    (one value per template position) and the window's top-left pixel ``roi_origin``."""

    center: np.ndarray
    peak: float
    score: np.ndarray
    roi_origin: np.ndarray


def match_template_roi(image, template, center, roi_half_size) -> TemplateMatch:
    """NCC template matching restricted to a region of interest, Carriere 2016, section II.

    The searched window is rows ``center[0] - h .. center[0] + h`` and columns
    ``center[1] - w .. center[1] + w`` (inclusive, ``(h, w) = roi_half_size``), clipped to
    the image; the template must fit inside it. Carriere searches a 2h x 2w region for an
    h x w template, i.e. ``roi_half_size = template.shape``. The score is OpenCV's
    ``TM_CCOEFF_NORMED`` on float32 (zero-mean NCC, the formula of Zhao 2013's eq. (5) in 2-D).

    Parameters
    ----------
    image : (H, W) array
        Typically the variance image of eq. (1).
    template : (h, w) array
        Must not be constant (its NCC is undefined).
    center : (row, col)
        Centre of the ROI, e.g. the model's predicted needle position; rounded to pixels.
    roi_half_size : int or (int, int)

    Returns
    -------
    TemplateMatch
        The template centre ((h - 1) / 2, (w - 1) / 2 from its top-left corner) at the best
        match, in full-image (row, col), refined by a parabola through the peak, and the peak.
    """
    img = np.asarray(image)
    tpl = np.asarray(template)
    if img.ndim != 2 or tpl.ndim != 2:
        raise ValueError(f"image and template must be 2-D, got shapes {img.shape} and {tpl.shape}")
    if not tpl.max() > tpl.min():
        raise ValueError("template is constant: its normalised cross-correlation is undefined")
    half = _half_sizes(roi_half_size, 2, "roi_half_size")
    c = np.rint(np.asarray(center, dtype=float)).astype(int)
    if c.shape != (2,):
        raise ValueError(f"center must be (row, col), got {center!r}")
    lo = np.maximum(c - half, 0)
    hi = np.minimum(c + half + 1, img.shape)
    if np.any(hi <= lo):
        raise ValueError(f"ROI around {tuple(c)} lies outside the image of shape {img.shape}")
    window = img[lo[0] : hi[0], lo[1] : hi[1]]
    if np.any(np.asarray(window.shape) < tpl.shape):
        raise ValueError(
            f"template of shape {tpl.shape} is larger than the ROI window of shape "
            f"{window.shape} (roi_half_size {tuple(half)}, clipped at the image border)"
        )
    score = cv2.matchTemplate(
        np.ascontiguousarray(window, dtype=np.float32),
        np.ascontiguousarray(tpl, dtype=np.float32),
        cv2.TM_CCOEFF_NORMED,
    )
    score = score.astype(float)
    if not np.isfinite(score).all():  # a flat window: no correlation there
        score = np.nan_to_num(score, nan=-1.0)
    index = np.unravel_index(int(np.argmax(score)), score.shape)
    offset = _refine_peak(score, index)
    tpl_centre = (np.asarray(tpl.shape) - 1) / 2.0
    best = lo + np.asarray(index) + offset + tpl_centre
    return TemplateMatch(center=best, peak=float(score[index]), score=score, roi_origin=lo)


class SpeckleMatch(NamedTuple):
    """Result of ``speckle_track_3d``.

    ``displacement``: integer shift (voxels) of the best match from the centred position;
    ``subvoxel_displacement``: the same refined by a parabola through the peak of rho;
    ``peak``: rho_max of eq. (5); ``rho``: the correlation map, shape search - kernel + 1.
    """

    displacement: np.ndarray
    subvoxel_displacement: np.ndarray
    peak: float
    rho: np.ndarray


def _check_kernel_search(kernel: np.ndarray, search: np.ndarray) -> None:
    if kernel.ndim != 3 or search.ndim != 3:
        raise ValueError(
            f"kernel and search volumes must be 3-D, got shapes {kernel.shape} and {search.shape}"
        )
    if np.any(np.asarray(kernel.shape) > search.shape):
        raise ValueError(
            f"kernel of shape {kernel.shape} is larger than the search region of shape "
            f"{search.shape}"
        )
    if not np.ptp(kernel) > 0:
        raise ValueError("kernel is constant: its normalised cross-correlation is undefined")


def _fncc_peak(kernel: np.ndarray, search: np.ndarray):
    """Zhao 2013, eq. (5) by Lewis's fast NCC: rho over every offset of the kernel inside the
    search region (skimage.feature.match_template: FFT numerator, integral-image
    denominator), its arg-max and sub-voxel refinement."""
    rho = match_template(search, kernel, pad_input=False)  # eq. (5), shape (M-m+1, ...)
    index = np.unravel_index(int(np.argmax(rho)), rho.shape)  # rho = rho_max
    return rho, np.asarray(index), _refine_peak(rho, index)


def speckle_track_3d(kernel_volume, search_volume) -> SpeckleMatch:
    """Speckle tracking by 3-D fast NCC, Zhao 2013, "Motion estimation", eq. (5).

    The kernel region X_0 (m x n x p) slides voxel by voxel through the search region X_1
    (M x N x P); rho has shape (M - m + 1, N - n + 1, P - p + 1). The search region is taken
    to be centred on the kernel's original position, so a zero displacement is the offset
    ((M - m) / 2, ...), and every size difference M - m must be even.
    """
    kernel = np.asarray(kernel_volume, dtype=float)
    search = np.asarray(search_volume, dtype=float)
    _check_kernel_search(kernel, search)
    margin = np.asarray(search.shape) - kernel.shape
    if np.any(margin % 2):
        raise ValueError(
            f"search shape {search.shape} minus kernel shape {kernel.shape} must be even on "
            "every axis so that the search region is centred on the kernel"
        )
    rho, index, offset = _fncc_peak(kernel, search)
    displacement = index - margin // 2
    return SpeckleMatch(
        displacement=displacement,
        subvoxel_displacement=displacement + offset,
        peak=float(rho[tuple(index)]),
        rho=rho,
    )


class TipVelocity(NamedTuple):
    """Result of ``tip_velocity``: ``velocity_mm_s`` (3,), ``displacement_mm`` (3,) and the
    NCC ``peak``."""

    velocity_mm_s: np.ndarray
    displacement_mm: np.ndarray
    peak: float


def tip_velocity(
    prev_volume,
    volume,
    tip_index,
    kernel_half,
    search_half,
    spacing_mm,
    dt,
) -> TipVelocity:
    """Needle tip velocity by speckle tracking, Zhao 2013, "Motion estimation".

    The kernel region is ``prev_volume[tip - kernel_half : tip + kernel_half + 1]`` (per
    axis), the search region ``volume[tip - search_half : tip + search_half + 1]``; both are
    clipped at the volume border. The displacement of the best-matching kernel position
    (sub-voxel, eq. (5) and a parabolic peak fit) times the voxel spacing, divided by the
    time between the volumes, is the velocity.

    Parameters
    ----------
    prev_volume, volume : 3-D arrays of one shape
    tip_index : (3,) ints
        Estimated tip voxel in ``prev_volume``.
    kernel_half, search_half : int or (3,) ints
        Half sizes of the kernel and search regions (voxels); search_half >= kernel_half.
    spacing_mm : float or (3,) floats
        Voxel size along each axis (mm).
    dt : float
        Time between the two volumes (s).
    """
    prev = np.asarray(prev_volume, dtype=float)
    cur = np.asarray(volume, dtype=float)
    if prev.ndim != 3 or cur.shape != prev.shape:
        raise ValueError(f"volumes must be 3-D and of one shape, got {prev.shape} and {cur.shape}")
    if not dt > 0:
        raise ValueError(f"dt must be positive, got {dt}")
    spacing = np.broadcast_to(np.asarray(spacing_mm, dtype=float), (3,))
    if not np.all(spacing > 0):
        raise ValueError(f"spacing_mm must be positive, got {spacing_mm!r}")
    k_half = _half_sizes(kernel_half, 3, "kernel_half")
    s_half = _half_sizes(search_half, 3, "search_half")
    if np.any(s_half < k_half):
        raise ValueError(
            f"search_half {tuple(s_half)} must be at least kernel_half {tuple(k_half)}"
        )
    tip = np.asarray(tip_index)
    if tip.shape != (3,) or np.any(tip != np.round(tip)):
        raise ValueError(f"tip_index must be three integers, got {tip_index!r}")
    tip = tip.astype(int)
    shape = np.asarray(prev.shape)
    if np.any(tip < 0) or np.any(tip >= shape):
        raise ValueError(f"tip_index {tuple(tip)} lies outside the volume of shape {prev.shape}")
    k_lo, k_hi = np.maximum(tip - k_half, 0), np.minimum(tip + k_half + 1, shape)
    s_lo, s_hi = np.maximum(tip - s_half, 0), np.minimum(tip + s_half + 1, shape)
    kernel = prev[tuple(slice(a, b) for a, b in zip(k_lo, k_hi, strict=True))]
    search = cur[tuple(slice(a, b) for a, b in zip(s_lo, s_hi, strict=True))]
    _check_kernel_search(kernel, search)
    rho, index, offset = _fncc_peak(kernel, search)
    displacement_vox = (s_lo + index + offset) - k_lo  # best match corner - kernel corner
    displacement_mm = displacement_vox * spacing
    return TipVelocity(
        velocity_mm_s=displacement_mm / dt,  # Zhao 2013: displacement / time
        displacement_mm=displacement_mm,
        peak=float(rho[tuple(index)]),
    )
