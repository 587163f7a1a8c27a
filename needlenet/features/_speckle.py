"""The speckle size of a 2D frame, and the model grid that makes it look like training's.

A network sees speckle at the size its training worlds had on its grid. Probes differ by
wavelength and aperture: a 2.7 MHz phased array's speckle measured 0.47 x 0.77 mm (axial x
lateral, full width at half maximum on a 0.2 mm grid), a 7.6 MHz linear array's 0.28 x 0.52,
and in a network trained on the second kind the first kind's broad bands and coarse speckle
are out of distribution. Resampling such a frame onto a coarser grid, by the ratio of its
speckle size to training's, shows the network speckle (and a needle band, whose width the
same point-spread function sets) of the size it learned.

The width is the full width at half maximum of the speckle's autocorrelation along each axis
(the resolution cell's size, Wagner et al. 1983), measured in tiles of the frame on the model's
grid after the local mean is removed, and the median over tiles, so that the needle, an
interface or a vessel in a few tiles does not move it. Tiles that reach into a black margin, a
sector mask or an anechoic region (a dark local mean) hold no speckle and are left out. The
local mean removed and the tile's finite size narrow the widths of coarse speckle (a
Gaussian-correlated field of 2.8 pixels' correlation reads 0.73 of its width): the same
estimator measures the training worlds' reference, so the ratio is what it compares.
"""

from __future__ import annotations

import cv2
import numpy as np

from ._resample import to_model_grid

__all__ = ["MAX_GRID_SCALE", "cell_size", "grid_scale", "speckle_widths"]

TILE = 32  # tile side on the model grid (6.4 mm at 0.2 mm): a few speckle cells of any probe
BOX = 9  # the local mean removed: 9 model pixels (1.8 mm at 0.2 mm), a few cells wide
MIN_TILES = 4  # fewer tiles of speckle than this: no estimate
# dark regions (margins, masks, anechoic lumen): a local mean at most this share of the
# frame's 1st-99th percentile range above its minimum
DARK_SHARE = 0.02
# the coarsest grid chosen: 3x the model's, where a 25 G needle (0.5 mm) on a 0.2 mm model's
# grid still spans most of a pixel
MAX_GRID_SCALE = 3.0


def _half_width(profiles: np.ndarray) -> np.ndarray:
    """Lag (in samples, interpolated) where each normalised autocorrelation profile first
    falls below 0.5; NaN where it never does within the tile."""
    below = profiles < 0.5
    i = np.argmax(below, axis=1)
    ok = below[np.arange(len(i)), i] & (i > 0)
    i = np.maximum(i, 1)
    a = profiles[np.arange(len(i)), i - 1]
    b = profiles[np.arange(len(i)), i]
    hw = (i - 1) + (a - 0.5) / np.where(a > b, a - b, 1.0)
    return np.where(ok, hw, np.nan)


def speckle_widths(image: np.ndarray, spacing_mm, grid_mm) -> np.ndarray | None:
    """(axial, lateral) full widths at half maximum of the speckle's autocorrelation, in mm,
    measured on a 2D frame resampled to ``grid_mm``; None when fewer than :data:`MIN_TILES`
    tiles of the frame hold speckle (a blank frame, a small one, one mostly masked)."""
    x = to_model_grid(np.nan_to_num(np.asarray(image, np.float32), nan=0.0, posinf=0.0,
                                    neginf=0.0), spacing_mm, grid_mm)
    if x.ndim != 2 or min(x.shape) < TILE:
        return None
    lo, p1, p99 = (float(v) for v in np.percentile(x, [0, 1, 99]))
    if not p99 > p1:
        return None
    mean = cv2.blur(x, (BOX, BOX), borderType=cv2.BORDER_REFLECT)
    lit = (mean > lo + DARK_SHARE * (p99 - p1)).astype(np.uint8)
    keep = cv2.erode(lit, np.ones((BOX, BOX), np.uint8), borderType=cv2.BORDER_REPLICATE)
    hp = x - mean
    nz, nx = x.shape[0] // TILE, x.shape[1] // TILE

    def tiles(a):
        return a[:nz * TILE, :nx * TILE].reshape(nz, TILE, nx, TILE).swapaxes(1, 2) \
            .reshape(nz * nx, TILE, TILE)

    t = tiles(hp)
    full = tiles(keep).all(axis=(1, 2))
    t = t[full] - t[full].mean(axis=(1, 2), keepdims=True)
    t = t[t.std(axis=(1, 2)) > 1e-6 * max(p99 - p1, 1e-12)]
    if len(t) < MIN_TILES:
        return None
    f = np.fft.rfft2(t, s=(2 * TILE, 2 * TILE))
    ac = np.fft.irfft2(f.real ** 2 + f.imag ** 2, s=(2 * TILE, 2 * TILE))
    ac /= ac[:, :1, :1]
    hw = np.stack([_half_width(ac[:, :TILE, 0]), _half_width(ac[:, 0, :TILE])], axis=1)
    good = np.isfinite(hw).all(axis=1)
    if good.sum() < MIN_TILES:
        return None
    return 2.0 * np.median(hw[good], axis=0) * np.asarray(grid_mm, float)


def cell_size(widths) -> float:
    """The speckle cell's size, mm: the geometric mean of its axial and lateral widths (the
    side of a square of the cell's area)."""
    return float(np.sqrt(np.prod(np.asarray(widths, float))))


def grid_scale(widths, reference_mm: float) -> float:
    """The factor by which to coarsen the model's grid so that speckle of ``widths`` (axial,
    lateral, mm) has on it the cell size ``reference_mm`` of the training worlds: the ratio of
    the cell sizes, at least 1 (speckle finer than the grid is averaged to the grid's size by
    the resampling, as it was in training) and at most :data:`MAX_GRID_SCALE`."""
    s = cell_size(widths) / float(reference_mm)
    if not np.isfinite(s):
        return 1.0
    return float(min(max(s, 1.0), MAX_GRID_SCALE))
