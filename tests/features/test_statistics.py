"""The robust normalisation's frame statistics: median and MAD from histograms for grey-level
frames, the same numbers as numpy's median on the same samples."""

import numpy as np
import pytest

from needlenet.features._resample import (
    _counts_median_mad,
    clip_unit,
    image_statistics,
)


@pytest.mark.parametrize("n", [1, 2, 3, 10, 11, 1000, 65536])
@pytest.mark.parametrize("dtype,high", [(np.uint8, 256), (np.uint16, 4096)])
def test_histogram_median_and_mad_agree_with_numpy(n, dtype, high):
    v = np.random.default_rng(n).integers(0, high, n).astype(dtype)
    med, mad = _counts_median_mad(np.bincount(v))
    f = v.astype(np.float64)
    assert med == np.median(f)
    assert mad == np.median(np.abs(f - np.median(f)))


def test_maps_clipped_to_the_unit_interval_with_nan_as_no_evidence():
    a = np.array([[-0.5, 0.25, 1.5], [np.nan, np.inf, -np.inf]], np.float32)
    view = np.zeros((4, 3), np.float32)
    view[1:3] = a
    clip_unit(view[1:3])  # in place, through a view
    assert view[1:3].tolist() == [[0.0, 0.25, 1.0], [0.0, 1.0, 0.0]]


def test_a_grey_frame_and_its_float_copy_give_the_same_statistics():
    rng = np.random.default_rng(4)
    frame = rng.integers(0, 256, (200, 240)).astype(np.uint8)  # under the subsample's cap
    frame[:, :40] = 0  # a black margin: not counted
    assert image_statistics(frame) == image_statistics(frame.astype(np.float32))
    inside = frame.astype(np.float64)
    inside = inside[inside > 0]
    med, spread = image_statistics(frame)
    assert med == np.median(inside)
    assert spread == pytest.approx(1.4826 * np.median(np.abs(inside - med)))


def test_a_frames_statistics_are_read_once_and_shared_by_the_learned_maps():
    from needlenet.features import Frame, frame_image_statistics, learned_features

    rng = np.random.default_rng(5)
    image = rng.integers(1, 256, (120, 100)).astype(np.uint8)
    frame = Frame.from_image(image, 0.2)
    assert frame_image_statistics(frame) == image_statistics(image)
    # the memo is what the learned features normalise with: a planted value changes the maps
    feats = learned_features("inplane")
    plain = feats.native_likelihood(Frame.from_image(image, 0.2))[0].shaft
    assert np.array_equal(feats.native_likelihood(frame)[0].shaft, plain)
    frame.extras["image_statistics"] = (float(np.median(image)) + 40.0, 5.0)
    assert not np.array_equal(feats.native_likelihood(frame)[0].shaft, plain)
