"""Tests for needlenet.features._variance: Carriere 2016's variance image, eq. (1)."""

import cv2
import numpy as np
import pytest

import synth
from needlenet.features._base import FeatureSource, Frame
from needlenet.features._variance import VarianceFeatures


def _frame(image, spacing=0.3):
    image = np.asarray(image)
    grid = synth.Grid(image.shape, (spacing, spacing), (0.0, 0.0))
    return Frame(image=image, grid=grid)


def test_hand_computed_values():
    # mean 3: (I - 3)^2 = 9, 1, 1, 9, divided by the largest, 9 (eq. 1 normalised)
    lik = VarianceFeatures().likelihood(_frame(np.array([[0, 2], [4, 6]], np.uint8)))
    np.testing.assert_allclose(lik.shaft, [[1.0, 1 / 9], [1 / 9, 1.0]], rtol=1e-6)
    assert lik.shaft.dtype == np.float32
    assert lik.tip is None
    assert lik.source == "variance"


def test_normalised_to_unit_interval():
    rng = np.random.default_rng(4)
    image = rng.integers(0, 256, (40, 50), dtype=np.uint8)
    shaft = VarianceFeatures().likelihood(_frame(image)).shaft
    assert shaft.shape == image.shape
    assert shaft.min() >= 0.0
    assert shaft.max() == pytest.approx(1.0)


@pytest.mark.parametrize("value", [0, 7, 255])
def test_constant_image_gives_zeros(value):
    for dtype in (np.uint8, np.float32):
        shaft = VarianceFeatures().likelihood(_frame(np.full((16, 12), value, dtype))).shaft
        np.testing.assert_array_equal(shaft, 0.0)


def test_polarity_and_offset_invariance():
    # eq. (1) squares the deviation from the mean: a negated or shifted image gives the same map
    rng = np.random.default_rng(5)
    image = rng.normal(size=(30, 30))
    vf = VarianceFeatures()
    a = vf.likelihood(_frame(image)).shaft
    np.testing.assert_allclose(vf.likelihood(_frame(-image)).shaft, a, atol=1e-6)
    np.testing.assert_allclose(vf.likelihood(_frame(image + 50.0)).shaft, a, atol=1e-5)


def test_roi_does_not_change_the_map():
    # the mean of eq. (1) is the whole frame's, so a region of interest cannot cut it
    rng = np.random.default_rng(6)
    frame = _frame(rng.integers(0, 256, (32, 32), dtype=np.uint8))
    vf = VarianceFeatures()
    np.testing.assert_array_equal(vf.likelihood(frame, roi=(slice(4, 12), slice(4, 12))).shaft,
                                  vf.likelihood(frame).shaft)


def test_needle_cross_section_is_the_smoothed_maximum():
    seq = synth.generate("axial", seed=8, frames=2, background="homogeneous", width_mm=19.2,
                         depth_mm=19.2, needle_depth_mm=10.0)
    grid = seq.grid()
    vf = VarianceFeatures()
    assert isinstance(vf, FeatureSource) and vf.kind == "classical"
    for k in range(seq.n_frames):
        shaft = vf.likelihood(Frame(image=seq.images[k], grid=grid)).shaft
        smooth = cv2.GaussianBlur(shaft, (0, 0), 0.635 / 0.3)
        peak = np.unravel_index(int(np.argmax(smooth)), smooth.shape)
        label = grid.points_to_index(seq.tip_mm[k])
        assert np.linalg.norm((np.asarray(peak) - label) * 0.3) < 1.0  # mm
