"""The beams' geometry read from a frame's imaged region (needlenet/trackers/_beams.py), and
the `line` tracker refusing a short line that runs along the beams (a reverberation tail)."""

from pathlib import Path

import numpy as np
import pytest

import synth
from needlenet.features import Frame
from needlenet.trackers._beams import BeamGeometry, beam_geometry
from synth import Grid

VALIDATION = Path(__file__).resolve().parents[2] / "needlenet" / "data" / "validation"


def _frame(valid: np.ndarray, grid: Grid) -> Frame:
    """An 8-bit frame whose imaged region is ``valid`` (speckle there, black elsewhere)."""
    rng = np.random.default_rng(5)
    im = np.where(valid, rng.integers(40, 200, valid.shape), 0).astype(np.uint8)
    return Frame(im, grid)


def _points(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    z = grid.origin_mm[0] + grid.spacing_mm[0] * np.arange(grid.shape[0])
    x = grid.origin_mm[1] + grid.spacing_mm[1] * np.arange(grid.shape[1])
    return x[None, :], z[:, None]


@pytest.mark.parametrize("apex, half_deg, bar", [((0.0, 0.0), 35.0, False),
                                                 ((4.0, -12.0), 20.0, False),
                                                 ((-3.0, -2.0), 45.0, False),
                                                 ((0.0, 0.0), 35.0, True)])
def test_a_sectors_apex_is_where_its_side_edges_meet(apex, half_deg, bar):
    """A phased or convex array's sector (apex above or at the top of the view, the top and
    bottom arcs about it; once with a grey-scale bar in the margin): the apex within a
    millimetre (the region's edge is read a fraction of a pixel inside the sector's, which
    moves the apex up the more the narrower the sector is), and the beam through points of
    the view along the line from the apex within 1 degree."""
    grid = Grid((300, 360), (0.15, 0.15), (0.0, -27.0))
    x, z = _points(grid)
    r = np.hypot(x - apex[0], z - apex[1])
    ang = np.degrees(np.arctan2(x - apex[0], z - apex[1]))
    valid = (np.abs(ang) <= half_deg) & (r >= 2.0 - apex[1]) & (r <= 40.0)
    frame = _frame(valid, grid)
    if bar:  # a scanner's grey-scale bar in the black margin beside the sector
        frame.image[20:290, 5:20] = np.linspace(0, 255, 270)[:, None].astype(np.uint8)
    g = beam_geometry(frame)
    assert g is not None and g.apex_mm is not None
    assert np.linalg.norm(g.apex_mm - np.array(apex)) < 1.0
    for p in (np.array([apex[0] + 5.0, 30.0]), np.array([apex[0] - 8.0, 25.0])):
        along = p - np.array(apex)
        assert g.angle_deg(p, along) < 1.0
        assert g.angle_deg(p, np.array([-along[1], along[0]])) > 89.0


def test_a_frame_filled_by_the_image_has_beams_along_the_depth_axis():
    grid = Grid((200, 250), (0.1, 0.1), (1.0, -12.5))
    g = beam_geometry(_frame(np.ones((200, 250), bool), grid))
    assert g is not None and g.apex_mm is None
    assert np.allclose(g.direction, [0.0, 1.0])
    assert g.angle_deg(np.zeros(2), np.array([np.sin(np.radians(10)), np.cos(np.radians(10))])) \
        == pytest.approx(10.0)


def test_parallel_slanted_side_edges_are_a_steered_linear_array():
    """A linear array steered 12 degrees: a parallelogram between black margins; the beams
    run along its sides."""
    grid = Grid((200, 300), (0.1, 0.1), (0.0, 0.0))
    x, z = _points(grid)
    t = np.tan(np.radians(12.0))
    valid = (x >= 6.0 + t * z) & (x <= 22.0 + t * z)
    g = beam_geometry(_frame(valid, grid))
    assert g is not None and g.apex_mm is None
    assert np.degrees(np.arctan2(g.direction[0], g.direction[1])) == pytest.approx(12.0, abs=0.3)


def test_one_upright_side_edge_is_a_linear_image_flush_with_the_frame():
    grid = Grid((200, 300), (0.1, 0.1), (0.0, 0.0))
    x, _ = _points(grid)
    g = beam_geometry(_frame(np.broadcast_to(x >= 6.0, grid.shape), grid))
    assert g is not None and g.apex_mm is None and np.allclose(g.direction, [0.0, 1.0])


def test_one_slanted_side_edge_or_a_ragged_region_leaves_the_beams_unknown():
    grid = Grid((200, 300), (0.1, 0.1), (0.0, 0.0))
    x, z = _points(grid)
    one_side = np.broadcast_to(x >= 8.0 + 0.3 * z, grid.shape)
    assert beam_geometry(_frame(one_side, grid)) is None
    rng = np.random.default_rng(2)
    ragged = np.zeros(grid.shape, bool)
    for r in range(grid.shape[0]):
        a, b = sorted(rng.integers(10, 290, 2))
        ragged[r, a:b + 1] = True
    assert beam_geometry(_frame(ragged, grid)) is None
    assert BeamGeometry(apex_mm=np.zeros(2)).at(np.zeros(2)).tolist() == [0.0, 1.0]


def test_a_short_line_along_the_beams_is_not_taken_for_the_needle():
    """PyMUST validation sequence `val_ph_left_side_20_shallow` (P4-2v sector, a needle from
    the left at 20 degrees): on its second frame the learned map's strongest line is the
    reverberation tail under the needle's first millimetres, 13 degrees from the beams, whose
    end lies 4 mm from the tip. It is refused, and no tip is reported; once the shaft shows
    across the beams it is tracked within 1 mm."""
    pytest.importorskip("onnxruntime")
    from needlenet.trackers import make_tracker

    seq = synth.load_sequence(VALIDATION / "val_ph_left_side_20_shallow.npz")
    est = make_tracker("inplane", "line", "learned", seed=0).run(seq)
    assert est[1].status.value != "tracking" and "from the beams" in est[1].reason
    tracked = [k for k, e in enumerate(est) if e.status.value == "tracking"]
    assert tracked and tracked[0] <= 3
    err = [np.linalg.norm(est[k].tip_mm - seq.tip_mm[k]) for k in tracked]
    assert max(err) < 3.0 and np.median(err) < 1.0
