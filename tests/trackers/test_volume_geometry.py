"""Tests of the volume trackers' pieces: the grid's geometry (ROI cylinder, sector boundary),
the needle's run along an axis, the contrast to its tissue and a learned tip channel's peak."""

import math

import numpy as np
import pytest

from needlenet.features import Frame, Likelihood
from needlenet.trackers.volume import VolumeTracker, VolumeTrackerParams
from needlenet.trackers.volume._geometry import (
    Volume,
    cylinder,
    first_run_out,
    run_out_distance,
)
from needlenet.trackers.volume._measure import needle_run
from needlenet.trackers.volume._placement import needle_contrast, tip_on_map
from synth import Grid


def test_needle_contrast_is_the_needle_over_the_tissue_ring():
    # a needle three times its tissue reads 3, the tissue alone reads 1, whatever the level
    from needlenet.backends._ransac import LineModel

    grid = Grid((40, 40, 40), (0.5, 0.5, 0.5), (0.0, 0.0, 0.0))
    x, y, z = grid.point_grids()
    pts = np.stack(np.broadcast_arrays(x, y, z), axis=-1)
    d = np.linalg.norm(pts[..., 1:] - np.array([10.0, 10.0]), axis=-1)  # line along x
    p = VolumeTrackerParams()
    axis = LineModel(np.array([5.0, 10.0, 10.0]), np.array([1.0, 0.0, 0.0]))
    for tissue in (30.0, 60.0):
        image = np.where(d <= 1.1, 3 * tissue, tissue).astype(np.uint8)
        vol = Volume(Frame(image, grid), Likelihood(image.astype(np.float32)), learned=False)
        assert needle_contrast(vol, axis, 0.0, 8.0, p.placement) == pytest.approx(3.0, rel=0.05)
        flat = np.full(grid.shape, tissue, np.uint8)
        vol = Volume(Frame(flat, grid), Likelihood(flat.astype(np.float32)), learned=False)
        assert needle_contrast(vol, axis, 0.0, 8.0, p.placement) == pytest.approx(1.0, rel=1e-3)


def test_run_out_distance_steps_over_dark_speckle_to_the_sector_boundary():
    # a sector ending at a plane, with a tenth of the voxels inside it 0 (dark speckle, as in
    # the servo's Cartesian volumes): the ray leaves the sector at the plane, not at the first
    # zero voxel
    grid = Grid((30, 30, 60), (0.5, 0.5, 0.5), (0.0, 0.0, 0.0))
    rng = np.random.default_rng(7)
    image = rng.integers(1, 200, grid.shape).astype(np.uint8)
    image[rng.random(grid.shape) < 0.1] = 0
    x = grid.axis_coords(2)
    image[:, :, x > 20.0] = 0  # outside the sector beyond x = 20 mm
    vol = Volume(Frame(image, grid), Likelihood(image.astype(np.float32)), learned=False)
    start, u = np.array([5.0, 7.0, 7.0]), np.array([1.0, 0.0, 0.0])
    # the ray crosses speckle zeros before the plane: a first-zero test would stop there
    s = np.arange(1, 60) * 0.25
    assert (vol.sample(image, start + s[:, None] * u, order=0) == 0).any()
    d = run_out_distance(vol, start, u, 30.0)
    assert abs(d - 15.0) <= 0.5  # the boundary lies between the voxel centres 20.0 and 20.5
    assert run_out_distance(vol, start, u, 4.0) == 4.0  # capped at max_mm
    assert run_out_distance(vol, start, -u, 30.0) <= 5.5  # the array's face counts as out
    # Chatelain's insertion test: the fan of rays from a point 4 mm from the plane measures
    # 4 mm (the +x ray; every other ray meets the plane or a face farther away)
    trk = VolumeTracker("chatelain")
    gap = trk._boundary_distance(vol, np.array([16.0, 7.0, 7.0]))
    assert abs(gap - 4.0) <= 0.5


def test_first_run_out_matches_a_loop():
    rng = np.random.default_rng(3)
    inside = rng.random((50, 40)) < 0.7
    inside[5] = True  # never leaves
    inside[6, 30:] = False  # leaves for good at 30
    for n in (1, 2, 3, 5):
        got = first_run_out(inside, n)
        for row, g in zip(inside, got, strict=True):
            padded = np.r_[row, np.zeros(n, bool)]  # past the end counts as outside
            want = next((i for i in range(len(row)) if not padded[i:i + n].any()), len(row))
            assert g == want
        assert got[5] == 40 and got[6] <= 30


def test_cylinder_roi_matches_brute_force():
    grid = Grid((20, 24, 28), (0.9, 0.5, 0.3), (1.0, -6.0, -4.0))
    rng = np.random.default_rng(1)
    image = rng.integers(0, 3, grid.shape).astype(np.uint8)  # zeros: outside the sector
    frame = Frame(image, grid)
    vol = Volume(frame, Likelihood(image.astype(np.float32)), learned=False)
    z, y, x = np.meshgrid(*[grid.axis_coords(a) for a in range(3)], indexing="ij")
    pts = np.stack([x, y, z], -1).reshape(-1, 3)
    for point, direction, radius, t_range in [
        ([0.0, 0.0, 10.0], [1.0, 0.3, 0.2], 2.0, (-math.inf, math.inf)),
        ([1.0, -2.0, 8.0], [0.1, 0.2, 1.0], 1.3, (-3.0, 5.0)),
        ([2.0, 1.0, 9.0], [0.0, 1.0, 0.0], 2.5, (0.0, 4.0)),
    ]:
        u = np.asarray(direction, float) / np.linalg.norm(direction)
        w = pts - point
        t = w @ u
        d = np.linalg.norm(w - t[:, None] * u, axis=1)
        expected = np.flatnonzero((d <= radius) & (t >= t_range[0]) & (t <= t_range[1])
                                  & (image.reshape(-1) > 0))
        got = cylinder(vol, point, direction, radius, t_range)
        np.testing.assert_array_equal(np.sort(got), expected)


def test_needle_run_bridges_small_gaps_and_picks_the_inlier_run():
    a = np.arange(40) * 0.5
    profile = np.zeros(40)
    profile[2:6] = 1.0  # a bright structure crossing the axis at 1-2.5 mm
    profile[10:20] = 1.0  # the needle, 5-9.5 mm ...
    profile[21:30] = 1.0  # ... with a 0.5 mm gap, to 14.5 mm
    assert needle_run(profile, a, 0.5, 1.0, a0=6.0, a1=14.0) == 10
    assert needle_run(profile, a, 0.5, 1.0, a0=0.0, a1=2.0) == 2
    assert needle_run(np.zeros(40), a, 0.5, 1.0, 0.0, 1.0) is None


def test_tip_window_moves_the_tip_to_the_tip_maps_peak_along_the_axis():
    from needlenet.backends._ransac import LineModel

    grid = Grid((40, 40, 60), (0.5, 0.5, 0.5), (0.0, 0.0, 0.0))
    pts = np.stack(np.meshgrid(*[grid.axis_coords(a) for a in range(3)], indexing="ij"), -1)
    xyz = pts[..., ::-1]  # point order (x, y, z)
    origin, u = np.array([2.0, 10.0, 10.0]), np.array([1.0, 0.0, 0.0])
    true_tip = origin + 17.3 * u
    tip_map = np.exp(-0.5 * (np.linalg.norm(xyz - true_tip, axis=-1) / 1.0) ** 2)
    image = np.full(grid.shape, 50, np.uint8)
    lk = Likelihood(shaft=np.zeros(grid.shape, np.float32), tip=tip_map.astype(np.float32))
    vol = Volume(Frame(image, grid), lk, learned=True)
    line = LineModel(origin, u)
    p = VolumeTrackerParams(tip_window_mm=3.0)
    # the shaft's drop put the tip 1.5 mm short: the tip map's peak moves it back
    assert tip_on_map(vol, line, 0.0, 15.8, p) == pytest.approx(17.3, abs=0.1)
    # no clear peak (below tip_min): the drop stands
    weak = Volume(Frame(image, grid), Likelihood(shaft=lk.shaft, tip=0.2 * lk.tip), True)
    assert tip_on_map(weak, line, 0.0, 15.8, p) == 15.8
    # classical features carry no tip map
    assert Volume(Frame(image, grid), lk, learned=False).tip is None
