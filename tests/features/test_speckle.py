"""The speckle size of a frame, and the model grid matched to the model's training speckle."""


import cv2
import numpy as np
import pytest

import synth
from needlenet.features._base import Frame
from needlenet.features._learned import LearnedFeatures, shipped_model_path
from needlenet.features._speckle import MAX_GRID_SCALE, cell_size, grid_scale, speckle_widths

GRID = (0.2, 0.2)


def _correlated_field(sigma_px, shape=(256, 256), seed=0):
    """White noise smoothed by a Gaussian of ``sigma_px`` (axial, lateral): its
    autocorrelation is a Gaussian of sigma * sqrt(2), FWHM 2 sqrt(2 ln 2) sqrt(2) sigma."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=shape).astype(np.float32)
    sz, sx = sigma_px
    x = cv2.GaussianBlur(x, (0, 0), sigmaX=sx, sigmaY=sz, borderType=cv2.BORDER_REFLECT)
    return 100.0 + 20.0 * x / x.std()


def test_widths_of_a_field_of_known_correlation():
    """The widths follow the field's Gaussian correlation, biased low by the local mean removed
    over 9 pixels and per tile (the same estimator measures the model's training speckle)."""
    sigma = np.array([1.0, 2.0])
    w = speckle_widths(_correlated_field(sigma), GRID, GRID)
    true = 2 * np.sqrt(2 * np.log(2)) * np.sqrt(2) * sigma * GRID[0]
    assert np.all((w > 0.7 * true) & (w < true))
    wider = speckle_widths(_correlated_field(1.5 * sigma), GRID, GRID)
    assert np.all(wider > 1.1 * w)


def test_widths_agree_with_scipy():
    """The FFT autocorrelation of each tile against scipy's direct correlation."""
    from scipy import ndimage, signal

    from needlenet.features._speckle import BOX, TILE

    x = _correlated_field((1.2, 2.5), shape=(128, 160))
    hp = x - ndimage.uniform_filter(x.astype(np.float64), BOX, mode="reflect")
    halves = []
    for i in range(0, 128, TILE):
        for j in range(0, 160, TILE):
            t = hp[i:i + TILE, j:j + TILE]
            t = t - t.mean()
            ac = signal.correlate2d(t, t, mode="full")[TILE - 1:, TILE - 1:]
            ac = ac / ac[0, 0]
            halves.append([np.interp(0.5, p[::-1], np.arange(8)[::-1])
                           for p in (ac[:8, 0], ac[0, :8])])
    np.testing.assert_allclose(speckle_widths(x, GRID, GRID),
                               2 * np.median(halves, axis=0) * GRID[0], rtol=0.01)


def test_widths_are_in_mm_whatever_the_frame_spacing():
    """The same field sampled at 0.1 mm, resampled to the 0.2 mm grid: widths in mm kept."""
    f = _correlated_field((2.0, 4.0), shape=(512, 512))
    fine = speckle_widths(f, (0.1, 0.1), GRID)
    coarse = speckle_widths(cv2.resize(f, (256, 256), interpolation=cv2.INTER_AREA),
                            (0.2, 0.2), GRID)
    np.testing.assert_allclose(fine, coarse, rtol=0.05)


def test_lower_frequency_gives_larger_speckle():
    """synth's homogeneous tissue: speckle scales with the wavelength (3 against 9 MHz)."""
    w = {}
    for f in (3.0, 9.0):
        seq = synth.generate("inplane", seed=2, frames=1, needle_free=True,
                             background="homogeneous",
                             imaging_overrides={"center_frequency_mhz": f})
        w[f] = speckle_widths(seq.images[0], seq.spacing_mm, GRID)
    assert np.all(w[3.0] > 1.3 * w[9.0])


def test_margins_and_a_needle_do_not_move_the_estimate():
    """Black capture margins are left out, and a needle in a few tiles does not move the
    median over tiles."""
    seq = synth.generate("inplane", seed=4, frames=1, background="homogeneous")
    im = seq.images[0]
    base = speckle_widths(seq.images[0], seq.spacing_mm, GRID)
    framed = np.pad(im, ((40, 0), (60, 60)))  # black margins above and to the sides
    np.testing.assert_allclose(speckle_widths(framed, seq.spacing_mm, GRID), base, rtol=0.05)
    free = synth.generate("inplane", seed=4, frames=1, background="homogeneous",
                          needle_free=True)
    np.testing.assert_allclose(speckle_widths(free.images[0], free.spacing_mm, GRID), base,
                               rtol=0.1)


@pytest.mark.parametrize("image", [np.zeros((300, 300)), np.full((300, 300), 90.0),
                                   np.random.default_rng(0).normal(90, 20, (20, 300))])
def test_no_speckle_no_estimate(image):
    """A blank frame, one grey value, a frame smaller than a tile: None."""
    assert speckle_widths(image, (0.1, 0.1), GRID) is None


def test_grid_scale():
    ref = cell_size((0.3, 0.45))
    assert grid_scale((0.15, 0.3), ref) == 1.0  # finer speckle: the model's grid
    assert grid_scale((0.6, 0.9), ref) == pytest.approx(2.0)  # twice as large each way
    assert grid_scale((0.6, 0.45), ref) == pytest.approx(np.sqrt(2))  # area twice
    assert grid_scale((30.0, 45.0), ref) == MAX_GRID_SCALE
    assert grid_scale((np.nan, 0.45), ref) == 1.0


def _features(speckle_cell_mm):
    f = LearnedFeatures(shipped_model_path("inplane"), "inplane")
    f.speckle_cell_mm = speckle_cell_mm
    return f


def test_the_model_grid_follows_the_recording_speckle():
    """A low-frequency recording runs on a coarser grid, by the speckle ratio; a frame with
    speckle like training's on the model's grid; the choice is kept for the recording and
    the maps come back on the frame's grid."""
    low = synth.generate("inplane", seed=5, frames=2, background="homogeneous",
                         imaging_overrides={"center_frequency_mhz": 2.0, "f_number": 3.5})
    w = speckle_widths(low.images[0], low.spacing_mm, GRID)
    f = _features(0.37)
    lik, grid = f.native_likelihood(Frame(low.images[0], low.grid(), 0.0))
    scale = grid_scale(w, 0.37)
    assert scale > 1.3
    np.testing.assert_allclose(f.spacing_mm, np.multiply(GRID, scale))
    np.testing.assert_allclose(grid.spacing_mm, f.spacing_mm, rtol=0.05)
    assert f.likelihood(Frame(low.images[1], low.grid(), 0.1)).shaft.shape == \
        low.images[1].shape
    assert f.spacing_mm == f.match_speckle(low.images[1], low.spacing_mm)
    # speckle as in training (a reference larger than this frame's): the model's grid
    assert _features(5.0).match_speckle(low.images[0], low.spacing_mm) == GRID
    # no reference in the model: its grid whatever the frame
    assert _features(None).match_speckle(low.images[0], low.spacing_mm) == GRID


def test_a_blank_first_frame_leaves_the_choice_to_the_next():
    low = synth.generate("inplane", seed=5, frames=1, background="homogeneous",
                         imaging_overrides={"center_frequency_mhz": 2.0, "f_number": 3.5})
    f = _features(0.37)
    assert f.match_speckle(np.zeros_like(low.images[0]), low.spacing_mm) == GRID
    assert f.match_speckle(low.images[0], low.spacing_mm)[0] > 1.3 * GRID[0]


def test_bad_speckle_metadata_is_refused(tmp_path):
    onnx = pytest.importorskip("onnx")
    from needlenet.features import ModelError

    m = onnx.load(shipped_model_path("inplane"))
    props = {p.key: p.value for p in m.metadata_props}
    props["speckle_cell_mm"] = "-1.0"
    del m.metadata_props[:]
    for k, v in props.items():
        p = m.metadata_props.add()
        p.key, p.value = k, v
    onnx.save(m, tmp_path / "bad.onnx")
    with pytest.raises(ModelError, match=r"bad\.onnx: metadata speckle_cell_mm -1.0 must be"):
        LearnedFeatures(tmp_path / "bad.onnx", "inplane")
