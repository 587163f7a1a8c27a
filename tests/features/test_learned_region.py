"""Learned maps of a region (a tracker's ROI): the linear maps between the frame's and the
model's grids, the boxes that cover a region, and agreement with the whole-frame maps."""

import numpy as np
import pytest

import synth
from needlenet.features import Frame, LearnedFeatures, ModelError
from needlenet.features._learned import GridMaps, plan_boxes, shipped_model_path
from needlenet.features._resample import _resize, apply_weights, resize_weights


@pytest.mark.parametrize("shape,new", [
    ((128, 128, 128), (100, 71, 65)),  # a Zhao volume to the model's 0.5 mm: area
    ((50, 36, 34), (100, 72, 68)),  # the network's stride-2 output up: linear
    ((64, 64, 64), (100, 71, 65)),  # a coarse volume up
    ((37, 29, 41), (30, 35, 29)),  # shrinking along some axes, growing along others
    ((101, 77), (26, 42)), ((33, 250), (51, 45)), ((40, 40), (40, 40)),
])
def test_weights_reproduce_the_resampling(shape, new):
    """OpenCV's resampling is separable: one weight matrix per axis gives the same array."""
    a = np.random.default_rng(0).random(shape).astype(np.float32) * 255
    np.testing.assert_allclose(apply_weights(a, resize_weights(shape, new)),
                               _resize(a, new, 1), atol=1e-4)
    two = np.stack([a, 255 - a])  # a leading channel axis is carried along
    np.testing.assert_allclose(apply_weights(two, resize_weights(shape, new))[1],
                               _resize(255 - a, new, 1), atol=1e-4)


def test_boxes_cover_a_tube_with_their_context():
    """A diagonal tube is split along its axis: every cell lies in a part, and every cell
    with what it reads (``reach``) lies in a box ``margin`` samples inside its faces (or at
    the grid's face), box corners on the alignment; cheaper than the whole grid."""
    t = np.arange(0, 40)
    cells = np.stack([t, t // 2 + 3, 39 - t], axis=1)  # a diagonal line of output samples
    grid, margin, reach = np.array([44, 30, 44]), 3, 1
    parts, boxes = plan_boxes(cells, grid, (margin,) * 3, 2, (reach,) * 3)
    assert boxes is not None and 1 < len(boxes) <= 8 and 1 < len(parts) <= 16
    in_part = [np.all((cells >= lo) & (cells <= hi), axis=1) for lo, hi in parts]
    assert np.all(np.any(in_part, axis=0))
    in_core = []
    for start, stop in boxes:
        assert np.all(start % 2 == 0) and np.all((stop % 2 == 0) | (stop == grid))
        lo = np.where(start > 0, start + margin, 0)
        hi = np.where(stop < grid, stop - margin, grid)
        in_core.append(np.all((cells >= lo) & (cells + reach < hi), axis=1))
    assert np.all(np.any(in_core, axis=0))
    assert sum(int(np.prod(b - a)) for a, b in boxes) < np.prod(grid)
    # a region filling the grid is run whole
    everything = np.argwhere(np.ones((10, 10, 10), bool))
    assert plan_boxes(everything, (10, 10, 10), (2, 2, 2), 2, (1, 1, 1))[1] is None


class _PoolingNet:
    """A stand-in network of receptive field 2: its two maps are functions of the 2x2x2 mean
    of the input at stride 2, so boxes aligned with the whole grid give its output exactly."""

    def run(self, names, feeds):
        x = feeds["image"][0, 0]
        d, h, w = (n // 2 for n in x.shape)
        m = x[:2 * d, :2 * h, :2 * w].reshape(d, 2, h, 2, w, 2).mean(axis=(1, 3, 5))
        return [np.stack([1 / (1 + np.exp(-m)), 1 / (1 + np.exp(m))])[None]]


@pytest.fixture(scope="module")
def model_path():
    try:
        return shipped_model_path("volume")
    except ModelError:
        pytest.skip("no shipped volume model in this checkout")


@pytest.fixture(scope="module")
def frame():
    """A seeded Zhao volume (64^3: voxels coarser than the model's along two axes) and the
    voxels within 3.5 mm of its needle's axis."""
    seq = synth.generate("volume", seed=7, frames=2, cr=3.0, output_size=64)
    fr = Frame(seq.images[1], seq.grid())
    x, y, z = fr.grid.point_grids()
    pts = np.stack(np.broadcast_arrays(x, y, z), axis=-1).reshape(-1, 3)
    tip = np.asarray(seq.tip_mm[1], float)
    u = np.asarray(seq.direction[1], float)
    w = pts - tip
    dist = np.linalg.norm(w - (w @ u)[:, None] * u, axis=1)
    return fr, np.flatnonzero(dist <= 3.5)


def test_region_maps_are_the_whole_maps_where_the_context_is_the_receptive_field(
        model_path, frame):
    """With a network whose receptive field the boxes hold (here a 2-voxel pooling) the maps
    of a region are the whole frame's to float rounding: the boxes are resampled by the
    whole frame's weights, lined up with its grid and mapped back as the whole."""
    fr, region = frame
    f = LearnedFeatures(model_path, margin_mm=0.0)
    f.sessions.exported = _PoolingNet()
    whole = f.likelihood(fr)
    part = f.likelihood(fr, roi=region)
    g = f._grid_maps(fr.image.shape, fr.grid.spacing_mm)
    assert isinstance(g, GridMaps) and g.out == tuple(n // 2 for n in g.padded)
    for a, b in ((part.shaft, whole.shaft), (part.tip, whole.tip)):
        np.testing.assert_allclose(a.reshape(-1)[region], b.reshape(-1)[region], atol=1e-5)
    assert np.count_nonzero(part.shaft) < 0.5 * part.shaft.size  # computed around it only
    assert np.count_nonzero(f.likelihood(fr, roi=region[:0]).shaft) == 0


def test_region_maps_agree_with_the_whole_maps_within_the_context_left_out(model_path, frame):
    """The shipped network's receptive field is 75 voxels at 0.5 mm (a 3^3 stem and three
    blocks at stride 2, then dilations 1, 2, 4 at stride 4): 18.5 mm of context either side,
    more than a box's margin. What a box leaves out changes the maps near its faces: inside
    the region the difference shrinks as the margin grows, and with the default 6 mm it is
    a few hundredths where it is largest and less on the needle (measured on seeds 7-9:
    mean 0.0003-0.003, 99th percentile 0.003-0.035, on the needle at most 0.018)."""
    fr, region = frame
    whole = LearnedFeatures(model_path).likelihood(fr).shaft.reshape(-1)[region]
    diff = {}
    for margin in (3.0, 6.0, 40.0):
        f = LearnedFeatures(model_path, margin_mm=margin)
        part = f.likelihood(fr, roi=region).shaft.reshape(-1)[region]
        diff[margin] = np.abs(part - whole)
    assert diff[40.0].max() < 1e-5  # the whole grid: the same maps
    d = diff[6.0]
    assert d.mean() < 0.005 and np.percentile(d, 99) < 0.05 and d.max() < 0.25
    needle = whole > 0.5
    assert needle.sum() > 10 and d[needle].max() < 0.05
    assert d.mean() < diff[3.0].mean()
