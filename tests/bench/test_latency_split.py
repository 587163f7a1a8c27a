"""bench latency's split of a run into detection and steady state."""

import numpy as np

from needlenet.bench._latency import split_detection
from needlenet.trackers._base import NeedleEstimate, Status


def _est(statuses):
    return [NeedleEstimate(t=0.1 * i, status=s) for i, s in enumerate(statuses)]


def test_detection_runs_to_the_first_tracking_frame():
    s, t = Status.SEARCHING, Status.TRACKING
    lat = np.array([30.0, 85.0, 5.0, 4.0, 4.5, 6.0])
    detect, steady = split_detection(_est([s, t, t, t, t, t]), lat)
    assert detect.tolist() == [30.0, 85.0] and steady.tolist() == [5.0, 4.0, 4.5, 6.0]
    # a tracker that reports tracking at once: only the first frame is detection
    detect, steady = split_detection(_est([t] * 6), lat)
    assert detect.tolist() == [30.0] and steady.size == 5


def test_without_tracking_the_first_frame_is_the_detection():
    lat = np.array([3.0, 2.0, 2.5])
    detect, steady = split_detection(_est([Status.SEARCHING] * 3), lat)
    assert detect.tolist() == [3.0] and steady.tolist() == [2.0, 2.5]
    # tracking only on the last frame still leaves one steady frame
    detect, steady = split_detection(_est([Status.SEARCHING] * 2 + [Status.TRACKING]), lat)
    assert detect.tolist() == [3.0, 2.0] and steady.tolist() == [2.5]
