"""A needle's first mark (needlenet/trackers/_inplane_growing.py): a short mark is taken for a
needle once it has grown where it was; a still mark, whose ends jitter, never is, nor is one
moved as a whole."""

import numpy as np
import pytest

from needlenet.backends import NeedleLine
from needlenet.trackers._inplane_growing import GrowingMark, GrowingMarkParams, StillMarks


def _mark(start, angle_deg, length_mm):
    d = np.array([np.cos(np.deg2rad(angle_deg)), np.sin(np.deg2rad(angle_deg))])
    s = np.asarray(start, float)
    return NeedleLine(True, start_mm=s, end_mm=s + length_mm * d, direction=d, support=0.7,
                      score=length_mm)


def test_a_still_mark_whose_ends_jitter_never_grows():
    rng = np.random.default_rng(0)
    g = GrowingMark()
    growth = [g.growth_mm(_mark(rng.normal([5.0, 1.0], 0.2), 40 + rng.normal(0, 3),
                                4.0 + rng.normal(0, 0.15))) for _ in range(50)]
    assert growth[0] == 0.0
    assert max(growth) < GrowingMarkParams().growth_mm


def test_a_mark_that_grows_where_it_is_reaches_the_growth():
    g = GrowingMark()
    # a blob whose line's direction is a guess, then the needle's own line through it
    assert g.growth_mm(_mark([5.0, 1.0], 80.0, 2.5)) == 0.0
    assert g.growth_mm(_mark([4.0, 1.2], 40.0, 3.0)) == pytest.approx(0.5)
    assert g.growth_mm(_mark([4.0, 1.2], 40.0, 4.2)) == pytest.approx(1.7)


def test_a_mark_moved_as_a_whole_is_a_new_sighting():
    g = GrowingMark()
    g.growth_mm(_mark([5.0, 1.0], 40.0, 3.0))
    assert g.growth_mm(_mark([12.0, 1.0], 40.0, 4.5)) == 0.0  # 7 mm away: another mark
    assert g.growth_mm(_mark([12.0, 1.0], 40.0, 4.6)) == pytest.approx(0.1)


def test_a_sighting_is_forgotten_after_frames_without_the_mark():
    g = GrowingMark(GrowingMarkParams(forget_after_frames=2))
    g.growth_mm(_mark([5.0, 1.0], 40.0, 3.0))
    g.missed()
    assert g.growth_mm(_mark([5.0, 1.0], 40.0, 4.5)) == pytest.approx(1.5)
    g.missed()
    g.missed()
    assert g.growth_mm(_mark([5.0, 1.0], 40.0, 6.0)) == 0.0


def test_a_still_mark_holds_the_lines_along_it_only():
    marks = StillMarks()
    mark = _mark([5.0, 1.0], 40.0, 6.0)
    # its far end reached 0.3 mm further, its measured tip 0.5 mm
    marks.add(mark, mark.end_mm + 0.3 * mark.direction, mark.end_mm + 0.5 * mark.direction)
    # the same line 2 mm longer: its end 1.7 mm beyond the mark's furthest
    longer = _mark([5.0, 1.0], 40.0, 8.0)
    assert marks.advance_mm(longer, longer.end_mm) == pytest.approx(1.7)
    # or its tip measured 3 mm on: 2.5 mm beyond the mark's furthest tip
    assert marks.advance_mm(longer, longer.end_mm + longer.direction) == pytest.approx(2.5)
    # a line 15 degrees off through its middle (7.3, 2.9) is the mark seen again; one 30
    # degrees off crosses it: another line
    other = _mark([6.1, 1.6], 55.0, 3.0)
    assert marks.advance_mm(other, other.end_mm) is not None
    crossing = _mark([6.3, 1.2], 70.0, 4.0)
    assert marks.advance_mm(crossing, crossing.end_mm) is None
    # a parallel line 3 mm beside it (more than near_mm = 2 mm)
    n = np.array([-np.sin(np.deg2rad(40.0)), np.cos(np.deg2rad(40.0))])
    beside = _mark(np.array([5.0, 1.0]) + 3.0 * n, 40.0, 6.0)
    assert marks.advance_mm(beside, beside.end_mm) is None


@pytest.mark.parametrize("name, value", [("growth_mm", 0.0), ("near_mm", -1.0),
                                         ("min_length_mm", 1e3), ("forget_after_frames", 0),
                                         ("prove_within_s", 0.0)])
def test_settings_out_of_range_are_refused(name, value):
    with pytest.raises(ValueError, match=name):
        GrowingMarkParams(**{name: value})
