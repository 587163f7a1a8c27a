"""Tests for needlenet.backends._ncc: Carriere 2016's variance image (eq. (1)) and ROI template
matching, Zhao 2013's 3-D speckle tracking (eq. (5))."""

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view
from skimage.feature import match_template

from needlenet.backends._ncc import (
    match_template_roi,
    speckle_track_3d,
    tip_velocity,
    variance_image,
)

# ---------------------------------------------------------------------------- variance image


def test_variance_image_hand_computed():
    # mean 3: squared deviations [[9, 1], [1, 9]], divided by the maximum 9
    v = variance_image(np.array([[0, 2], [4, 6]], dtype=np.uint8))
    np.testing.assert_allclose(v, [[1.0, 1 / 9], [1 / 9, 1.0]])
    assert v.dtype == np.float64


def test_variance_image_range_and_constant_image():
    rng = np.random.default_rng(0)
    v = variance_image(rng.normal(100.0, 20.0, (64, 48)))
    assert v.min() >= 0.0 and v.max() == 1.0
    with np.errstate(all="raise"):  # no division by zero
        np.testing.assert_array_equal(variance_image(np.full((5, 7), 3.0)), 0.0)
    # eq. (1) is invariant to an intensity offset and scale
    img = rng.random((10, 10))
    np.testing.assert_allclose(variance_image(3.0 * img + 7.0), variance_image(img))


# ---------------------------------------------------------------------------- 2-D NCC in an ROI


def _blob(shape, center, sigma=4.0):
    rows, cols = np.indices(shape)
    return np.exp(-((rows - center[0]) ** 2 + (cols - center[1]) ** 2) / (2 * sigma**2))


def test_roi_match_agrees_with_skimage():
    rng = np.random.default_rng(1)
    image = rng.random((80, 90))
    template = image[30:41, 50:59] + 0.2 * rng.random((11, 9))
    result = match_template_roi(image, template, center=(37, 52), roi_half_size=(15, 12))
    r0, c0 = result.roi_origin
    np.testing.assert_array_equal(result.roi_origin, [22, 40])
    window = image[r0 : 37 + 16, c0 : 52 + 13]
    expected = match_template(window, template)  # skimage, float64, same ZNCC
    assert result.score.shape == expected.shape
    np.testing.assert_allclose(result.score, expected, atol=1e-4)
    assert np.unravel_index(np.argmax(expected), expected.shape) == (30 - 22, 50 - 40)
    assert result.peak == pytest.approx(expected.max(), abs=1e-4)
    # the template's top-left corner was at (30, 50); its centre at (35, 54)
    np.testing.assert_allclose(result.center, [35.0, 54.0], atol=0.5)


def test_roi_match_subpixel_on_a_smooth_blob():
    true_center = np.array([40.3, 55.7])
    image = _blob((100, 120), true_center)
    template = _blob((21, 21), (10.0, 10.0))
    result = match_template_roi(image, template, center=(45, 50), roi_half_size=25)
    assert np.all(np.abs(result.center - true_center) < 0.1)
    assert result.peak > 0.99


def test_roi_clipped_at_the_image_border():
    true_center = np.array([6.4, 7.8])
    image = _blob((60, 60), true_center, sigma=3.0) + 0.3 * _blob((60, 60), (40, 40), 3.0)
    template = _blob((11, 11), (5.0, 5.0), sigma=3.0)
    result = match_template_roi(image, template, center=(2, 3), roi_half_size=(20, 20))
    np.testing.assert_array_equal(result.roi_origin, [0, 0])
    assert result.score.shape == (23 - 11 + 1, 24 - 11 + 1)
    assert np.all(np.abs(result.center - true_center) < 0.1)


def test_roi_match_bad_input():
    image = np.random.default_rng(2).random((30, 30))
    with pytest.raises(ValueError, match="larger than the ROI"):
        match_template_roi(image, image[:9, :9], center=(15, 15), roi_half_size=3)
    with pytest.raises(ValueError, match="larger than the ROI"):  # clipped at the corner
        match_template_roi(image, image[:9, :9], center=(0, 0), roi_half_size=5)
    with pytest.raises(ValueError, match="constant"):
        match_template_roi(image, np.ones((5, 5)), center=(15, 15), roi_half_size=8)
    with pytest.raises(ValueError, match="2-D"):
        match_template_roi(image[None], image[:5, :5], center=(15, 15), roi_half_size=8)
    with pytest.raises(ValueError, match="outside the image"):
        match_template_roi(image, image[:5, :5], center=(60, 15), roi_half_size=8)
    with pytest.raises(ValueError, match="non-negative integers"):
        match_template_roi(image, image[:5, :5], center=(15, 15), roi_half_size=-2)


# ---------------------------------------------------------------------------- 3-D speckle tracking


def _brute_force_eq5(kernel, search):
    """Zhao 2013, eq. (5) written directly: zero-mean products over every kernel position."""
    windows = sliding_window_view(search, kernel.shape)  # (A, B, C, m, n, p)
    axes = (-3, -2, -1)
    w0 = kernel - kernel.mean()
    w1 = windows - windows.mean(axis=axes, keepdims=True)
    num = np.sum(w0 * w1, axis=axes)
    den = np.sqrt(np.sum(w0**2) * np.sum(w1**2, axis=axes))
    return num / den


def test_fast_ncc_matches_brute_force_eq5():
    rng = np.random.default_rng(3)
    kernel = rng.random((3, 4, 3))
    search = rng.random((7, 6, 9))
    result = speckle_track_3d(kernel, search)
    expected = _brute_force_eq5(kernel, search)
    assert result.rho.shape == (5, 3, 7)  # (M - m + 1, N - n + 1, P - p + 1)
    np.testing.assert_allclose(result.rho, expected, atol=1e-6)
    assert result.peak == pytest.approx(expected.max(), abs=1e-6)


@pytest.mark.parametrize("shift", [(2, -1, 3), (0, 0, 0), (-4, 4, -2)])
def test_speckle_tracking_recovers_an_integer_shift_exactly(shift):
    rng = np.random.default_rng(4)
    volume = rng.random((40, 40, 40))
    moved = np.roll(volume, shift, axis=(0, 1, 2))
    c, k, s = 20, 4, 9
    kernel = volume[c - k : c + k + 1, c - k : c + k + 1, c - k : c + k + 1]
    search = moved[c - s : c + s + 1, c - s : c + s + 1, c - s : c + s + 1]
    result = speckle_track_3d(kernel, search)
    np.testing.assert_array_equal(result.displacement, shift)
    np.testing.assert_allclose(result.subvoxel_displacement, shift, atol=0.1)
    assert result.peak == pytest.approx(1.0, abs=1e-9)


def test_speckle_tracking_bad_input():
    rng = np.random.default_rng(5)
    with pytest.raises(ValueError, match="larger than the search region"):
        speckle_track_3d(rng.random((5, 5, 5)), rng.random((7, 3, 7)))
    with pytest.raises(ValueError, match="even"):
        speckle_track_3d(rng.random((3, 3, 3)), rng.random((6, 7, 7)))
    with pytest.raises(ValueError, match="3-D"):
        speckle_track_3d(rng.random((3, 3)), rng.random((7, 7)))
    with pytest.raises(ValueError, match="constant"):
        speckle_track_3d(np.ones((3, 3, 3)), rng.random((7, 7, 7)))


def test_tip_velocity_in_mm_per_second():
    rng = np.random.default_rng(6)
    volume = rng.random((32, 36, 30))
    shift = np.array([2, -1, 3])
    moved = np.roll(volume, shift, axis=(0, 1, 2))
    spacing = np.array([0.5, 0.4, 0.3])
    result = tip_velocity(
        volume,
        moved,
        (15, 18, 14),
        kernel_half=3,
        search_half=(6, 6, 7),
        spacing_mm=spacing,
        dt=0.1,
    )
    np.testing.assert_array_equal(np.rint(result.displacement_mm / spacing), shift)
    np.testing.assert_allclose(
        result.velocity_mm_s, shift * spacing / 0.1, atol=0.1 * spacing.max() / 0.1
    )
    assert result.peak == pytest.approx(1.0, abs=1e-9)


def test_tip_velocity_subvoxel_on_a_smooth_volume_near_the_border():
    grid = np.indices((24, 24, 24)).astype(float)

    def blob(c):
        return np.exp(-sum((g - ci) ** 2 for g, ci in zip(grid, c, strict=True)) / (2 * 3.0**2))

    before = blob((3.0, 12.0, 12.0))
    after = blob((4.3, 11.6, 12.2))
    result = tip_velocity(
        before, after, (3, 12, 12), kernel_half=4, search_half=7, spacing_mm=0.2, dt=0.05
    )  # both regions clipped at axis-0 start
    np.testing.assert_allclose(result.displacement_mm / 0.2, [1.3, -0.4, 0.2], atol=0.1)
    np.testing.assert_allclose(result.velocity_mm_s, result.displacement_mm / 0.05)


def test_tip_velocity_bad_input():
    rng = np.random.default_rng(7)
    vol = rng.random((20, 20, 20))
    with pytest.raises(ValueError, match="one shape"):
        tip_velocity(vol, vol[:-1], (10, 10, 10), 2, 4, 0.3, 0.1)
    with pytest.raises(ValueError, match="at least kernel_half"):
        tip_velocity(vol, vol, (10, 10, 10), 4, 2, 0.3, 0.1)
    with pytest.raises(ValueError, match="dt"):
        tip_velocity(vol, vol, (10, 10, 10), 2, 4, 0.3, 0.0)
    with pytest.raises(ValueError, match="outside the volume"):
        tip_velocity(vol, vol, (10, 25, 10), 2, 4, 0.3, 0.1)
    with pytest.raises(ValueError, match="spacing_mm"):
        tip_velocity(vol, vol, (10, 10, 10), 2, 4, -0.3, 0.1)
