"""The 2D pixel tube of the contrast-ratio labels against scipy's feature transform."""

import numpy as np
import pytest

from synth import Grid, contrast_ratio
from synth._render import _tube_distances_edt, tube_distances


def _polyline(rng, kind, grid):
    """Vertices 0.1 mm apart: a straight shaft, an arc, or a shaft with a kink; some start or
    end outside the grid."""
    h, w = (np.asarray(grid.shape) - 1) * np.asarray(grid.spacing_mm)
    start = rng.uniform([-5.0, -5.0], [0.6 * h, w + 5.0])
    angle = rng.uniform(0, 2 * np.pi)
    length = rng.uniform(5.0, 1.5 * max(h, w))
    s = np.arange(0.0, length, 0.1)
    if kind == "straight":
        theta = np.full(len(s), angle)
    elif kind == "arc":
        theta = angle + s / rng.uniform(20.0, 200.0)
    else:  # a kink half-way
        theta = angle + np.where(s > length / 2, rng.uniform(-0.5, 0.5), 0.0)
    step = 0.1 * np.stack([np.cos(theta), np.sin(theta)], -1)
    return start + np.cumsum(step, axis=0)


def _cr_reference(image, grid, pts, r, valid):
    roi, d = _tube_distances_edt(grid, pts, 5.0 * r, exact=False)
    v = valid.reshape(-1)[roi]
    roi, d = roi[v], d[v]
    vals = image.reshape(-1)[roi].astype(np.float64)
    inner = d <= r
    if not np.any(inner) or np.all(inner):
        return float("nan")
    return float(vals[inner].mean() / vals[~inner].mean())


@pytest.mark.parametrize("kind", ["straight", "arc", "kink"])
def test_pixel_tube_matches_feature_transform(kind):
    rng = np.random.default_rng(7)
    for spacing, shape in ((0.2, (256, 256)), (0.1, (500, 384)), (0.3, (90, 140))):
        grid = Grid(shape=shape, spacing_mm=(spacing, spacing), origin_mm=(0.0, -3.0))
        for _ in range(6):
            pts = _polyline(rng, kind, grid)
            for radius in (0.4095, 1.054, 5 * 0.4095, 5 * 1.054):
                idx, d = tube_distances(grid, pts, radius, exact=False)
                ref_idx, ref_d = _tube_distances_edt(grid, pts, radius, exact=False)
                np.testing.assert_array_equal(idx, ref_idx)
                np.testing.assert_allclose(d, ref_d, rtol=1e-12, atol=0)
                assert np.all(d <= radius)


def test_pixel_tube_contrast_ratio_matches_feature_transform():
    rng = np.random.default_rng(3)
    grid = Grid(shape=(256, 256), spacing_mm=(0.2, 0.2), origin_mm=(0.0, -25.6))
    valid = np.ones(grid.shape, bool)
    valid[:, :10] = False
    for kind in ("straight", "arc", "kink", "straight", "arc"):
        pts = _polyline(rng, kind, grid)
        image = rng.integers(0, 256, grid.shape).astype(np.uint8)
        cr = contrast_ratio(image, grid, pts, 1.054, valid)
        ref = _cr_reference(image, grid, pts, 1.054, valid)
        if np.isnan(ref):
            assert np.isnan(cr)
        else:
            assert abs(cr - ref) <= 1e-6 * abs(ref)


def test_pixel_tube_outside_grid_is_empty():
    grid = Grid(shape=(64, 64), spacing_mm=(0.2, 0.2), origin_mm=(0.0, 0.0))
    pts = np.stack([np.full(50, -10.0), np.linspace(0, 5, 50)], -1)
    idx, d = tube_distances(grid, pts, 1.0, exact=False)
    assert idx.shape == (0,) and d.shape == (0,)
    idx, d = tube_distances(grid, np.zeros((0, 2)), 1.0, exact=False)
    assert idx.shape == (0,) and d.shape == (0,)


def test_needle_far_out_of_plane_renders_without_echo():
    # every echo below the amplitude floor: no splatted point, only the shadow's crop
    import synth

    seq = synth.generate("inplane", seed=21, angle_deg=35.0, elevation_offset_mm=12.0, frames=3)
    assert seq.images.shape[0] == 3 and not seq.visible.any()
