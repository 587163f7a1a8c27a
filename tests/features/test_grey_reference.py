"""A model trained on fixed grey levels sees each frame mapped to its training worlds' grey
median and spread: its input, and so its maps, do not move with gain or dynamic range."""

import numpy as np
import pytest

import synth
from needlenet.features import Frame, LearnedFeatures
from needlenet.features._learned import shipped_model_path
from needlenet.features._resample import NORMALIZATIONS, image_statistics, normalize

REF = [90.5, 28.9]


def _frame(seed=3):
    rng = np.random.default_rng(seed)
    img = rng.normal(80.0, 12.0, (120, 90)).clip(1, 200).astype(np.float32)
    img[40:44, 10:80] = 200.0  # a bright line
    img[:, :8] = 0.0  # a black capture margin
    return img


def test_the_frame_is_mapped_to_the_reference_grey_levels():
    """Log compression makes a gain change a grey offset and a dynamic-range change a grey
    scale: after the affine map the median and 1.4826 MAD of the non-zero pixels are the
    reference's, whatever offset and scale the frame had; black stays black."""
    norm = {**NORMALIZATIONS["fixed"], "grey_reference": REF}
    img = _frame()
    z = normalize(img, norm)
    grey = (z * norm["std"] + norm["mean"]) / norm["scale"]  # back to grey levels
    med, spread = image_statistics(np.where(img > 0, grey, 0))
    assert med == pytest.approx(REF[0], abs=0.05) and spread == pytest.approx(REF[1], rel=1e-3)
    assert np.allclose(grey[:, :8], 0.0, atol=1e-4)
    for scale, offset in ((1.2, -35.0), (0.55, 40.0)):
        changed = np.where(img > 0, img * np.float32(scale) + np.float32(offset), 0.0)
        np.testing.assert_allclose(normalize(changed.astype(np.float32), norm), z, atol=1e-4)
    # without a reference the fixed input follows the grey levels
    assert not np.allclose(normalize(img + np.float32(20) * (img > 0), NORMALIZATIONS["fixed"]),
                           normalize(img, NORMALIZATIONS["fixed"]), atol=0.1)


def test_the_shipped_model_maps_do_not_move_with_gain():
    """The shipped in-plane model records its training worlds' grey levels: a synth frame and
    the same frame 20 grey levels brighter and at 0.8 of its contrast give the same maps."""
    f = LearnedFeatures(shipped_model_path("inplane"), "inplane")
    assert f.normalization["mode"] == "fixed" and len(f.normalization["grey_reference"]) == 2
    seq = synth.generate("inplane", seed=4, frames=1)
    # zero reads "not imaged" (a margin): the few speckle pixels at 0 are lifted to 1
    img = np.maximum(seq.images[0], 1).astype(np.float32)
    other = np.where(img > 0, img * np.float32(0.8) + np.float32(20), 0).astype(np.float32)
    a = f.likelihood(Frame(img, seq.grid(), 0.0))
    b = f.likelihood(Frame(other, seq.grid(), 0.0))
    assert a.shaft.max() > 0.5  # the needle is marked
    np.testing.assert_allclose(a.shaft, b.shaft, atol=1e-3)
    np.testing.assert_allclose(a.tip, b.tip, atol=1e-3)
