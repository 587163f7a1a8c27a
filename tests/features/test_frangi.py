"""Tests of Zhao 2013's line filter (Appendix A) as a feature source."""

import numpy as np
import pytest
from scipy import ndimage
from skimage.feature import hessian_matrix

from needlenet.features._base import Frame
from needlenet.features._frangi import (
    FrangiFeatures,
    FrangiParams,
    _block_factor,
    frangi_tubularness,
)
from synth import Grid

N = 48
UNIT = Grid((N, N, N), (1.0, 1.0, 1.0), (0.0, 0.0, 0.0))


@pytest.fixture(scope="module")
def shapes():
    """A bright tube, a blob and a plate of the same contrast on a dark background."""
    z, y, x = np.mgrid[:N, :N, :N].astype(float)
    tube = ((z - 12) ** 2 + (y - 12) ** 2 <= 4) & (x >= 4) & (x <= N - 5)  # radius 2
    blob = (z - 34) ** 2 + (y - 12) ** 2 + (x - 24) ** 2 <= 9  # radius 3
    plate = (np.abs(z - 24) <= 1.5) & (y >= 26) & (y <= 44) & (x >= 4) & (x <= 43)
    return tube, blob, plate


def _explicit_frangi(volume, sigma, alpha=0.5, beta=0.5):
    """Zhao's eqs. (A6)-(A10) written out from the Hessian eigenvalues."""
    h = hessian_matrix(volume, sigma, use_gaussian_derivatives=True, mode="reflect")
    hzz, hzy, hzx, hyy, hyx, hxx = h
    H = np.stack([np.stack([hzz, hzy, hzx], -1), np.stack([hzy, hyy, hyx], -1),
                  np.stack([hzx, hyx, hxx], -1)], -2)
    lam = np.linalg.eigvalsh(H)
    lam = np.take_along_axis(lam, np.argsort(np.abs(lam), axis=-1), axis=-1)
    l1, l2, l3 = lam[..., 0], lam[..., 1], lam[..., 2]
    bright = (l2 < 0) & (l3 < 0)  # eq. (A6): a bright tube on a dark background
    with np.errstate(divide="ignore", invalid="ignore"):
        ra = np.abs(l2) / np.abs(l3)  # eq. (A8)
        rb = np.abs(l1) / np.sqrt(np.abs(l2 * l3))  # eq. (A7)
    s = np.sqrt((lam**2).sum(-1))  # eq. (A9)
    c = s.max() / 2  # Frangi's c: half the largest Hessian norm
    t = ((1 - np.exp(-(ra**2) / (2 * alpha**2))) * np.exp(-(rb**2) / (2 * beta**2))
         * (1 - np.exp(-(s**2) / (2 * c**2))))  # eq. (A10)
    return np.where(bright, np.nan_to_num(t), 0.0), bright, np.abs(l1) / np.abs(l2)


def test_tube_responds_more_than_blob_and_plate(shapes):
    tube, blob, plate = shapes
    volume = np.where(tube | blob | plate, 100.0, 10.0)
    t = frangi_tubularness(volume, UNIT, FrangiParams(radius_mm=2.0, max_voxels=N**3)).values

    def peak(mask):
        return float(t[ndimage.binary_dilation(mask, iterations=2)].max())

    assert peak(tube) == pytest.approx(1.0)  # normalised: the tube holds the maximum
    assert peak(tube) > 1.5 * peak(blob)
    assert peak(tube) > 2.5 * peak(plate)
    assert t.dtype == np.float32 and t.min() >= 0.0


def test_zero_in_zero_out():
    for volume in (np.zeros((16, 16, 16)), np.full((16, 16, 16), 7.0)):
        tub = frangi_tubularness(volume, Grid((16,) * 3, (1.0,) * 3, (0.0,) * 3))
        assert tub.values.shape == (16, 16, 16)
        assert tub.values.dtype == np.float32
        assert not tub.values.any()


def test_skimage_frangi_is_zhaos_equations():
    rng = np.random.default_rng(20130283)
    volume = ndimage.gaussian_filter(rng.normal(size=(20, 22, 24)), 1.0)
    grid = Grid(volume.shape, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0))
    ours = frangi_tubularness(volume, grid, FrangiParams(radius_mm=1.5, max_voxels=10**6))
    expected, bright, l1_over_l2 = _explicit_frangi(volume, 1.5)
    # skimage zeroes the wrong polarity through the underflow of exp(-R_B^2 / 2 beta^2); where
    # l1 is itself ~0 (l1 / l2 < 1e-2) the underflow fails and a small response remains.
    clear = bright | (l1_over_l2 > 1e-2)
    assert clear.mean() > 0.98
    np.testing.assert_allclose(ours.values[clear], (expected / expected.max())[clear], atol=2e-4)


def test_scale_is_the_radius_in_voxels_per_axis():
    grid = Grid((40, 40, 40), (2.0, 1.0, 0.5), (0.0, 0.0, 0.0))
    tub = frangi_tubularness(np.zeros(grid.shape), grid, FrangiParams(radius_mm=3.0,
                                                                      max_voxels=10**6))
    assert tub.sigma_voxels == pytest.approx((1.5, 3.0, 6.0))
    # below one voxel the scale is held just above one voxel
    tub = frangi_tubularness(np.zeros(grid.shape), grid, FrangiParams(radius_mm=0.5,
                                                                      max_voxels=10**6))
    assert tub.sigma_voxels == pytest.approx((1.01, 1.01, 1.01))


def test_block_averaging_to_the_voxel_budget():
    assert _block_factor((128, 128, 128), 300_000) == 2
    assert _block_factor((64, 64, 64), 300_000) == 1
    assert _block_factor((96, 96, 96), 300_000) == 2
    grid = Grid((9, 8, 8), (0.4, 0.3, 0.2), (1.0, 2.0, 3.0))
    tub = frangi_tubularness(np.ones(grid.shape), grid, FrangiParams(max_voxels=100))
    assert tub.factor == 2
    assert tub.values.shape == (5, 4, 4)  # partial blocks are kept
    assert tub.grid.spacing_mm == pytest.approx((0.8, 0.6, 0.4))
    assert tub.grid.origin_mm == pytest.approx((1.2, 2.15, 3.1))  # centres of the blocks


def test_likelihood_on_an_roi_and_the_sector(shapes):
    tube, _, _ = shapes
    image = np.where(tube, 200, 20).astype(np.uint8)
    image[:, :, :2] = 0  # outside the sector
    frame = Frame(image=image, grid=UNIT)
    features = FrangiFeatures(FrangiParams(radius_mm=2.0, max_voxels=N**3))
    roi = (slice(4, 24), slice(2, 22), slice(0, 30))
    lik = features.likelihood(frame, roi=roi)
    assert lik.shaft.shape == image.shape and lik.source == "frangi"
    outside = np.ones(image.shape, bool)
    outside[roi] = False
    assert not lik.shaft[outside].any()
    assert not lik.shaft[:, :, :2].any()
    sub = frangi_tubularness(image[roi], Grid(image[roi].shape, (1.0,) * 3, (4.0, 2.0, 0.0)),
                             features.params).values
    sub[:, :, :2] = 0.0
    np.testing.assert_allclose(lik.shaft[roi], sub)
    assert lik.shaft[12, 12, 20] > 0.9  # on the tube


def test_params_are_checked():
    with pytest.raises(ValueError, match="radius_mm"):
        FrangiParams(radius_mm=0.0)
    with pytest.raises(ValueError, match="max_voxels"):
        FrangiParams(max_voxels=0)
    with pytest.raises(ValueError, match="does not match the grid"):
        frangi_tubularness(np.zeros((4, 4, 4)), Grid((5, 4, 4), (1.0,) * 3, (0.0,) * 3))
