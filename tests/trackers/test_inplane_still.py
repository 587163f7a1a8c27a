"""Needle-like lines that stood still beside the advancing needle are tissue
(needlenet/trackers/_inplane_still.py)."""

import dataclasses

import numpy as np
import pytest

import synth
from needlenet.backends import LineSearchParams, NeedleLine, WorkingMap
from needlenet.trackers._base import Status
from needlenet.trackers._inplane_still import StillLineParams, StillLines
from needlenet.trackers._registry import make_tracker


def _map_with_lines(*lines, shape=(200, 200), step=0.2):
    """A working map (0.2 mm grid from the origin) with 0.6 mm wide lines of probability 1
    between the given (x, z) mm ends."""
    v = np.zeros(shape, np.float32)
    zz, xx = np.mgrid[:shape[0], :shape[1]] * step
    for a, b in lines:
        a, b = np.asarray(a, float), np.asarray(b, float)
        d = (b - a) / np.linalg.norm(b - a)
        t = (xx - a[0]) * d[0] + (zz - a[1]) * d[1]
        off = np.abs((xx - a[0]) * -d[1] + (zz - a[1]) * d[0])
        v[(off <= 0.3) & (t >= 0) & (t <= np.linalg.norm(b - a))] = 1.0
    return WorkingMap(v, 0.0, 0.0, step)


def _seg(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = (b - a) / np.linalg.norm(b - a)
    return NeedleLine(True, "", a, b, d, 1.0, 1.0)


NEEDLE = ((39.0, 0.0), (15.0, 18.0))
TISSUE = ((5.0, 0.0), (2.0, 15.0))


def _observe(still, wm, tip, looks=lambda seg, level: ""):
    n = _seg(*NEEDLE)
    still.observe(wm, 0.5, LineSearchParams(), 0.5 * (n.start_mm + n.end_mm), n.direction,
                  np.asarray(tip, float), looks)


def test_a_line_seen_twice_in_place_while_the_needle_moved_is_recorded():
    wm = _map_with_lines(NEEDLE, TISSUE)
    still = StillLines()
    _observe(still, wm, (20.0, 14.0))
    assert still.lines == []  # seen once
    _observe(still, wm, (19.0, 15.0))
    assert still.lines == []  # the needle moved 1.4 mm: not yet
    _observe(still, wm, (17.0, 16.5))
    assert len(still.lines) == 1  # 4.2 mm since the first sighting
    assert still.holds(_seg(*TISSUE)) and still.holds(_seg(*TISSUE).reversed())
    assert not still.holds(_seg(*NEEDLE))
    shifted = _seg(np.add(TISSUE[0], (4.0, 0.0)), np.add(TISSUE[1], (4.0, 0.0)))
    assert not still.holds(shifted)  # 4 mm beside it: another line


def test_a_line_that_moved_with_the_needle_is_not_recorded():
    """A probe moved by hand moves the tissue line as well as the needle."""
    still = StillLines()
    _observe(still, _map_with_lines(NEEDLE, TISSUE), (20.0, 14.0))
    moved = tuple(tuple(np.add(q, (6.0, 0.0))) for q in TISSUE)
    _observe(still, _map_with_lines(NEEDLE, moved), (26.0, 14.0))
    assert still.lines == []


def test_a_line_the_look_rejects_is_not_recorded():
    wm = _map_with_lines(NEEDLE, TISSUE)
    still = StillLines()
    for tip in ((20.0, 14.0), (15.0, 18.0)):
        _observe(still, wm, tip, looks=lambda seg, level: "no")
    assert still.lines == []


def test_settings_out_of_range_are_refused():
    with pytest.raises(ValueError, match="advance_mm"):
        StillLineParams(advance_mm=0.0)


@pytest.mark.parametrize("seed", [14, 22])
def test_a_tissue_line_from_the_skin_is_not_taken_once_the_needle_is_gone(seed):
    """Issue 21's protocol, shortened: seed 14's and 22's worlds hold a straight tissue line
    entering through the skin (7.6 and 14.7 mm; the learned map marks both like a faint
    needle). Seen beside the advancing needle, it is not taken when the needle leaves
    (frames 40-69 needle-free: 30 of 30 `tracking` without this rule, measured 0)."""
    seq = synth.generate("inplane", seed=seed, frames=70)
    free = synth.generate("inplane", seed=seed, frames=70, needle_free=True)
    images = seq.images.copy()
    images[40:] = free.images[40:]
    est = make_tracker("inplane", "line", "learned").run(dataclasses.replace(seq,
                                                                             images=images))
    assert not any(e.status == Status.TRACKING for e in est[40:])
    err = [np.linalg.norm(e.tip_mm - t)
           for e, t in zip(est[:40], seq.tip_mm[:40], strict=True) if e.tip_mm is not None]
    assert len(err) >= 30 and np.median(err) < 1.0
