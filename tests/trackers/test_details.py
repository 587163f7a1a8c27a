"""What NeedleEstimate.to_json writes (the frames of ``needlenet track --json``): the shared
fields, then each tracker's details under their field names; hand-made estimates."""

import json
from dataclasses import FrozenInstanceError

import numpy as np
import pytest

from needlenet.trackers import (
    AxialDetails,
    AxialModel,
    InplaneDetails,
    LineDetails,
    NeedleEstimate,
    Status,
    VolumeDetails,
)

BASE = {"t", "status", "tip_mm", "direction", "covariance", "latency_ms"}


def _tracking(details, **kw):
    return NeedleEstimate(t=0.5, status=Status.TRACKING, tip_mm=np.array([1.0, 2.0]),
                          direction=np.array([0.6, 0.8]), covariance=np.eye(2),
                          details=details, **kw)


def test_a_frame_without_details_writes_the_shared_fields_and_its_reason():
    est = NeedleEstimate(t=0.25, status=Status.LOST, reason="the frame is constant")
    assert est.to_json() == {"t": 0.25, "status": "lost", "tip_mm": None, "direction": None,
                             "covariance": None, "latency_ms": 0.0,
                             "reason": "the frame is constant"}
    assert set(NeedleEstimate(t=0.0, status=Status.SEARCHING).to_json()) == BASE


def test_fields_with_a_default_are_written_only_when_set():
    out = _tracking(InplaneDetails(np.float64(2.5))).to_json()
    assert set(out) == BASE | {"shaft_contrast"}
    assert type(out["shaft_contrast"]) is float  # numpy scalars as Python numbers
    # False is a value when the default is None, and no value when the default is False
    out = _tracking(InplaneDetails(2.5, measurement_accepted=False, mirrored=False,
                                   candidates=np.int64(3))).to_json()
    assert out["measurement_accepted"] is False and "mirrored" not in out
    assert out["candidates"] == 3 and type(out["candidates"]) is int
    assert _tracking(InplaneDetails(2.5, mirrored=True)).to_json()["mirrored"] is True


def test_arrays_are_rounded_lists_and_the_axis_point_is_shared():
    details = LineDetails(entry_mm=np.array([0.1234567, 5.0]), theta_deg=30.0,
                          tip_velocity_mm_s=np.array([1.0, -2.0]), shaft_support=0.9,
                          segment_length_mm=12.0, tip_measurement_mm=np.array([1.0, 2.0]),
                          tip_from_tip_map=False)
    out = _tracking(details, axis_point_mm=details.entry_mm).to_json()
    assert out["axis_point_mm"] == out["entry_mm"] == [0.123457, 5.0]
    assert out["tip_from_tip_map"] is False
    # the filter's first frame: no gate decision; no restart
    assert "measurement_accepted" not in out and "restarted" not in out
    json.dumps(out)


def test_required_fields_are_written_even_when_none_and_the_model_in_place():
    nan = float("nan")
    model = AxialModel(R_mm=nan, theta0_deg=nan, phi_deg=nan, R_sd_mm=nan, theta0_sd_deg=nan,
                       shape_v_mm=None, shape_u_mm=None, origin_xz_mm=None, u_axis_xz=None,
                       origin_depth_mm=nan, rotation_depth_mm=None, pf_updates=0)
    details = AxialDetails(depth_mm=3.0, ncc_peak=nan, predicted_u_mm=nan, outlier=False,
                           roi_source=None, score=20.0, model=model, image_ms=1.0,
                           filter_ms=0.1)
    out = _tracking(details).to_json()
    assert "model" not in out and "axis_point_mm" not in out
    assert out["shape_u_mm"] is None and out["roi_source"] is None
    assert out["rotation_depth_mm"] is None and out["outlier"] is False
    assert set(out) == BASE | {
        "depth_mm", "ncc_peak", "predicted_u_mm", "outlier", "roi_source", "score", "R_mm",
        "theta0_deg", "phi_deg", "R_sd_mm", "theta0_sd_deg", "shape_v_mm", "shape_u_mm",
        "origin_xz_mm", "u_axis_xz", "origin_depth_mm", "rotation_depth_mm", "pf_updates",
        "image_ms", "filter_ms"}


def test_volume_details_without_and_with_a_tip():
    lost = NeedleEstimate(t=0.0, status=Status.LOST, reason="RANSAC: too few candidates",
                          details=VolumeDetails(inliers=0, ransac_trials=40, roi_voxels=900))
    assert set(lost.to_json()) == BASE | {"reason", "inliers", "ransac_trials", "roi_voxels"}
    found = _tracking(VolumeDetails(inliers=80, ransac_trials=12, roi_voxels=900,
                                    alpha_deg=90.0, beta_deg=73.0,
                                    measured_tip_mm=np.array([1.0, 2.0, 3.0])),
                      axis_point_mm=np.zeros(3))
    out = found.to_json()
    assert set(out) == BASE | {"axis_point_mm", "inliers", "ransac_trials", "roi_voxels",
                               "alpha_deg", "beta_deg", "measured_tip_mm"}
    assert out["measured_tip_mm"] == [1.0, 2.0, 3.0]


def test_details_are_frozen():
    with pytest.raises(FrozenInstanceError):
        VolumeDetails(inliers=0, ransac_trials=0, roi_voxels=0).inliers = 3
