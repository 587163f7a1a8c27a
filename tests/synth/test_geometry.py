import numpy as np
import pytest

import synth


def test_grid_point_index_round_trip_and_order():
    g = synth.Grid((10, 20), (0.5, 0.25), (3.0, -2.5))
    # element [i, j] is at origin + index * spacing in array order; points are (x, z)
    assert np.allclose(g.index_to_points([2, 4]), [-2.5 + 4 * 0.25, 3.0 + 2 * 0.5])
    rng = np.random.default_rng(0)
    pts = rng.uniform(-2, 2, (50, 2))
    assert np.allclose(g.index_to_points(g.points_to_index(pts)), pts)
    g3 = synth.Grid((4, 5, 6), (1.0, 2.0, 3.0), (0.0, 0.0, 0.0))
    assert np.allclose(g3.points_to_index([3.0, 2.0, 1.0]), [1.0, 1.0, 1.0])


def test_grid_rejects_bad_spacing():
    with pytest.raises(ValueError, match="spacing_mm"):
        synth.Grid((4, 4), (0.0, 1.0), (0.0, 0.0))
    with pytest.raises(ValueError, match="2 or 3 axes"):
        synth.Grid((4,), (1.0,), (0.0,))


def test_rigid_transforms():
    R = synth.rotation_matrix([0, 0, 1], np.pi / 2)
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0])
    T = synth.rigid_transform(R, [1, 2, 3])
    p = np.array([[0.5, -1.0, 2.0]])
    assert np.allclose(synth.apply_transform(synth.invert_rigid(T),
                                             synth.apply_transform(T, p)), p)


def test_sector_probe_geometry():
    probe = synth.SectorProbe(output_shape=(32, 32, 32))
    assert probe.beam_grid.shape == (160, 55, 64)  # Zhao 2013: samples, planes, beams
    th = np.deg2rad(34.5 / 2)
    # a point on the edge beam of the central plane maps to beam index 63
    p = np.array([[30 * np.sin(th), 0.0, 30 * np.cos(th)]])
    assert probe.to_beam_index(p)[0, 2] == pytest.approx(63.0)
    assert probe.to_beam_index(p)[0, 1] == pytest.approx(27.0)
    vol = np.ones(probe.beam_grid.shape, np.float32)
    out = probe.scan_convert(vol)
    assert out.shape == (32, 32, 32)
    inside = out > 0
    assert inside.mean() > 0.3
    assert np.allclose(out[inside], 1.0, atol=1e-5)  # trilinear interpolation of ones is one


def test_distance_to_polyline_by_hand():
    poly = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 10.0, 0.0]])
    pts = np.array([[5.0, 3.0, 0.0], [12.0, 5.0, 0.0], [-3.0, 4.0, 0.0], [10.0, 0.0, 2.0]])
    assert np.allclose(synth.distance_to_polyline(pts, poly), [3.0, 2.0, 5.0, 2.0])
