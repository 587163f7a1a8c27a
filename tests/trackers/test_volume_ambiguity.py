"""What one volume leaves unknown about its needle's tip (needlenet/trackers/volume/_ambiguity.py):
the spread of the places offered for the tip along the axis, and a map band wider than a
needle's image across it, checked on drawn maps against the variances they must give."""

import numpy as np
import pytest

from needlenet.backends._ransac import LineModel
from needlenet.features import Frame, Likelihood
from needlenet.trackers.volume._ambiguity import measurement_ambiguity
from needlenet.trackers.volume._geometry import Volume
from synth import Grid


def _tube_volume(half_y: float, half_z: float, step: float = 0.25) -> Volume:
    """A map of 1 inside the elliptic tube |y - 10| / half_y, |z - 10| / half_z <= 1 along x
    (point order x, y, z; a band wider in y than in z), 0 elsewhere."""
    grid = Grid((80, 80, 80), (step, step, step), (0.0, 0.0, 0.0))
    x, y, z = grid.point_grids()
    inside = ((y - 10.0) / half_y) ** 2 + ((z - 10.0) / half_z) ** 2 <= 1.0
    m = np.broadcast_to(inside, grid.shape).astype(np.float32)
    return Volume(Frame(m, grid), Likelihood(m), learned=True)


AXIS = LineModel(np.array([2.0, 10.0, 10.0]), np.array([1.0, 0.0, 0.0]))


def test_places_apart_along_the_axis_give_their_even_spread_there():
    vol = _tube_volume(0.3, 0.3)  # a band narrower than a needle's image
    C = measurement_ambiguity(vol, AXIS, 2.0, 12.0, 0.5, [10.0, 11.0, 13.0], 0.75)
    assert C[0, 0] == pytest.approx(3.0 ** 2 / 12.0)  # evenly over 3 mm along x
    assert np.allclose(C[1:, 1:], 0.0) and np.allclose(C[0, 1:], 0.0)


def test_a_band_wider_than_a_needle_adds_its_variance_beyond_the_needles_across():
    r = 0.75
    vol = _tube_volume(1.8, 0.5)  # 1.8 mm half-width in y, 0.5 in z
    C = measurement_ambiguity(vol, AXIS, 2.0, 12.0, 0.5, [12.0], r)
    assert C[0, 0] == pytest.approx(0.0, abs=1e-12)  # one place: nothing along
    # a filled ellipse of half-axes a, b: variances a^2 / 4 and b^2 / 4, less a needle's
    # r^2 / 4; the drawn map, read linearly, stays at 0.5 half a voxel (0.125 mm) further out
    a = 1.8 + 0.125
    assert C[1, 1] == pytest.approx(a ** 2 / 4 - r ** 2 / 4, rel=0.05)
    assert C[2, 2] == pytest.approx(0.0, abs=1e-9)  # 0.5 mm: within a needle's image
    assert C[1, 2] == pytest.approx(0.0, abs=1e-3)


def test_nothing_at_the_level_adds_nothing():
    vol = _tube_volume(1.8, 1.8)
    assert np.allclose(measurement_ambiguity(vol, AXIS, 2.0, 12.0, 1.5, [12.0], 0.75), 0.0)
