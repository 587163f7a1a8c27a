"""The PSF's Gaussian blur of the splatted IQ grids, with a width that varies with depth.

Along an axis whose PSF width varies with the row (depth), the blur is that of a few anchor
widths interpolated linearly row by row (depth bands): row i is blurred with
``sum_k w_k(i) g_k``, g_k the Gaussian of anchor k truncated at 3 sigma with zero outside the
grid (``scipy.ndimage.gaussian_filter1d(..., mode="constant", truncate=3.0)``). A 2D image,
(H, W, 2), goes through OpenCV one anchor at a time; a volume, (A, B, C, 2), through one
compiled pass per axis in which each row applies its own mixed kernel (sums in float64).
"""

from __future__ import annotations

import cv2
import numba
import numpy as np
from scipy.ndimage import gaussian_filter1d

__all__ = ["SPLAT_VAR", "blur_axis", "blur_const"]

SPLAT_VAR = 1.0 / 6.0  # variance (px^2) of the linear splat kernel along one axis


def _bands(sigma_rows: np.ndarray, varying: bool) -> tuple[np.ndarray, np.ndarray] | None:
    """Anchor sigmas and the (rows, anchors) weights of the depth bands; a single anchor (the
    median sigma) of weight 1 when ``varying`` is False or the width hardly varies; None
    when there is nothing to blur.

    ``sigma_rows`` (px) includes the splat kernel, whose variance is taken out here.
    """
    s = np.sqrt(np.maximum(np.asarray(sigma_rows, float) ** 2 - SPLAT_VAR, 0.0))
    if s.max() < 0.05:
        return None
    if not varying or s.max() - s.min() < 0.05 * s.max():
        sig = float(np.median(s))
        return (np.array([sig]), np.ones((len(s), 1))) if sig >= 0.05 else None
    anchors = np.unique(np.round(np.linspace(s.min(), s.max(), 4), 3))
    pos = np.interp(s, anchors, np.arange(len(anchors)))
    w = np.clip(1.0 - np.abs(pos[:, None] - np.arange(len(anchors))[None]), 0.0, 1.0)
    return anchors, w


def _gaussian(sigma: float, radius: int) -> np.ndarray:
    """scipy's normalised Gaussian kernel of ``sigma`` (truncated at 3 sigma), zero-padded to
    ``radius``; a unit impulse below sigma 0.05 (no blur)."""
    out = np.zeros(2 * radius + 1)
    if sigma < 0.05:
        out[radius] = 1.0
        return out
    r = int(3.0 * sigma + 0.5)
    x = np.arange(-r, r + 1)
    g = np.exp(-0.5 / (sigma * sigma) * x**2)
    out[radius - r:radius + r + 1] = g / g.sum()
    return out


def blur_axis(arr: np.ndarray, axis: int, sigma_rows: np.ndarray) -> np.ndarray:
    """Gaussian blur of a (..., 2) array along ``axis`` with a sigma (px, splat kernel
    included) per row of axis 0; along axis 0 itself the median sigma is used. A volume,
    float32 or float64, comes back float32 (the input itself when nothing is blurred).

    ``arr`` may hold only the first rows of the grid ``sigma_rows`` describes (the rest being
    zero): it is blurred with the whole grid's bands and median, as the whole grid would be."""
    bands = _bands(sigma_rows, varying=axis != 0)
    if bands is None:
        return arr
    anchors, w = bands
    w = w[:arr.shape[0]]
    if arr.ndim == 4 and arr.dtype in (np.float32, np.float64):
        radius = max(int(3.0 * a + 0.5) if a >= 0.05 else 0 for a in anchors)
        g = np.stack([_gaussian(a, radius) for a in anchors])
        kernels = np.ascontiguousarray(w @ g)  # (rows, 2 radius + 1)
        a4 = np.ascontiguousarray(arr)
        out = np.empty(a4.shape, np.float32)
        if axis == 0:
            _blur_rows_axis0(a4.reshape(a4.shape[0], -1), kernels[0],
                             out.reshape(a4.shape[0], -1))
        elif axis == 1:
            n = a4.shape[2] * a4.shape[3]
            _blur_rows_axis1(a4.reshape(*a4.shape[:2], n), kernels,
                             out.reshape(*a4.shape[:2], n))
        else:
            n = a4.shape[2] * a4.shape[3]
            _blur_rows_axis2(a4.reshape(*a4.shape[:2], n), kernels, a4.shape[3],
                             out.reshape(*a4.shape[:2], n))
        return out
    if len(anchors) == 1:
        return blur_const(arr, axis, float(anchors[0]))
    out = np.zeros_like(arr)
    shape = [-1] + [1] * (arr.ndim - 1)
    for k, a in enumerate(anchors):
        rows = np.flatnonzero(w[:, k] > 0)
        if len(rows) == 0:
            continue
        lo, hi = rows[0], rows[-1] + 1
        # rows are blurred independently along the other axes: only the band's rows
        part = arr[lo:hi] if axis else arr
        b = blur_const(part, axis, a) if a >= 0.05 else part
        b = b if axis else b[lo:hi]
        out[lo:hi] += b * w[lo:hi, k].reshape(shape).astype(np.float32)
    return out


def blur_const(arr: np.ndarray, axis: int, sigma: float) -> np.ndarray:
    """Gaussian blur of constant ``sigma`` (px) along ``axis``, zero outside the array."""
    if arr.ndim == 3:  # a 2D complex image as (H, W, 2): OpenCV is much faster
        if axis == 0:
            return cv2.GaussianBlur(arr, (1, 2 * int(np.ceil(3 * sigma)) + 1), sigmaX=0.0001,
                                    sigmaY=sigma, borderType=cv2.BORDER_CONSTANT)
        return cv2.GaussianBlur(arr, (2 * int(np.ceil(3 * sigma)) + 1, 1), sigmaX=sigma,
                                sigmaY=0.0001, borderType=cv2.BORDER_CONSTANT)
    return gaussian_filter1d(arr, sigma, axis=axis, mode="constant", truncate=3.0)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _blur_rows_axis0(arr, kernel, out):  # pragma: no cover - compiled
    """out[i] = sum_m kernel[m] arr[i + m - r] over rows (A, L), zero outside."""
    A, L = arr.shape
    r = (kernel.shape[0] - 1) // 2
    acc = np.empty(L)
    for i in range(A):
        acc[:] = 0.0
        for m in range(kernel.shape[0]):
            ii = i + m - r
            w = kernel[m]
            if ii < 0 or ii >= A or w == 0.0:
                continue
            src = arr[ii]
            for k in range(L):
                acc[k] += w * src[k]
        dst = out[i]
        for k in range(L):
            dst[k] = acc[k]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _blur_rows_axis1(arr, kernels, out):  # pragma: no cover - compiled
    """out[i, j] = sum_m kernels[i, m] arr[i, j + m - r] for (A, B, L) arrays."""
    A, B, L = arr.shape
    r = (kernels.shape[1] - 1) // 2
    acc = np.empty(L)
    for i in range(A):
        for j in range(B):
            acc[:] = 0.0
            for m in range(kernels.shape[1]):
                jj = j + m - r
                w = kernels[i, m]
                if jj < 0 or jj >= B or w == 0.0:
                    continue
                src = arr[i, jj]
                for k in range(L):
                    acc[k] += w * src[k]
            dst = out[i, j]
            for k in range(L):
                dst[k] = acc[k]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _blur_rows_axis2(arr, kernels, inner, out):  # pragma: no cover - compiled
    """The blur of :func:`_blur_rows_axis1` along the third axis of an (A, B, C, inner)
    array given as (A, B, C * inner)."""
    A, B, L = arr.shape
    r = (kernels.shape[1] - 1) // 2
    acc = np.empty(L)
    for i in range(A):
        for j in range(B):
            acc[:] = 0.0
            for m in range(kernels.shape[1]):
                w = kernels[i, m]
                if w == 0.0:
                    continue
                sh = (m - r) * inner
                lo = max(0, -sh)
                hi = min(L, L - sh)
                src = arr[i, j, lo + sh:hi + sh]
                part = acc[lo:hi]
                for k in range(hi - lo):
                    part[k] += w * src[k]
            dst = out[i, j]
            for k in range(L):
                dst[k] = acc[k]
