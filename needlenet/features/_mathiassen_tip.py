"""Mathiassen 2017's tip features (IEEE TCST 25(3), section II-B) along an axis found by
:mod:`._mathiassen_axis`, and the fitted weights of h(x).

- :func:`tip_features` and :func:`tip_likelihood`: the five features E_1..E_5 along the axis
  (eqs. 7-10) and h(x) = w^T E(x) (eq. 6, Algorithm 3); :func:`tip_map_along_axis` is h(x)
  for a learned source that predicts a tip map;
- :class:`TipWeights` and :func:`load_tip_weights`: the shipped w of eq. (6) with its
  calibration, written by ``training/mathiassen_fit.py``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from synth import Grid

from ._mathiassen_axis import (
    N_FEATURES,
    AxisEstimate,
    MathiassenParams,
    _as_float_image,
    _axis_length_mm,
    _n,
    _remap,
    _step_mm,
    axis_vectors,
)

__all__ = [
    "TipFeatures",
    "TipWeights",
    "kernel_sq",
    "kernel_gpp",
    "region_difference",
    "tip_features",
    "tip_likelihood",
    "tip_map_along_axis",
    "load_tip_weights",
    "weights_path",
]


# --------------------------------------------------------------------------- tip features


def kernel_sq(length_px: int, width_px: int) -> np.ndarray:
    """K^SQ of eq. (9), shape (width, length) = (v_p, v_n): +1 where the scaled |y_s| < 1/2,
    -1 elsewhere, y_s from -1 to 1 across the kernel. Each part is divided by its pixel count
    so that the kernel has zero mean and its response is in the image's units."""
    if length_px < 1 or width_px < 3:
        raise ValueError(f"K^SQ needs length >= 1 and width >= 3, got {length_px}, {width_px}")
    y_s = np.linspace(-1.0, 1.0, int(width_px))
    inner = np.abs(y_s) < 0.5  # eq. (9)
    col = np.where(inner, 1.0 / inner.sum(), -1.0 / (~inner).sum())
    return np.repeat(col[:, None], int(length_px), axis=1) / int(length_px)


def kernel_gpp(size_px: int, zero_px: float) -> np.ndarray:
    """K^G'' of eq. (10) across the needle, y in [-(s_y-1)/2, (s_y-1)/2]:
    -2 (s^2 y^2 / sigma^2 - 1) exp(-s^2 y^2 / sigma^2), with s_scale / sigma = 1 / ``zero_px``
    so that it is positive on +-s_n/2 (section III-B). As printed it is not zero-mean; it is
    scaled so that its positive part sums to one."""
    if size_px < 3:
        raise ValueError(f"K^G'' needs s_y >= 3, got {size_px}")
    y = np.arange(size_px) - (size_px - 1) / 2.0
    a2 = (y / float(zero_px)) ** 2
    k = -2.0 * (a2 - 1.0) * np.exp(-a2)  # eq. (10)
    return k / k[k > 0].sum()


def region_difference(profile: np.ndarray, length: int) -> np.ndarray:
    """Eq. (7) along the axis: mean of the ``length`` samples behind x (TR, towards the entry)
    minus the mean of the ``length`` samples from x on (LR), over the last axis. The ends are
    padded with the edge values."""
    f = np.asarray(profile, dtype=np.float64)
    L = int(length)
    pad = [(0, 0)] * (f.ndim - 1) + [(L, L)]
    c = np.concatenate([np.zeros(f.shape[:-1] + (1,)),
                        np.cumsum(np.pad(f, pad, mode="edge"), axis=-1)], axis=-1)
    n = f.shape[-1]
    i = np.arange(n) + L  # index of x in the padded profile
    trailing = c[..., i] - c[..., i - L]  # sum over [x - L, x)
    leading = c[..., i + L] - c[..., i]  # sum over [x, x + L)
    return (trailing - leading) / L  # eq. (7)


@dataclass(frozen=True)
class TipFeatures:
    """Everything sampled along one axis: ``x_mm`` (n,) positions from the ROI corner,
    ``E`` (5, n) the features E_1..E_5 (None for a learned tip map), ``line`` (n,) the
    feature image on the line echo and ``background`` (n,) and ``background_sd`` (n,) the mean
    and spread of the band above it, for the shaft contrast. ``null_difference`` (n,): the same
    line-minus-band difference with both moved up by as much as the strip allows (1.4 mm:
    the band then ends at the strip's edge), where both lie in tissue: what the difference is
    where no line is; None for a learned source."""

    x_mm: np.ndarray
    E: np.ndarray | None
    line: np.ndarray
    background: np.ndarray
    background_sd: np.ndarray
    null_difference: np.ndarray | None = None

    def shaft_contrast(self, x_from_mm: float, x_to_mm: float, floor: float = 0.02) -> float:
        """(mean line - mean background) / background spread over [x_from, x_to]: about 0 on
        tissue, a few units on a needle. ``floor`` bounds the spread from below (feature
        units) so that a clean probability map does not divide by zero."""
        sel = (self.x_mm >= x_from_mm) & (self.x_mm <= x_to_mm)
        if sel.sum() < 2:
            return 0.0
        sd = max(float(np.sqrt(np.mean(self.background_sd[sel] ** 2))), floor)
        return float((self.line[sel].mean() - self.background[sel].mean()) / sd)


def _strip(image: np.ndarray, grid: Grid, axis: AxisEstimate, x_mm: np.ndarray,
           y_mm: np.ndarray) -> np.ndarray:
    """The image resampled on (y, x): point A + (p_p + y) v_p + x v_n."""
    vn, vp = axis_vectors(axis.theta_deg)
    base = axis.anchor_mm + axis.p_p_mm * vp
    pts_x = base[0] + y_mm[:, None] * vp[0] + x_mm[None, :] * vn[0]
    pts_z = base[1] + y_mm[:, None] * vp[1] + x_mm[None, :] * vn[1]
    return _remap(_as_float_image(image), grid, pts_x, pts_z)


def _axis_samples(grid: Grid, axis: AxisEstimate) -> np.ndarray:
    step = _step_mm(grid)
    length = _axis_length_mm(grid, axis.anchor_mm, axis.theta_deg, axis.p_p_mm)
    return step * np.arange(max(2, int(np.floor(length / step)) + 1))


def _contrast_rows(y: np.ndarray, p: MathiassenParams):
    line = np.abs(y) <= p.line_half_width_mm + 1e-9
    lo, hi = p.background_band_mm
    bg = (y >= lo - 1e-9) & (y <= hi + 1e-9)
    return line, bg


def tip_features(image: np.ndarray, previous: np.ndarray | None, grid: Grid,
                 axis: AxisEstimate, params: MathiassenParams | None = None) -> TipFeatures:
    """E_1..E_5 of section II-B1 along the axis (Algorithm 3, lines 2-3), one sample per pixel.

    E_1: eq. (7) on the image; E_2: eq. (7) on I^Delta = I_k - I_{k-delta} (eq. 8, ``previous``
    is I_{k-delta}; None gives E_2 = 0); E_3: eq. (7) on the image filtered by K^SQ (eq. 9);
    E_4: eq. (7) on the image filtered by K^G'' (eq. 10); E_5: eq. (7) on the K^SQ image read
    n below the axis ("shifting the image n pixels up"). The kernels are aligned with the axis,
    so the image is resampled on a strip along it and filtered there with 1-D operations.
    """
    p = MathiassenParams() if params is None else params
    step = _step_mm(grid)
    x = _axis_samples(grid, axis)
    # +-gpp_size_mm / 2 across the axis (K^G''), and at least the background band and the
    # K^SQ kernel when pixels as coarse as they are round it below them
    far = max(abs(p.background_band_mm[0]), abs(p.background_band_mm[1]), 0.5 * p.sq_width_mm)
    half = max(_n(p.gpp_size_mm, step) // 2, int(np.ceil(far / step - 1e-9)))
    y = step * np.arange(-half, half + 1)
    strip = _strip(image, grid, axis, x, y).astype(np.float64)  # rows y, columns x
    line_rows, bg_rows = _contrast_rows(y, p)
    line = strip[line_rows].mean(axis=0)
    L = _n(p.region_length_mm, step)
    E1 = region_difference(line, L)  # eq. (7) on I^GS
    if previous is None:
        E2 = np.zeros_like(E1)
    else:
        prev = _strip(previous, grid, axis, x, y[line_rows]).astype(np.float64).mean(axis=0)
        E2 = region_difference(line - prev, L)  # eqs. (7)-(8)
    # K^SQ: +-1 across the needle times a box of length s_x along it (separable)
    sq_w = _n(p.sq_width_mm, step) | 1
    k_sq = kernel_sq(1, sq_w)[:, 0]
    sq_len = _n(p.sq_length_mm, step)
    box = np.ones(sq_len) / sq_len

    def sq_at(offset_rows: int) -> np.ndarray:
        r0 = half + offset_rows - sq_w // 2
        across = k_sq @ strip[r0:r0 + sq_w]
        along = np.convolve(np.pad(across, (sq_len, sq_len), mode="edge"), box, mode="same")
        return along[sq_len:-sq_len]

    sq0 = sq_at(0)
    shift = int(round(p.sq_shift_mm / step))
    if shift:
        sq0 = np.roll(np.pad(sq0, shift, mode="edge"), -shift)[shift:-shift]
    E3 = region_difference(sq0, L)  # eq. (7) on the K^SQ image, eq. (9)
    k_g = kernel_gpp(2 * half + 1, p.gpp_zero_mm / step)
    E4 = region_difference(k_g @ strip, L)  # eq. (7) on the K^G'' image, eq. (10)
    n_rows = _n(p.bevel_shift_mm, step)
    n_rows = min(n_rows, half - sq_w // 2)
    E5 = region_difference(sq_at(n_rows), L)  # eq. (7), K^SQ image shifted n up
    bg = strip[bg_rows]
    up = int(np.flatnonzero(bg_rows)[0])  # rows from the strip's top edge to the band's
    null = None
    if y[up] - y[0] > 2 * p.line_half_width_mm:  # the moved line stays clear of the echo
        null = (strip[np.roll(line_rows, -up)].mean(axis=0)
                - strip[np.roll(bg_rows, -up)].mean(axis=0))
    return TipFeatures(x, np.stack([E1, E2, E3, E4, E5]), line, bg.mean(axis=0),
                       bg.std(axis=0), null)


def tip_likelihood(features: TipFeatures, weights) -> np.ndarray:
    """h(x) = sum_i w_i E_i(x), eq. (6) (Algorithm 3, line 4)."""
    w = np.asarray(weights, dtype=float)
    if features.E is None:
        raise ValueError("these features come from a tip map; h(x) is the map itself")
    if w.shape != (features.E.shape[0],):
        raise ValueError(f"need {features.E.shape[0]} weights, got shape {w.shape}")
    return w @ features.E  # eq. (6)


def tip_map_along_axis(shaft: np.ndarray, tip_map: np.ndarray, grid: Grid,
                       axis: AxisEstimate, params: MathiassenParams | None = None
                       ) -> tuple[TipFeatures, np.ndarray]:
    """The learned case: h(x) is the tip map read along the axis (its maximum within +-0.5 mm
    across it, so that a slightly offset axis still meets the peak); the shaft map gives the
    contrast profiles."""
    p = MathiassenParams() if params is None else params
    step = _step_mm(grid)
    x = _axis_samples(grid, axis)
    lo = min(p.background_band_mm[0], -0.5)
    half = _n(-lo, step)
    y = step * np.arange(-half, half + 1)
    shaft_strip = _strip(shaft, grid, axis, x, y).astype(np.float64)
    line_rows, bg_rows = _contrast_rows(y, p)
    band = np.abs(y) <= 0.5 + 1e-9
    h = _strip(tip_map, grid, axis, x, y[band]).astype(np.float64).max(axis=0)
    bg = shaft_strip[bg_rows]
    feats = TipFeatures(x, None, shaft_strip[line_rows].mean(axis=0), bg.mean(axis=0),
                        bg.std(axis=0))
    return feats, h


# --------------------------------------------------------------------------- the weights


@dataclass(frozen=True)
class TipWeights:
    """The fitted w of eq. (6) with the calibration that goes with it: ``axis_offset_mm`` from
    the line echo to the needle's centre line along v_p, ``tip_offset_mm`` from the maximum of
    h(x) to the tip along v_n, and the file's metadata."""

    weights: np.ndarray
    axis_offset_mm: float = 0.0
    tip_offset_mm: float = 0.0
    meta: dict = field(default_factory=dict, repr=False)


def weights_path() -> Path:
    """Where the shipped weight file lives (``needlenet/data/mathiassen_weights.json``)."""
    return Path(str(resources.files("needlenet").joinpath("data", "mathiassen_weights.json")))


def load_tip_weights(path: str | Path | None = None) -> TipWeights:
    """Read the weights of h(x) written by ``python -m training.mathiassen_fit``."""
    path = weights_path() if path is None else Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"Mathiassen tip weights not found at {path}; create them with "
            "`python -m training.mathiassen_fit`")
    data = json.loads(path.read_text())
    w = np.asarray(data.get("weights", []), dtype=float)
    if w.shape != (N_FEATURES,) or not np.all(np.isfinite(w)):
        raise ValueError(f"{path}: 'weights' must hold {N_FEATURES} finite numbers, got {w}")
    return TipWeights(w, float(data.get("axis_offset_mm", 0.0)),
                      float(data.get("tip_offset_mm", 0.0)), data)
