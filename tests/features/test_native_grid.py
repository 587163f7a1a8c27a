"""Maps on the model's own grid (FeatureSource.native_likelihood): where that grid lies, and
that the maps are the frame-grid maps before their last resampling."""

import numpy as np
import pytest

import synth
from needlenet.features import Frame, IntensityFeatures, learned_features
from needlenet.features._resample import model_grid, to_frame_grid, to_model_grid


@pytest.mark.parametrize("shape, spacing, model_spacing", [
    ((500, 384), (0.1, 0.1), (0.2, 0.2)),
    ((301, 351), (0.15, 0.15), (0.2, 0.2)),
    ((120, 90), (0.3, 0.25), (0.2, 0.2)),
])
def test_model_grid_places_each_sample_where_the_resampling_reads_it(shape, spacing,
                                                                       model_spacing):
    """A linear ramp in x and z survives OpenCV's area and linear resampling away from the
    borders (to a few hundredths of a millimetre where the scale is not a whole number: the
    area weights are rounded), so each resampled value names the position it was read at;
    the model grid must put the sample there, with no offset on average."""
    g = synth.Grid(shape, spacing, (3.0, -7.5))
    x, z = g.index_to_points(np.stack(np.indices(shape), -1).reshape(-1, 2)).T
    ramp_x = x.reshape(shape).astype(np.float32)
    ramp_z = z.reshape(shape).astype(np.float32)
    rx = to_model_grid(ramp_x, spacing, model_spacing)
    rz = to_model_grid(ramp_z, spacing, model_spacing)
    mg = model_grid(g, rx.shape)
    idx = np.stack(np.indices(rx.shape), -1).reshape(-1, 2)
    pts = mg.index_to_points(idx)  # (x, z) of each model sample
    inner = (slice(2, -2), slice(2, -2))
    for got, axis in ((rx, 0), (rz, 1)):
        diff = got[inner] - pts[:, axis].reshape(got.shape)[inner]
        assert abs(float(diff.mean())) < 1e-3 and float(np.abs(diff).max()) < 0.02


def test_learned_native_maps_resampled_are_the_frame_maps():
    seq = synth.generate("inplane", seed=3, frames=1)
    g = seq.grid()
    frame = Frame(image=seq.images[0], grid=g)
    src = learned_features("inplane")
    native, grid = src.native_likelihood(frame)
    assert grid.spacing_mm == pytest.approx(src.spacing_mm, rel=0.01)
    whole = src.likelihood(frame)
    back = np.clip(to_frame_grid(np.stack([native.shaft, native.tip]), g.shape), 0, 1)
    np.testing.assert_allclose(back[0], whole.shaft, atol=1e-6)
    np.testing.assert_allclose(back[1], whole.tip, atol=1e-6)


def test_a_classical_source_gives_the_frame_grid():
    im = np.random.default_rng(0).integers(0, 255, (40, 30)).astype(np.uint8)
    g = synth.Grid(im.shape, (0.2, 0.2), (0.0, 0.0))
    lik, grid = IntensityFeatures().native_likelihood(Frame(image=im, grid=g))
    assert grid == g and lik.shaft.shape == im.shape
