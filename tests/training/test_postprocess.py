"""A scanner's post-processing of training frames: deterministic, masked, sized in mm, and
doing to speckle what each operation does (smoothing lowers its spread, sharpening raises it)."""

import numpy as np
import pytest

pytest.importorskip("cv2")

import synth  # noqa: E402
from training.data import DataConfig  # noqa: E402
from training.postprocess import draw_postprocessing, postprocess, postprocessed  # noqa: E402


@pytest.fixture(scope="module")
def speckle():
    """A homogeneous in-plane frame without a needle (0.1 mm pixels), with a black margin."""
    seq = synth.generate("inplane", seed=5, frames=1, needle_free=True,
                         background="homogeneous", width_mm=20, depth_mm=20)
    im = seq.images[0].copy()
    im[:, :20] = 0  # outside the imaged region
    return im, float(seq.spacing_mm[0])


def test_chains_are_deterministic_per_seed_and_varied():
    a = [draw_postprocessing(np.random.default_rng(3)) for _ in range(2)]
    assert a[0] == a[1]
    rng = np.random.default_rng(0)
    chains = [draw_postprocessing(rng) for _ in range(400)]
    kinds = [op for c in chains for op, _ in c]
    for op in ("bilateral", "median", "nlm", "gaussian", "sharpen", "jpeg"):
        assert op in kinds
    # shares as documented: speckle reduction 70%, sharpening 40%, JPEG 30%
    smooth = np.mean([any(op in ("bilateral", "median", "nlm", "gaussian") for op, _ in c)
                      for c in chains])
    assert abs(smooth - 0.7) < 0.07
    assert abs(np.mean([any(op == "sharpen" for op, _ in c) for c in chains]) - 0.4) < 0.07
    assert abs(np.mean([any(op == "jpeg" for op, _ in c) for c in chains]) - 0.3) < 0.07


@pytest.mark.parametrize("op, params, lower", [
    ("median", {"size_mm": 0.5}, True),
    ("bilateral", {"size_mm": 0.6, "sigma_color": 60.0}, True),
    ("gaussian", {"size_mm": 0.6}, True),
    ("nlm", {"h": 25.0}, True),
    ("sharpen", {"sigma_mm": 0.4, "amount": 1.0}, False),
])
def test_smoothing_lowers_the_speckle_spread_and_sharpening_raises_it(speckle, op, params,
                                                                      lower):
    im, sp = speckle
    out = postprocess(im, sp, [(op, params)])
    assert out.dtype == np.uint8 and out.shape == im.shape
    assert np.all(out[:, :20] == 0)  # the margin stays black
    inner = (slice(40, -40), slice(60, -40))
    before, after = float(im[inner].std()), float(out[inner].std())
    assert (after < 0.85 * before) if lower else (after > 1.15 * before)
    # the mean grey is kept (within a few levels): the operation changes texture, not gain
    assert abs(float(out[inner].mean()) - float(im[inner].mean())) < 6.0


def test_filter_sizes_are_in_millimetres(speckle):
    # the same 0.5 mm median on a frame and on its copy at twice the spacing smooths the
    # same tissue: the coarse copy, filtered, is the fine one filtered and then decimated
    im, sp = speckle
    coarse = im[::2, ::2]
    fine_then_dec = postprocess(im, sp, [("gaussian", {"size_mm": 0.8})])[::2, ::2]
    dec_then_coarse = postprocess(coarse, 2 * sp, [("gaussian", {"size_mm": 0.8})])
    inner = (slice(20, -20), slice(30, -20))
    r = np.corrcoef(fine_then_dec[inner].ravel().astype(float),
                    dec_then_coarse[inner].ravel().astype(float))[0, 1]
    assert r > 0.9


def test_jpeg_keeps_the_frame_close_and_the_sequence_form(speckle):
    im, sp = speckle
    seq = np.stack([im, im])
    out = postprocessed(seq, (sp, sp), [("jpeg", {"quality": 90})])
    assert out.shape == seq.shape and out.dtype == np.uint8
    d = np.abs(out.astype(int) - seq.astype(int))[:, :, 20:]
    assert 0 < d.mean() < 6


def test_unknown_operation_and_bad_fraction_are_refused(speckle):
    im, sp = speckle
    with pytest.raises(ValueError, match="unknown post-processing"):
        postprocess(im, sp, [("emboss", {})])
    with pytest.raises(ValueError, match="postprocess_fraction"):
        DataConfig(postprocess_fraction=1.5)
