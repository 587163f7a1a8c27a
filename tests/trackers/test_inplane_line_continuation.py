"""A confirmed needle whose map goes on past its tip, more weakly, to the edge of the view:
its tip has left the view only if it can have reached that edge since it was seen (the
filter's speed prior); where the tip is seen advancing and the edge is farther off, the weak
continuation is no needle (the streak past a tip of plane-wave imaging), and the tip stays
tracked where the needle ends. A tip that stops while the map runs on may be a needle that
fades on the map as it goes on: lost, not tracked where the map stopped."""

import cv2
import numpy as np
import pytest

import synth
from needlenet.features import FeatureSource, Frame, Likelihood
from needlenet.trackers._base import Status
from needlenet.trackers._inplane_line import LineTracker

H, W, STEP = 200, 300, 0.2  # rows, columns, mm


class _Maps(FeatureSource):
    """A stand-in learned source: one shaft map per frame, in order."""

    kind = "learned"
    name = "map-stub"
    target_reference = "centerline"

    def __init__(self, maps):
        self.maps = list(maps)

    def likelihood(self, frame, roi=None):
        return Likelihood(shaft=self.maps[frame.index], tip=None, source=self.name)


def _run(tip_cols, fade_col=W):
    """A needle from the top edge at about 17 degrees, its tip advancing through the columns
    ``tip_cols`` (one a frame, 20 frames/s), confident (0.9) on the map up to its tip (or up
    to ``fade_col``, where the needle fades on the map) and weaker (0.35: above
    ``learned_extend_level``, under ``learned_level``) from there to the right edge:
    (estimates, true tips (x, z) mm)."""
    entry = np.array([0.0, 10.0])  # (row, col)
    d = np.array([0.3, 1.0]) / np.hypot(0.3, 1.0)
    maps, tips = [], []
    for col in tip_cols:
        tip = entry + d * (col - entry[1]) / d[1]
        seen = entry + d * (min(col, fade_col) - entry[1]) / d[1]
        edge = entry + d * (W - 1 - entry[1]) / d[1]
        shaft = np.zeros((H, W), np.float32)
        cv2.line(shaft, (int(seen[1]), int(round(seen[0]))),
                 (int(edge[1]), int(round(edge[0]))), 0.35, 3)
        cv2.line(shaft, (int(entry[1]), int(entry[0])), (int(seen[1]), int(round(seen[0]))),
                 0.9, 3)
        maps.append(shaft)
        tips.append(np.array([tip[1], tip[0]]) * STEP)
    rng = np.random.default_rng(11)
    grid = synth.Grid((H, W), (STEP, STEP), (0.0, 0.0))
    tr = LineTracker(features=_Maps(maps))
    est = [tr.update(Frame(image=rng.integers(40, 120, (H, W)).astype(np.uint8), grid=grid,
                           t=0.05 * k, index=k)) for k in range(len(tip_cols))]
    return est, tips


@pytest.mark.parametrize("far", [True, False])
def test_a_weak_continuation_to_the_edge_is_the_tip_leaving_only_where_it_can_have(far):
    # far: the tip 1 mm a frame from 26 mm to 19 mm short of the edge; near: from 8 mm to
    # 1 mm short of it (the filter's speed prior, 20 mm/s at its gate's 3 sigma over 0.05 s,
    # with the search's 2 mm gap: 5 mm)
    cols = np.arange(8) * 5 + (150 if far else 255)
    est, tips = _run(cols)
    tracking = np.array([e.status == Status.TRACKING for e in est])
    assert tracking[:3].all(), [e.reason for e in est[:3]]
    if far:
        assert tracking.all(), [e.reason for e in est]
        err = [float(np.linalg.norm(e.tip_mm - t)) for e, t in zip(est, tips, strict=True)]
        assert max(err) < 1.0, err
    else:
        # once the edge lies within reach of the tip (5.0 mm along it on frame 4), the tip may
        # have left the view
        assert not tracking[4:].any()
        assert "runs on to the edge" in est[4].reason


def test_a_needle_fading_on_the_map_is_lost_once_its_tip_stops_advancing_there():
    # the map's confident evidence stops at column 180 (22 mm from the edge along the needle)
    # while the needle goes on 1 mm a frame: tracked while its measured tip still advances,
    # lost within a few frames of it stopping, never a tip more than 3 mm off
    cols = np.arange(36) * 5 + 120
    est, tips = _run(cols, fade_col=180)
    tracking = np.array([e.status == Status.TRACKING for e in est])
    assert tracking[3:12].all(), [e.reason for e in est[:12]]
    err = [float(np.linalg.norm(e.tip_mm - t)) for e, t in zip(est, tips, strict=True)
           if e.tip_mm is not None]
    assert max(err) < 3.0, err
    assert not tracking[18:].any()
    assert "runs on to the edge" in est[18].reason



class _MapsWithTip(_Maps):
    """The stand-in learned source with a tip map as well."""

    def __init__(self, maps, tips):
        super().__init__(maps)
        self.tips = list(tips)

    def likelihood(self, frame, roi=None):
        return Likelihood(shaft=self.maps[frame.index], tip=self.tips[frame.index],
                          source=self.name)


def test_a_new_tracks_first_tip_is_not_read_on_its_weaker_continuation():
    """A needle's first frame, confident on the map (0.9) to its tip and weaker (0.35) for 6
    mm past it, the tip map firing at that continuation's end (the streak past a tip of
    plane-wave imaging, as PyMUST's images show it): the new track's tip is the confident
    segment's end. Once tracked, a needle's continuation confirmed by the tip map is read as
    before (``test_inplane_line.py``: a shallow needle through the side)."""
    entry = np.array([0.0, 10.0])  # (row, col)
    d = np.array([0.3, 1.0]) / np.hypot(0.3, 1.0)
    tip = entry + d * 150.0  # 30 mm along
    streak = entry + d * 180.0  # 6 mm on
    shaft = np.zeros((H, W), np.float32)
    cv2.line(shaft, (int(tip[1]), int(round(tip[0]))), (int(streak[1]), int(round(streak[0]))),
             0.35, 3)
    cv2.line(shaft, (int(entry[1]), int(entry[0])), (int(tip[1]), int(round(tip[0]))), 0.9, 3)
    tip_map = np.zeros((H, W), np.float32)
    cv2.circle(tip_map, (int(streak[1]), int(round(streak[0]))), 3, 0.9, -1)
    grid = synth.Grid((H, W), (STEP, STEP), (0.0, 0.0))
    image = np.random.default_rng(12).integers(40, 120, (H, W)).astype(np.uint8)
    tr = LineTracker(features=_MapsWithTip([shaft], [tip_map]))
    est = tr.update(Frame(image=image, grid=grid, t=0.0, index=0))
    assert est.status == Status.TRACKING, est.reason
    true_tip = np.array([tip[1], tip[0]]) * STEP
    assert np.linalg.norm(est.tip_mm - true_tip) < 0.6, (est.tip_mm, true_tip)
