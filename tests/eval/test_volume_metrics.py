"""Tests of Zhao 2013's volume metrics on hand-made geometry."""

import math

import numpy as np
import pytest

from needlenet.eval._volume_metrics import (
    FAILURE_MM,
    axis_accuracy,
    distance_to_line,
    evaluate_volume,
)
from needlenet.trackers import NeedleEstimate, Status, VolumeDetails
from synth import Sequence

ENTRY = np.array([0.0, 0.0, 30.0])
TIP = np.array([10.0, 0.0, 30.0])
DIRECTION = np.array([1.0, 0.0, 0.0])


def _sequence(n, visible=None):
    return Sequence(
        images=np.zeros((n, 2, 2, 2), np.uint8), spacing_mm=np.ones(3), origin_mm=np.zeros(3),
        modality="volume", timestamps_s=np.arange(n, dtype=float), dynamic_range_db=60.0,
        tip_mm=np.tile(TIP, (n, 1)), entry_mm=np.tile(ENTRY, (n, 1)),
        direction=np.tile(DIRECTION, (n, 1)),
        visible=np.ones(n, bool) if visible is None else np.asarray(visible, bool))


def _estimate(tip, direction=DIRECTION, point=None, latency_ms=100.0, trials=20):
    return NeedleEstimate(t=0.0, status=Status.TRACKING, tip_mm=np.asarray(tip, float),
                          direction=np.asarray(direction, float), covariance=np.eye(3),
                          latency_ms=latency_ms,
                          axis_point_mm=None if point is None else np.asarray(point, float),
                          details=VolumeDetails(inliers=0, ransac_trials=trials, roi_voxels=0))


def _missing(status=Status.LOST, latency_ms=100.0):
    return NeedleEstimate(t=0.0, status=status, latency_ms=latency_ms)


def test_eps_axis_is_the_larger_end_point_distance():
    # an axis parallel to the needle, 1 mm off: both ends are 1 mm away
    assert axis_accuracy(ENTRY, TIP, ENTRY + [0, 1, 0], DIRECTION) == pytest.approx(1.0)
    # an axis through the entry, tilted towards +y by atan(2/10): only the tip is off,
    # |N_tip Q2| = 10 sin(atan(0.2)) = 20 / sqrt(104)
    eps = axis_accuracy(ENTRY, TIP, ENTRY, [10.0, 2.0, 0.0])
    assert eps == pytest.approx(20.0 / math.sqrt(104.0))
    # the axis's sign and the point chosen on it do not matter
    assert axis_accuracy(ENTRY, TIP, ENTRY + [37.0, 1.0, 0.0], -DIRECTION) == pytest.approx(1.0)
    np.testing.assert_allclose(distance_to_line([[0, 3, 4], [5, 0, 0]], [0, 0, 0], [2, 0, 0]),
                               [5.0, 0.0])


def test_failure_on_tip_or_axis_beyond_3_mm():
    seq = _sequence(5, visible=[True, True, True, True, False])
    estimates = [
        _estimate(TIP + [0.5, 0.5, 0.0], point=ENTRY + [0, 0.5, 0]),  # fine: both 0.71, 0.5
        _estimate(TIP + [3.5, 0.0, 0.0], point=ENTRY),  # tip 3.5 mm along the true axis
        _estimate(TIP, direction=[10.0, 4.0, 0.0], point=TIP),  # tip exact, entry 3.71 mm off
        _missing(),  # visible but no estimate
        _estimate(TIP + [20.0, 0.0, 0.0], point=ENTRY),  # not visible: not scored
    ]
    ev = evaluate_volume(estimates, seq)
    np.testing.assert_allclose(ev.tip_error[:3], [math.sqrt(0.5), 3.5, 0.0])
    assert ev.axis_error[0] == pytest.approx(0.5)  # the tip is 0.5 mm off the axis
    assert ev.axis_error[1] == pytest.approx(0.0)
    assert ev.axis_error[2] == pytest.approx(10.0 * 4.0 / math.sqrt(116.0))
    assert np.isnan(ev.tip_error[3]) and np.isnan(ev.axis_error[3])
    np.testing.assert_array_equal(ev.failure, [False, True, True, True, False])
    assert ev.summary["failure_rate"] == pytest.approx(3 / 4)
    assert ev.summary["n_visible"] == 4 and ev.summary["n_estimated"] == 3
    assert ev.summary["false_detections"] == 1
    assert FAILURE_MM == 3.0


def test_means_and_stds_are_eqs_7_and_8():
    seq = _sequence(3)
    errors = np.array([[1.0, -1.0, 0.0], [2.0, 0.0, 0.0], [3.0, 1.0, 0.5]])
    estimates = [_estimate(TIP + e, point=ENTRY, latency_ms=lat, trials=tr)
                 for e, lat, tr in zip(errors, (50.0, 100.0, 150.0), (10, 20, 60), strict=True)]
    s = evaluate_volume(estimates, seq).summary
    assert s["tip_error_x_mean"] == pytest.approx(2.0)  # eq. (7), signed
    assert s["tip_error_x_std"] == pytest.approx(1.0)  # eq. (8): n - 1 in the denominator
    assert s["tip_error_y_mean"] == pytest.approx(0.0)
    assert s["tip_error_y_std"] == pytest.approx(1.0)
    norms = np.linalg.norm(errors, axis=1)
    assert s["tip_error_mean"] == pytest.approx(norms.mean())
    assert s["tip_error_std"] == pytest.approx(norms.std(ddof=1))
    assert s["tip_error_median"] == pytest.approx(np.median(norms))
    assert s["ransac_trials_mean"] == pytest.approx(30.0)
    assert s["latency_ms_mean"] == pytest.approx(100.0)
    assert s["first_latency_ms"] == pytest.approx(50.0)
    assert s["volumes_per_s"] == pytest.approx(10.0)


def test_angle_errors_of_eq_4_wrap_alpha():
    seq = _sequence(2)
    # true alpha = atan2(y, x) of the label direction: 179 deg; estimated -179 deg: 2 deg apart
    a_true, a_est, beta = math.radians(179.0), math.radians(-179.0), math.radians(73.0)
    seq.direction[:] = [math.sin(beta) * math.cos(a_true), math.sin(beta) * math.sin(a_true),
                        math.cos(beta)]
    b_est = math.radians(70.0)
    est_dir = [math.sin(b_est) * math.cos(a_est), math.sin(b_est) * math.sin(a_est),
               math.cos(b_est)]
    ev = evaluate_volume([_estimate(TIP, est_dir), _estimate(TIP, est_dir)], seq)
    np.testing.assert_allclose(ev.alpha_error_deg, [2.0, 2.0], atol=1e-9)
    np.testing.assert_allclose(ev.beta_error_deg, [-3.0, -3.0], atol=1e-9)


def test_inputs_are_checked():
    seq = _sequence(2)
    with pytest.raises(ValueError, match="2 frames"):
        evaluate_volume([_estimate(TIP)], seq)
    seq.tip_mm = None
    with pytest.raises(ValueError, match="no labels"):
        evaluate_volume([_estimate(TIP), _estimate(TIP)], seq)
