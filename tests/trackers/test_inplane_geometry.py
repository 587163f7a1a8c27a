"""distance_to_edge (needlenet/trackers/_inplane_geometry.py): against a plain reading of
every sample's nearest pixel, and against the analytic distance to a straight edge."""

import numpy as np

from needlenet.features import Frame
from needlenet.trackers._inplane_geometry import AROUND, distance_to_edge
from synth import Grid


def _reference(valid, grid, start, dirs, step, max_mm):
    """The first sample, over all directions, whose nearest pixel is outside ``valid``."""
    s = np.arange(0.0, max_mm, step)
    for sj in s:
        for d in np.reshape(dirs, (-1, 2)):
            r, c = np.rint(grid.points_to_index(start + sj * d)).astype(int)
            if not (0 <= r < valid.shape[0] and 0 <= c < valid.shape[1]) or not valid[r, c]:
                return float(sj)
    return float(max_mm)


def test_distance_to_edge_agrees_with_a_plain_reading_of_each_sample():
    rng = np.random.default_rng(11)
    for k in range(200):
        h, w = (int(v) for v in rng.integers(40, 160, 2))
        grid = Grid((h, w), (float(rng.uniform(0.05, 0.3)),) * 2,
                    (float(rng.uniform(-3, 3)), float(rng.uniform(-20, 0))))
        valid = np.ones((h, w), bool)
        valid[:int(rng.integers(0, h // 3))] = False
        valid &= rng.random((h, w)) > 0.002  # black speckle pixels inside
        frame = Frame(np.zeros((h, w), np.uint8), grid)
        start = np.array([grid.origin_mm[1] + rng.uniform(0, w) * grid.spacing_mm[1],
                          grid.origin_mm[0] + rng.uniform(0, h) * grid.spacing_mm[0]])
        if k % 2:
            dirs, max_mm = AROUND, float(rng.uniform(1, 8))
        else:
            a = rng.uniform(0, 2 * np.pi)
            dirs, max_mm = np.array([np.cos(a), np.sin(a)]), 60.0
        assert distance_to_edge(valid, frame, start, dirs, 0.2, max_mm) == \
            _reference(valid, grid, start, dirs, 0.2, max_mm)


def test_distance_to_a_straight_margin_is_the_analytic_distance():
    """A margin above row 50 of a 0.1 mm grid: from 3 mm below it, straight up is 3 mm to the
    margin, 45 degrees up 3 * sqrt(2) mm, both to within a sample and a pixel."""
    grid = Grid((200, 200), (0.1, 0.1), (0.0, 0.0))
    valid = np.ones((200, 200), bool)
    valid[:50] = False
    frame = Frame(np.zeros((200, 200), np.uint8), grid)
    start = np.array([10.0, 8.0])  # (x, z) mm: 3 mm below the margin's edge at z = 5 mm
    up = distance_to_edge(valid, frame, start, np.array([0.0, -1.0]), 0.05)
    diag = distance_to_edge(valid, frame, start, np.array([1.0, -1.0]) / np.sqrt(2), 0.05)
    assert abs(up - 3.0) <= 0.1
    assert abs(diag - 3.0 * np.sqrt(2)) <= 0.15
    assert distance_to_edge(valid, frame, start, AROUND, 0.05) == up  # the nearest way out
