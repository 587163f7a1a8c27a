"""Tests for needlenet.eval._axial_metrics: Carriere 2016's tip error, shape error (eq. 8),
cross-section tracking error and Table II timing, on hand-computed cases."""

import json
from dataclasses import replace

import numpy as np
import pytest

import synth
from needlenet.eval._axial_metrics import axial_errors, axial_metrics, eq8_shape_error
from needlenet.trackers import AxialDetails, AxialModel, NeedleEstimate, Status


def test_eq8_hand_computed():
    v = np.array([0.0, 1.0, 2.0, 3.0])
    # |u - u_hat| = v: the integral from 0 to 3 of v dv is 4.5, exact for the trapezoid
    assert eq8_shape_error(v, v, np.zeros(4)) == pytest.approx(4.5)
    # |u - u_hat| = v^2 sampled at 0..3: trapezoid (0 + 1)/2 + (1 + 4)/2 + (4 + 9)/2 = 9.5
    assert eq8_shape_error(v, v**2 + 1.0, np.ones(4)) == pytest.approx(9.5)
    # order and missing samples do not matter
    assert eq8_shape_error(v[::-1], v[::-1], np.zeros(4)) == pytest.approx(4.5)
    u = np.array([0.0, 1.0, np.nan, 3.0])
    assert eq8_shape_error(v, u, np.zeros(4)) == pytest.approx(0.5 + 2.0 * 2.0)
    assert np.isnan(eq8_shape_error([1.0], [1.0], [0.0]))


def _details(depth_mm, image_ms=1.0, filter_ms=0.5, **model) -> AxialDetails:
    """An axial tracker's details at ``depth_mm``: no model unless ``model`` gives its
    fields."""
    nan = np.nan
    fields = dict(R_mm=nan, theta0_deg=nan, phi_deg=nan, R_sd_mm=nan, theta0_sd_deg=nan,
                  shape_v_mm=None, shape_u_mm=None, origin_xz_mm=None, u_axis_xz=None,
                  origin_depth_mm=nan, rotation_depth_mm=5.0, pf_updates=0)
    return AxialDetails(depth_mm=depth_mm, ncc_peak=nan, predicted_u_mm=nan, outlier=False,
                        roi_source=None, score=nan, model=AxialModel(**{**fields, **model}),
                        image_ms=image_ms, filter_ms=filter_ms)


def _sequence(T=11, step=1.0, offset=(0.3, 0.4)):
    """A labelled axial sequence whose shaft bends along +x: x = 0.01 v^2 at depth v = k step
    (slices translated along their elevation axis), plus estimates that track it with a
    constant (0.3, 0.4) mm offset and predict a straight needle from frame 5 (v = 5)."""
    v = step * np.arange(T)
    truth = np.stack([2.0 + 0.01 * v**2, np.full(T, 10.0)], axis=1)
    pose = np.repeat(np.eye(4)[None], T, axis=0)
    pose[:, 1, 3] = v
    seq = synth.Sequence(
        images=np.zeros((T, 4, 4), np.uint8), spacing_mm=np.array([0.3, 0.3]),
        origin_mm=np.array([0.0, 0.0]), modality="axial",
        timestamps_s=np.arange(T) / 20.0, dynamic_range_db=60.0,
        meta={"params": {"rotation_depth_mm": 5.0}}, probe_pose=pose, tip_mm=truth,
        visible=np.ones(T, bool))
    shape_v = np.linspace(0.0, 20.0, 21)
    estimates = []
    for k in range(T):
        model = {}
        if k >= 2:  # the model exists from frame 2; it predicts u = 0 everywhere
            model = dict(shape_v_mm=shape_v, shape_u_mm=np.zeros_like(shape_v),
                         origin_xz_mm=truth[0] + offset, u_axis_xz=np.array([1.0, 0]),
                         origin_depth_mm=0.0)
        estimates.append(NeedleEstimate(t=k / 20.0, status=Status.TRACKING,
                                        tip_mm=truth[k] + offset, latency_ms=2.0 + k % 2,
                                        details=_details(v[k], 1.0 + k % 2, **model)))
    return seq, estimates


def test_tip_shape_and_tracking_errors_hand_computed():
    seq, est = _sequence()
    m = axial_errors(est, seq)
    np.testing.assert_allclose(m.tracking_error_mm, 0.5)  # |(0.3, 0.4)|
    assert m.prediction_frame == 5  # the last frame at or before D = 5 mm
    assert m.final_frame == 10
    np.testing.assert_allclose(m.u_true_mm, 0.01 * np.arange(11.0) ** 2, atol=1e-12)
    np.testing.assert_allclose(m.u_pred_mm, 0.0)
    assert m.tip_error_mm == pytest.approx(1.0)  # 0.01 * 10^2
    assert m.tip_error_transverse_mm == pytest.approx(1.0)
    # absolute: predicted crossing = the tracked origin (offset included), truth at x = 3
    assert m.tip_error_absolute_mm == pytest.approx(np.hypot(1.0 - 0.3, 0.4))
    # eq. (8) by the trapezoid over v = 0..10: 0.01 (100 / 2 + 1 + 4 + ... + 81) = 3.35
    assert m.shape_error_mm2 == pytest.approx(3.35)
    # the dict form that needlenet.eval.evaluate and the CLI use: flat, JSON-ready
    out = axial_metrics(est, seq)
    s = out["summary"]
    json.dumps(out)
    assert s["tracking_error_mean_mm"] == pytest.approx(0.5)
    assert s["tracking_error_sd_mm"] == pytest.approx(0.0, abs=1e-12)
    assert s["tip_error_mm"] == pytest.approx(1.0)
    assert s["shape_error_mm2"] == pytest.approx(3.35)
    assert s["total_ms_mean"] == pytest.approx(np.mean(2.0 + np.arange(11) % 2))
    assert s["image_ms_sd"] == pytest.approx(np.std(1.0 + np.arange(11) % 2))
    assert (s["filter_ms_mean"], s["filter_ms_sd"]) == pytest.approx((0.5, 0.0))
    assert s["detection_rate"] == 1.0
    np.testing.assert_allclose(out["per_frame"]["tracking_error_mm"], 0.5)


def test_evaluate_dispatches_axial_with_latency():
    from needlenet.eval import evaluate

    seq, est = _sequence()
    s = evaluate("axial", est, seq)["summary"]
    assert s["tip_error_mm"] == pytest.approx(1.0)
    assert s["latency_median_ms"] == pytest.approx(2.0)


def test_prediction_depth_and_untracked_frames():
    seq, est = _sequence()
    est[3] = NeedleEstimate(t=0.15, status=Status.LOST, details=_details(3.0))
    seq.visible[7] = False
    m = axial_errors(est, seq, prediction_depth_mm=3.5)
    assert m.prediction_frame == 2  # frame 3 was lost: the last model at or before 3.5 mm
    assert np.isnan(m.tracking_error_mm[3]) and np.isnan(m.tracking_error_mm[7])
    assert m.detection_rate == pytest.approx(9 / 10)
    assert m.false_tracking_rate == pytest.approx(1.0)  # frame 7 invisible but tracked
    # frame 7 is dropped from eq. (8): the trapezoid bridges 6..8
    full = 0.01 * (100 / 2 + np.sum(np.arange(1, 10.0) ** 2))
    bridged = full - 0.01 * (36 + 2 * 49 + 64) / 2 + 0.01 * (36 + 64)
    assert m.shape_error_mm2 == pytest.approx(bridged)


def test_no_model_gives_nan_and_length_is_checked():
    seq, est = _sequence()
    for e in est:
        e.details = replace(e.details, model=replace(e.details.model, shape_u_mm=None))
    m = axial_errors(est, seq)
    assert m.prediction_frame == -1
    assert np.isnan(m.tip_error_mm) and np.isnan(m.shape_error_mm2)
    with pytest.raises(ValueError, match="estimates for a sequence of 11 frames"):
        axial_errors(est[:-1], seq)
