"""Frangi's line filter as Zhao 2013 uses it to initialise the ROI (Appendix A).

Zhao 2013 turns the whole first volume into a "tubularness" volume with the multiscale vessel
filter of Frangi et al. (1998) at a single scale, the expected needle radius, and runs the
model-fitting RANSAC on it to place the first ROI. The filter is expensive, so it is used only
at initialisation.

The filter is :func:`skimage.filters.frangi`, which follows Frangi's equations as Zhao
reprints them: the Hessian of eq. (A2) from Gaussian derivatives (eqs. (A3)-(A5)), its
eigenvalues sorted by magnitude ``|l1| <= |l2| <= |l3|``, then

* ``R_B = |l1| / sqrt(|l2 l3|)`` (eq. (A7), skimage's ``r_b``),
* ``R_A = |l2| / |l3|`` (eq. (A8), skimage's ``r_a``),
* ``S = ||H||_F = sqrt(sum l_i^2)`` (eq. (A9), skimage's ``s``),
* ``T = (1 - exp(-R_A^2 / 2 alpha^2)) exp(-R_B^2 / 2 beta^2) (1 - exp(-S^2 / 2 c^2))``
  (eq. (A10)), set to zero where ``l2`` or ``l3`` has the sign of a dark ridge (eq. (A6):
  a bright tube on a dark background has ``l2, l3 < 0``);

with ``alpha = beta = 0.5`` and ``c`` half the largest Hessian norm S over the filtered
volume (skimage's ``gamma=None``; Zhao's "c = 1/2 argmax" of the eigenvalues' size). One
detail differs: skimage zeroes the wrong polarity through the underflow of
``exp(-R_B^2 / 2 beta^2)`` (it clips ``l2, l3`` to 1e-10), which fails where ``l1`` is itself
close to 0, leaving a small response at about 0.02% of the voxels of smooth noise.
``tests/features/test_frangi.py`` checks the two against each other.

Two practical choices, both stated in :class:`FrangiParams`:

* voxels are anisotropic, so the scale ``s`` is the needle radius in mm converted to voxels
  per axis (skimage's Hessian accepts one sigma per axis);
* a 128^3 volume takes seconds, so the volume is first averaged over blocks of ``f^3``
  voxels (the smallest ``f`` that brings it under ``max_voxels``); block averaging also
  averages speckle. Scales are kept above one voxel: skimage warns that narrower Gaussians
  alias, and for sigma <= 1 it switches to a 100-sigma kernel that is an order of magnitude
  slower.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from synth import Grid

from ._base import FeatureSource, Frame, Likelihood

__all__ = ["FrangiParams", "FrangiFeatures", "TubularnessMap", "frangi_tubularness"]


@dataclass(frozen=True)
class FrangiParams:
    """Parameters of Zhao 2013's line filter (Appendix A).

    Attributes
    ----------
    radius_mm : float
        Scale s of eq. (A5): the expected needle radius (Zhao's needle: 0.5 mm).
    alpha, beta : float
        Sensitivities of eq. (A10) to R_A and R_B; Zhao (after Frangi): 0.5 and 0.5.
    c : float or None
        Sensitivity to S (eq. (A10)); None: half the largest S over the filtered region, as
        Zhao and Frangi recommend.
    max_voxels : int
        Working-volume budget: the volume is block-averaged by the smallest integer factor
        that brings it to at most this many voxels (300,000: a 128^3 volume is filtered at
        64^3 in about 0.3 s on two cores).
    min_sigma_voxels : float
        Smallest Gaussian scale in working voxels (just above 1, see the module notes).
    """

    radius_mm: float = 0.5
    alpha: float = 0.5
    beta: float = 0.5
    c: float | None = None
    max_voxels: int = 300_000
    min_sigma_voxels: float = 1.01

    def __post_init__(self):
        for name in ("radius_mm", "alpha", "beta", "min_sigma_voxels"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"FrangiParams.{name} must be finite and > 0, got {value}")
        if self.c is not None and not (np.isfinite(self.c) and self.c > 0):
            raise ValueError(f"FrangiParams.c must be None or finite and > 0, got {self.c}")
        if int(self.max_voxels) != self.max_voxels or self.max_voxels < 1:
            raise ValueError(f"FrangiParams.max_voxels must be an integer >= 1, "
                             f"got {self.max_voxels!r}")


@dataclass(frozen=True, eq=False)
class TubularnessMap:
    """Tubularness on the working grid.

    ``values``: T of eq. (A10) divided by its maximum, float32 in [0, 1] (all zeros when
    nothing is tubular); ``grid``: where the working voxels lie (block centres, mm);
    ``factor``: the block size in voxels of the input; ``sigma_voxels``: the scale used per
    working axis.
    """

    values: np.ndarray
    grid: Grid
    factor: int
    sigma_voxels: tuple[float, ...]


def _block_factor(shape, max_voxels: int) -> int:
    f = 1
    while math.prod(-(-n // f) for n in shape) > max_voxels and f < max(shape):
        f += 1
    return f


def _block_mean(volume: np.ndarray, f: int) -> np.ndarray:
    """Mean over f^d blocks; the last partial block of each axis is averaged over what it has."""
    if f == 1:
        return volume.astype(np.float32, copy=False)
    pad = [(0, (-n) % f) for n in volume.shape]
    v = np.pad(volume.astype(np.float32, copy=False), pad, mode="edge")
    shape = []
    for n in v.shape:
        shape += [n // f, f]
    return v.reshape(shape).mean(axis=tuple(range(1, 2 * volume.ndim, 2)), dtype=np.float32)


def frangi_tubularness(volume, grid: Grid, params: FrangiParams | None = None) -> TubularnessMap:
    """Zhao 2013, Appendix A: bright-tube tubularness of a volume (or a region of it).

    Parameters
    ----------
    volume : array, 3D, on ``grid``
        Intensities (any real dtype). NaNs are not allowed.
    grid : synth.Grid
        Position of ``volume``'s voxels in mm (for a region: the region's own grid).
    params : FrangiParams, optional

    Returns
    -------
    TubularnessMap
        On the block-averaged working grid.
    """
    from skimage.filters import frangi  # skimage.filters is slow to import

    p = FrangiParams() if params is None else params
    vol = np.asarray(volume)
    if vol.ndim != grid.ndim or vol.shape != grid.shape:
        raise ValueError(f"volume of shape {vol.shape} does not match the grid {grid.shape}")
    if vol.dtype.kind == "f" and not np.all(np.isfinite(vol)):
        raise ValueError("volume contains NaN or infinite values")
    f = _block_factor(vol.shape, int(p.max_voxels))
    work = _block_mean(vol, f)
    spacing = np.asarray(grid.spacing_mm) * f
    origin = np.asarray(grid.origin_mm) + 0.5 * (f - 1) * np.asarray(grid.spacing_mm)
    wgrid = Grid(work.shape, tuple(spacing), tuple(origin))
    # Scale s = needle radius (eq. (A5)), per axis in working voxels.
    sigma = tuple(float(max(p.radius_mm / s, p.min_sigma_voxels)) for s in spacing)
    if not np.ptp(work) > 0:  # a constant volume has no structure: T = 0 (zero in, zero out)
        return TubularnessMap(np.zeros(work.shape, np.float32), wgrid, f, sigma)
    t = frangi(work, sigmas=[sigma], alpha=p.alpha, beta=p.beta, gamma=p.c,
               black_ridges=False, mode="reflect")  # eqs. (A7)-(A10)
    t = np.asarray(t, dtype=np.float32)
    peak = float(t.max())
    if peak > 0:
        t /= np.float32(peak)
    return TubularnessMap(t, wgrid, f, sigma)


def _upsample(values: np.ndarray, f: int, shape: tuple[int, ...]) -> np.ndarray:
    """Nearest-neighbour (block) upsampling back to ``shape``."""
    if f == 1:
        return values
    out = values
    for axis in range(values.ndim):
        out = np.repeat(out, f, axis=axis)
    return np.ascontiguousarray(out[tuple(slice(0, n) for n in shape)])


class FrangiFeatures(FeatureSource):
    """Tubularness of Zhao 2013 (Appendix A) as a :class:`FeatureSource`.

    ``likelihood(frame, roi)`` filters the whole volume, or only ``roi`` (a tuple of slices in
    array order) when given, which is much cheaper; outside the ROI the map is 0. The map is
    the filter on the block-averaged working grid, brought back to the frame's grid by block
    (nearest-neighbour) upsampling, and normalised to [0, 1]. Voxels outside the imaged
    sector (exactly 0 in scan-converted volumes) are set to 0.
    """

    name = "frangi"

    def __init__(self, params: FrangiParams | None = None):
        self.params = FrangiParams() if params is None else params

    def tubularness(self, frame: Frame, roi: tuple[slice, ...] | None = None) -> TubularnessMap:
        """The filter of ``frame.image[roi]`` on its working grid (:func:`frangi_tubularness`)."""
        image = np.asarray(frame.image)
        grid = frame.grid
        if roi is not None:
            roi = tuple(roi)
            if len(roi) != image.ndim or any(s.indices(n)[2] != 1
                                             for s, n in zip(roi, image.shape, strict=True)):
                raise ValueError(f"roi must be {image.ndim} slices with step 1, got {roi}")
            starts = [s.indices(n)[0] for s, n in zip(roi, image.shape, strict=True)]
            image = image[roi]
            if image.size == 0:
                raise ValueError(f"roi {roi} selects no voxel of a volume of shape {grid.shape}")
            origin = np.asarray(grid.origin_mm) + np.asarray(starts) * np.asarray(grid.spacing_mm)
            grid = Grid(image.shape, grid.spacing_mm, tuple(origin))
        return frangi_tubularness(image, grid, self.params)

    def likelihood(self, frame: Frame, roi: tuple[slice, ...] | None = None) -> Likelihood:
        image = np.asarray(frame.image)
        tub = self.tubularness(frame, roi)
        if roi is None:
            shaft = _upsample(tub.values, tub.factor, image.shape)
        else:
            shaft = np.zeros(image.shape, np.float32)
            region = shaft[tuple(roi)]
            region[...] = _upsample(tub.values, tub.factor, region.shape)
        shaft[image == 0] = 0.0  # outside the sector: not tissue
        return Likelihood(shaft=shaft, tip=None, source=self.name)
