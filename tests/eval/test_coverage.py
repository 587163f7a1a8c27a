"""The share of tracked frames whose labelled tip lies inside the reported 95% region
(``needlenet.eval.tip_coverage``, in every labelled ``needlenet track`` summary)."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import chi2

from needlenet.eval import tip_coverage
from needlenet.eval._coverage import region_coverage
from needlenet.trackers._base import NeedleEstimate, Status


def _estimate(tip, cov, status=Status.TRACKING):
    return NeedleEstimate(t=0.0, status=status, tip_mm=None if tip is None else np.asarray(tip),
                          covariance=None if cov is None else np.asarray(cov))


def test_tip_coverage_counts_tracked_visible_labelled_frames_with_a_covariance():
    truth = np.zeros((6, 2))
    truth[4] = np.nan  # no label
    seq = SimpleNamespace(tip_mm=truth, visible=np.array([1, 1, 1, 0, 1, 1], bool))
    est = [_estimate([0.5, 0.0], np.eye(2)),  # inside: 0.5 < 2.45
           _estimate([3.0, 0.0], np.eye(2)),  # outside
           _estimate([0.1, 0.0], None),  # no covariance: not counted
           _estimate([9.0, 0.0], np.eye(2)),  # not visible: not counted
           _estimate([0.0, 0.0], np.eye(2)),  # no label: not counted
           _estimate([0.0, 0.0], np.eye(2), Status.LOST)]  # not tracking: not counted
    assert tip_coverage(est, seq) == pytest.approx(0.5)
    assert tip_coverage(est[2:3], seq.__class__(tip_mm=truth[:1], visible=None)) is None
    assert tip_coverage(est, SimpleNamespace(tip_mm=None, visible=None)) is None


def test_region_coverage_agrees_with_scipys_chi_square():
    rng = np.random.default_rng(3)
    y = rng.normal(size=(500, 3)) * np.array([0.5, 1.0, 2.0])
    cov = np.broadcast_to(np.diag([0.25, 1.0, 4.0]), (500, 3, 3)).copy()
    cov[7] = np.nan  # not usable
    cov[8] = -np.eye(3)  # not positive definite
    usable, inside = region_coverage(y, cov)
    keep = np.ones(500, bool)
    keep[[7, 8]] = False
    d2 = (y[keep] ** 2 / np.array([0.25, 1.0, 4.0])).sum(axis=1)
    assert usable == 498
    assert inside == int(np.count_nonzero(chi2.cdf(d2, 3) <= 0.95))
