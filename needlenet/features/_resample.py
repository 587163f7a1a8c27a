"""Resampling between a frame's grid and a model's grid: one implementation, used by the
runtime (learned feature source) and by training, so both see the same images."""

from __future__ import annotations

import functools

import cv2
import numba
import numpy as np

from synth import Grid

__all__ = ["model_shape", "model_grid", "to_model_grid", "to_frame_grid", "pad_to_multiple",
           "image_level", "image_statistics", "frame_image_statistics", "frame_statistics",
           "normalize", "NORMALIZATIONS", "clip_unit",
           "axis_weights", "resize_weights", "apply_weights"]

# Intensity normalisations a model can be trained with (stored in its ONNX metadata):
# "fixed": (I / 255 - 0.35) / 0.25, the same for every image;
# "median": I / level - 1 with level the median of the frame's non-zero pixels: invariant to
#   the scanner's gain and to the tissue's grey level, so a needle at contrast ratio CR
#   (Zhao eq. 9) reads CR - 1 whatever the preset.
# "robust": (I - median) / (1.4826 MAD) over the frame's non-zero pixels, clipped to "clip";
#   zero pixels (black capture margins, outside a sector) read "zero_value". Log compression
#   turns a gain change into a grey offset and a dynamic-range change into a grey scale, so
#   this input is invariant to both (1.4826 MAD is the standard deviation of a Gaussian).
NORMALIZATIONS = {
    "fixed": {"mode": "fixed", "scale": 1 / 255.0, "mean": 0.35, "std": 0.25},
    "median": {"mode": "median", "scale": 1.0, "mean": 1.0, "std": 1.0},
    "robust": {"mode": "robust", "scale": 1.0, "mean": 0.0, "std": 1.0, "clip": [-4.0, 12.0],
               "zero_value": -3.0},
}
MAD_TO_SIGMA = 1.4826  # 1 / Phi^-1(3/4): the MAD of a Gaussian times this is its sigma


def model_shape(shape, spacing_mm, model_spacing_mm) -> tuple[int, ...]:
    """Array shape of a frame of ``shape`` at ``spacing_mm`` resampled to the model spacing."""
    return tuple(max(int(round(n * s / m)), 1)
                 for n, s, m in zip(shape, spacing_mm, model_spacing_mm, strict=True))


def _resize2d(a: np.ndarray, shape: tuple[int, int], order: int) -> np.ndarray:
    if tuple(a.shape) == tuple(shape):
        return a
    if order == 0:
        interp = cv2.INTER_NEAREST
    elif shape[0] <= a.shape[0] and shape[1] <= a.shape[1]:
        interp = cv2.INTER_AREA  # shrinking: average, do not alias the speckle
    else:
        interp = cv2.INTER_LINEAR
    return cv2.resize(a, (shape[1], shape[0]), interpolation=interp)


def _resize(a: np.ndarray, shape: tuple[int, ...], order: int) -> np.ndarray:
    """Linear (or nearest) resampling with half-pixel centres; separable passes in 3D."""
    if tuple(a.shape) == tuple(shape):
        return a
    if a.ndim == 2:
        return _resize2d(a, shape, order)
    d, h, w = a.shape
    D, H, W = shape
    if (h, w) != (H, W):  # in-plane, slice by slice
        a = np.stack([_resize2d(a[k], (H, W), order) for k in range(d)])
    if d != D:  # along depth: a (d, H*W) image resized to (D, H*W), in column blocks
        flat = a.reshape(d, H * W)  # (OpenCV limits image widths to 32767)
        a = np.concatenate([_resize2d(np.ascontiguousarray(flat[:, i:i + 8192]),
                                      (D, min(8192, H * W - i)), order)
                            for i in range(0, H * W, 8192)], axis=1).reshape(D, H, W)
    return a


def axis_weights(n_src: int, n_dst: int, area: bool) -> np.ndarray:
    """(n_dst, n_src) weights of OpenCV's one-axis resampling of ``n_src`` samples to
    ``n_dst``: ``INTER_AREA`` (the share of each source pixel in the destination pixel's
    footprint; OpenCV uses it when shrinking) or ``INTER_LINEAR`` (half-pixel centres, the
    ends clamped). :func:`_resize` is separable, so its result is these matrices applied along
    each axis (:func:`resize_weights`); a row range of them resamples part of a frame."""
    w = np.zeros((n_dst, n_src))
    if n_src == n_dst:
        return np.eye(n_src)
    scale = 1.0 / (n_dst / n_src)  # as OpenCV computes it
    if area:
        for d in range(n_dst):
            f1 = d * scale
            f2 = f1 + scale
            cell = min(scale, n_src - f1)
            s1, s2 = int(np.ceil(f1)), int(np.floor(f2))
            s2 = min(s2, n_src - 1)
            s1 = min(s1, s2)
            if s1 - f1 > 1e-3:
                w[d, s1 - 1] += (s1 - f1) / cell
            w[d, s1:s2] += 1.0 / cell
            if f2 - s2 > 1e-3:
                w[d, s2] += min(f2 - s2, 1.0, cell) / cell
        return w
    f = (np.arange(n_dst) + 0.5) * scale - 0.5
    s = np.floor(f).astype(int)
    frac = f - s
    lo = s < 0
    hi = s >= n_src - 1
    frac[lo | hi] = 0.0
    s = np.clip(s, 0, n_src - 1)
    rows = np.arange(n_dst)
    w[rows, s] += 1.0 - frac
    inner = ~(lo | hi)
    w[rows[inner], s[inner] + 1] += frac[inner]
    return w


def resize_weights(shape, new_shape) -> list[np.ndarray]:
    """Per-axis weights (:func:`axis_weights`) with which :func:`_resize` (linear) takes an
    array of ``shape`` to ``new_shape``: the interpolation each axis gets follows its rules
    (area where a 2D image or, in 3D, a slice shrinks along both axes, and along the depth
    where it shrinks; linear otherwise)."""
    shape, new_shape = tuple(shape), tuple(new_shape)
    inplane = shape[-2:]
    area2 = new_shape[-2] <= inplane[0] and new_shape[-1] <= inplane[1]
    out = [axis_weights(n, m, area2) for n, m in zip(inplane, new_shape[-2:], strict=True)]
    if len(shape) == 3:
        out.insert(0, axis_weights(shape[0], new_shape[0], new_shape[0] <= shape[0]))
    return out


@numba.njit(cache=True, nogil=True)
def _resample_axis(x, index, weight):  # pragma: no cover - compiled
    """(A, N, B) -> (A, M, B): out[a, m, b] = sum_k weight[m, k] x[a, index[m, k], b]."""
    n_a, _, n_b = x.shape
    n_m, n_k = index.shape
    out = np.zeros((n_a, n_m, n_b), np.float32)
    for a in range(n_a):
        for m in range(n_m):
            for k in range(n_k):
                w = weight[m, k]
                if w != 0.0:
                    s = index[m, k]
                    for b in range(n_b):
                        out[a, m, b] += w * x[a, s, b]
    return out


def apply_weights(a: np.ndarray, weights) -> np.ndarray:
    """``a`` (its trailing ``len(weights)`` axes spatial, any leading ones) resampled by one
    weight matrix per spatial axis (rows: output samples, columns: ``a``'s samples), float32.

    The matrices are banded (a few source samples per output sample): each axis is one
    single-threaded pass over its non-zero weights, the last axis first. (A dense matrix
    product does 20-50 times the work, and the BLAS spreads it over threads that on a loaded
    machine wait for cores: 12 ms for what takes 0.4 ms unloaded.)"""
    out = np.ascontiguousarray(a, np.float32)
    d = len(weights)
    for k in range(d - 1, -1, -1):
        w = np.asarray(weights[k])
        nz = w != 0
        n_k = max(int(nz.sum(axis=1).max(initial=0)), 1)
        index = np.argsort(~nz, axis=1, kind="stable")[:, :n_k]  # the non-zero columns first
        weight = np.take_along_axis(w, index, axis=1).astype(np.float32)
        ax = out.ndim - d + k
        shape = out.shape
        before = int(np.prod(shape[:ax], dtype=np.int64))
        after = int(np.prod(shape[ax + 1:], dtype=np.int64))
        res = _resample_axis(out.reshape(before, shape[ax], after), index.astype(np.int64),
                             weight)
        out = res.reshape(shape[:ax] + (w.shape[0],) + shape[ax + 1:])
    return out


def model_grid(grid: Grid, shape) -> Grid:
    """The grid of an array of ``shape`` resampled from ``grid`` by :func:`_resize` (cv2's
    half-pixel centres): sample i lies at frame index (i + 1/2) n / m - 1/2 per axis."""
    return _model_grid(grid, tuple(int(k) for k in shape))


@functools.lru_cache(maxsize=64)  # a recording's frames share their grid
def _model_grid(grid: Grid, shape: tuple[int, ...]) -> Grid:
    n = np.asarray(grid.shape, float)
    m = np.asarray(shape, float)
    sp = np.asarray(grid.spacing_mm, float)
    ratio = n / m
    origin = np.asarray(grid.origin_mm, float) + (0.5 * ratio - 0.5) * sp
    return Grid(tuple(int(k) for k in shape), tuple(float(v) for v in ratio * sp),
                tuple(float(v) for v in origin))


def to_model_grid(image: np.ndarray, spacing_mm, model_spacing_mm) -> np.ndarray:
    """A frame (uint8 or float, array order) resampled to the model's spacing, float32."""
    a = np.asarray(image, np.float32)
    return _resize(a, model_shape(a.shape, spacing_mm, model_spacing_mm), 1)


def to_frame_grid(maps: np.ndarray, frame_shape) -> np.ndarray:
    """Maps (C, *model_shape) back to the frame's shape (C, *frame_shape), linear."""
    shape = tuple(frame_shape)
    m0 = np.asarray(maps)
    if m0.ndim != 3 or m0.dtype != np.float32 or m0.shape[1:] == shape:
        return np.stack([_resize(np.ascontiguousarray(m), shape, 1) for m in m0])
    # 2D maps: each resized straight into the output (fresh arrays per channel, then a
    # stack, took six times as long)
    out = np.empty((len(m0), *shape), np.float32)
    interp = cv2.INTER_AREA if shape[0] <= m0.shape[1] and shape[1] <= m0.shape[2] else \
        cv2.INTER_LINEAR  # as _resize2d chooses
    for c, m in enumerate(m0):
        r = cv2.resize(np.ascontiguousarray(m), (shape[1], shape[0]), dst=out[c],
                       interpolation=interp)
        if not np.may_share_memory(r, out):  # an OpenCV that did not write into dst
            out[c] = r
    return out


def pad_to_multiple(a: np.ndarray, multiple: int) -> tuple[np.ndarray, tuple[slice, ...]]:
    """Pad the trailing spatial axes to a multiple (edge values, as ``np.pad``'s ``"edge"``
    mode); return the crop back."""
    pads = [(-n) % multiple for n in a.shape]
    crop = tuple(slice(0, n) for n in a.shape)
    if not any(pads):
        return a, tuple(slice(None) for _ in a.shape)
    out = np.empty([n + k for n, k in zip(a.shape, pads, strict=True)], a.dtype)
    out[crop] = a
    for axis, (n, k) in enumerate(zip(a.shape, pads, strict=True)):
        if k:  # the last sample along this axis, repeated (corners from the axes before)
            last = [slice(None)] * a.ndim
            last[axis] = slice(n - 1, n)
            more = [slice(None)] * a.ndim
            more[axis] = slice(n, n + k)
            out[tuple(more)] = out[tuple(last)]
    return out, crop


def _subsample(image: np.ndarray, max_samples: int) -> np.ndarray:
    a = np.asarray(image)
    step = max(1, int(np.ceil((a.size / max_samples) ** (1.0 / a.ndim))))
    return a[(slice(None, None, step),) * a.ndim]


def _nonzero_subsample(image: np.ndarray, max_samples: int) -> np.ndarray:
    sub = _subsample(image, max_samples)
    return sub[sub != 0]


def image_level(image: np.ndarray, max_samples: int = 65536) -> float:
    """The median of the non-zero pixels (zero: outside a sector scan) of a regular
    subsample of ``image``; 1.0 for an all-zero image."""
    nz = _nonzero_subsample(image, max_samples)
    return float(np.median(nz)) if nz.size else 1.0


def _histogram_median(counts: np.ndarray) -> float:
    """The median (the mean of the two middle values for an even count, as ``np.median``) of
    the integers 0, 1, ... taken ``counts`` times each."""
    c = np.cumsum(counts)
    n = int(c[-1])
    lo = int(np.searchsorted(c, (n - 1) // 2 + 1))
    hi = int(np.searchsorted(c, n // 2 + 1))
    return 0.5 * (lo + hi)


def _counts_median_mad(counts: np.ndarray) -> tuple[float, float]:
    """``np.median`` of the integers 0, 1, ... taken ``counts`` times each and of their
    absolute deviations from it, from the histogram (a frame's statistics in 0.1 ms instead of
    1 ms)."""
    med = _histogram_median(counts)
    # deviations |v - med| in half-units, integers whether the median is whole or not
    twice = np.abs(2 * np.arange(len(counts)) - int(round(2 * med)))
    return med, 0.5 * _histogram_median(np.bincount(twice, weights=counts))


def clip_unit(a: np.ndarray) -> np.ndarray:
    """``a`` clipped to [0, 1] in place, NaN set to 0 (a model that fails somewhere gives no
    evidence there: the tracker then says lost, never a NaN estimate); returns ``a``."""
    np.clip(a, 0.0, 1.0, out=a)
    a[np.isnan(a)] = 0.0
    return a


def image_statistics(image: np.ndarray, max_samples: int = 65536) -> tuple[float, float]:
    """(median, 1.4826 MAD) of the non-zero pixels of a regular subsample of ``image``: the
    robust centre and spread of the ``"robust"`` normalisation. The spread falls back to the
    standard deviation where the MAD is 0, and to 1 where that is 0 too (one grey value);
    an all-zero image gives (0, 1)."""
    a = np.asarray(image)
    if a.dtype in (np.uint8, np.uint16):  # grey levels: the same numbers from histograms
        counts = np.bincount(_subsample(a, max_samples).ravel())
        counts[0] = 0  # black (a margin, outside a sector): not counted
        if not counts.any():
            return 0.0, 1.0
        med, mad = _counts_median_mad(counts)
    else:
        nz = _nonzero_subsample(a, max_samples).astype(np.float64)
        if nz.size == 0:
            return 0.0, 1.0
        med = float(np.median(nz))
        mad = float(np.median(np.abs(nz - med)))
    spread = MAD_TO_SIGMA * mad
    if not spread > 0:
        spread = float(_nonzero_subsample(a, max_samples).astype(np.float64).std())
    return med, (spread if spread > 0 else 1.0)


def frame_image_statistics(frame) -> tuple[float, float]:
    """:func:`image_statistics` of a :class:`~needlenet.features.Frame`'s image, read once per
    frame (kept in ``frame.extras``): the robust normalisation of the learned features and the
    trackers' speckle spread read the same two numbers."""
    if "image_statistics" not in frame.extras:
        frame.extras["image_statistics"] = image_statistics(np.asarray(frame.image))
    return frame.extras["image_statistics"]


def frame_statistics(image: np.ndarray, norm: dict):
    """What :func:`normalize` needs from the whole frame under ``norm``: None ("fixed"),
    :func:`image_level` ("median") or :func:`image_statistics` ("robust"). An ROI is
    normalised with its frame's statistics."""
    mode = norm.get("mode", "fixed")
    if mode == "median":
        return image_level(image)
    if mode == "robust":
        return image_statistics(image)
    return None


def normalize(x: np.ndarray, norm: dict, level: float | None = None) -> np.ndarray:
    """Model input from grey levels ``x`` (0-255, float32) under normalisation ``norm``
    (see :data:`NORMALIZATIONS`); ``level`` is :func:`frame_statistics` of the whole frame
    (an ROI is normalised like the frame it comes from; computed from ``x`` when None)."""
    mode = norm.get("mode", "fixed")
    mean, std = np.float32(norm["mean"]), np.float32(norm["std"])
    if mode == "fixed":
        return (x * np.float32(norm["scale"]) - mean) / std
    if mode == "median":
        if level is None:
            level = image_level(x)
        return (x / np.float32(max(level, 1e-3)) - mean) / std
    if mode == "robust":
        med, spread = image_statistics(x) if level is None else level
        lo, hi = norm.get("clip", NORMALIZATIONS["robust"]["clip"])
        # in place on one new array: the same numbers as the expression written out
        z = x - np.float32(med)
        z /= np.float32(spread)
        np.clip(z, np.float32(lo), np.float32(hi), out=z)
        if mean != 0:  # (z - 0) / 1 is z
            z -= mean
        if std != 1:
            z /= std
        z[x == 0] = np.float32(norm.get("zero_value", NORMALIZATIONS["robust"]["zero_value"]))
        return z.astype(np.float32, copy=False)
    raise ValueError(f"unknown intensity normalisation mode {mode!r}")
