"""Ye's loop closed through images: the detector's calibration (detection stops where the plane
passes the tip), the physical in-plane test, learned maps of the needle's wall, the scanner's
field cache, the axial edge helper and the volume tracker's move to a new probe frame."""

import json
import math

import numpy as np
import pytest

from needlenet.backends import KalmanFilter, angles_to_direction
from needlenet.servo import (
    CALIBRATION_SEEDS,
    Measurement,
    YeServoConfig,
    calibrate_detector,
    calibrate_reach,
    in_slice,
    make_detector,
    run_ye,
    servo_rows,
    slice_half_width_mm,
)
from needlenet.servo._api import check_options
from needlenet.servo._images import ServoWorld
from needlenet.trackers._cross_section import below_top_edge, local_peak, subpixel_peak
from needlenet.trackers.volume import VolumeTracker


@pytest.fixture(scope="module")
def learned():
    det = make_detector("learned")
    cal = calibrate_detector(det)
    return det, cal


def test_calibrated_detection_stops_at_the_tip(learned):
    """On a world the calibration never saw, the plane swept across the tip: the needle is
    found behind the tip and no longer once the plane has passed it (reach ~0, where the
    uncalibrated detector reaches ~1.5 mm ahead)."""
    det, cal = learned
    assert cal.seeds == CALIBRATION_SEEDS and abs(cal.reach_mm) <= 0.3
    reach = calibrate_reach(det, seed=1_000_005, arc_mm=(40.0, 100.0, 160.0),
                            offsets_mm=np.round(np.arange(-1.0, 2.01, 0.1), 6))
    assert abs(reach) <= 0.3
    thr, det.echo_threshold = det.echo_threshold, None
    try:
        loose = calibrate_reach(det, seed=1_000_005, arc_mm=(40.0, 100.0, 160.0),
                                offsets_mm=np.round(np.arange(-1.0, 2.01, 0.1), 6))
    finally:
        det.echo_threshold = thr
    assert loose > 1.0  # the elevation beam's reach the calibration removes


def test_wall_maps_are_moved_one_radius_deeper(learned, monkeypatch):
    """A model marking the wall facing the probe (target_reference "wall"): the same map
    gives a centre one needle radius deeper than for a centre-line model (whichever the
    shipped model is)."""
    det, _ = learned
    w = ServoWorld(11, 400)
    k = 200
    probe = np.array([w.tip[k, 0] - 0.8, w.tip[k, 1], w.probe_z])
    w.prepare(np.array([probe[0] - 1.0, probe[0] + 1.0]))
    img = w.image(k, probe)
    monkeypatch.setattr(det.source, "target_reference", "centerline", raising=False)
    found, xz_c, _ = det.detect(img, w.grid)
    assert found and det.target_reference == "centerline"
    monkeypatch.setattr(det.source, "target_reference", "wall", raising=False)
    found, xz_w, _ = det.detect(img, w.grid)
    assert found and det.target_reference == "wall"
    assert xz_w[1] - xz_c[1] == pytest.approx(det.radius_mm, abs=1e-9)
    assert xz_w[0] == pytest.approx(xz_c[0])
    monkeypatch.setattr(det.source, "target_reference", "edge", raising=False)
    with pytest.raises(ValueError, match="edge"):
        det.detect(img, w.grid)


def test_in_plane_is_the_elevation_slice():
    from synth import scenario_params

    params = scenario_params("servo").imaging()
    for z in (10.0, 20.0, 40.0):
        assert slice_half_width_mm(z) == pytest.approx(0.5 * params.psf_fwhm_mm(z)[2])
    half = float(slice_half_width_mm(20.0))
    assert 0.4 < half < 0.8
    tip = np.array([[10.0, 0.0, 10.0]] * 4)
    probe = np.array([[10.0 - half + 0.01, 0, -10], [10.0 + half - 0.01, 0, -10],
                      [10.0 - half - 0.01, 0, -10], [10.0 + half + 0.01, 0, -10]])
    assert in_slice(tip, probe).tolist() == [True, True, False, False]
    with pytest.raises(ValueError):
        slice_half_width_mm([np.nan])


def test_a_shaft_seen_far_behind_the_predicted_tip_counts_as_detected():
    """Measurement.shaft_seen: the image shows the shaft without the tip's echo. With the
    probe held still, the tip runs ahead of the plane; once the EKF's predicted tip is
    behind_margin_mm ahead, K_e counts the frames as detected and the EKF is not updated."""
    cfg = YeServoConfig()

    def measure(k, probe):
        return Measurement(False, None, 0.0, shaft_seen=True)

    r = run_ye("prv", "dynamic", 200, 0, config=cfg, measure=measure)
    assert not r["stopped"]  # the needle is in the image: not lost
    ahead = r["estimate"][:, 0] - r["probe"][:, 0]
    assert np.any(r["detected"]) and not np.any(r["accepted"])
    assert np.all(ahead[r["detected"]] > cfg.behind_margin_mm - 0.2)
    r2 = run_ye("prv", "dynamic", 200, 0, config=cfg,
                measure=lambda k, p: Measurement(False, None, 0.0))
    assert r2["stopped"] and not np.any(r2["detected"])


def test_calibration_seeds_are_refused_as_run_seeds():
    with pytest.raises(ValueError, match=str(CALIBRATION_SEEDS[0])):
        check_options("servo", features=("learned",), seed=CALIBRATION_SEEDS[0] - 1,
                      repeats=3)
    check_options("servo", features=("ideal",), seed=CALIBRATION_SEEDS[0], repeats=1)


def test_servo_rows_learned_quick_keeps_the_tip_near_the_plane():
    """A quick seeded closed loop through learned images (400 frames, 16 s of Ye's profile):
    the tip in the imaged slice (1.0 measured; 0.71 with a 0.75 mm behind-margin, 0.01 when
    the detector accepted the needle 1.5 mm ahead of the tip; issue 5 asks 0.95), the probe
    mostly behind it, P-hat within 0.5 mm, never lost."""
    rows = servo_rows("servo", features=("learned",), filters=("prv",), gains=("dynamic",),
                      repeats=1, seed=3, quick=True)
    (r,) = rows
    assert r["safety_stops"] == 0
    assert r["in_plane_fraction"] >= 0.95
    assert r["behind_fraction"] > 0.6 and r["lead_lag_ratio"] < 0.5
    assert r["rmse_p_mm"] <= 0.5
    assert abs(r["reach_mm"]) <= 0.3 and len(r["echo_threshold"]["levels"]) > 3
    json.dumps(r)  # plain data
    assert r["latency_p99_ms"] > 0


# ------------------------------------------------------------------ small fixes elsewhere


def test_below_top_edge_on_a_flat_column_returns_the_centre():
    F = np.full((20, 10), 0.5, np.float32)
    c = np.array([10.0, 0.0])  # at the image's edge, a flat column: no edge, no division
    assert np.array_equal(below_top_edge(F, c, 0.5, 2.0), c)
    assert np.array_equal(below_top_edge(F, c, 0.7, 2.0), c)  # below the background
    G = np.zeros((20, 10), np.float32)
    G[8:12, 4:7] = 1.0  # an echo with its upper edge between rows 7 and 8
    out = below_top_edge(G, np.array([10.0, 5.0]), 0.0, 2.0)
    assert out[0] == pytest.approx(7.5 + 2.0)


def test_local_peak_is_the_map_mode_not_the_smoothed_peak():
    """A wall-like Gaussian spot (sigma 2 px, at row 20.3, col 15.6) with a comet tail
    under it: the map's own sub-pixel mode lies within 0.05 px of the spot's centre; the
    peak of the map smoothed again at the spot's scale is pulled down the tail."""
    import cv2

    rr, cc = np.mgrid[0:48, 0:32].astype(float)
    F = np.exp(-((rr - 20.3) ** 2 + (cc - 15.6) ** 2) / (2 * 2.0**2))
    tail = (rr > 20.3) & (rr < 34) & (np.abs(cc - 15.6) < 2.0)
    F = np.maximum(F, 0.5 * tail * np.exp(-(rr - 20.3) / 10.0)).astype(np.float32)
    S = cv2.GaussianBlur(F, (0, 0), 2.0)
    idx = np.unravel_index(int(np.argmax(S)), S.shape)
    smoothed = np.asarray(idx, float) + subpixel_peak(S, idx)
    mode = local_peak(F, idx, (3, 3))
    assert mode == pytest.approx([20.3, 15.6], abs=0.05)
    assert smoothed[0] - 20.3 > 0.15


def test_scanner_field_cache_size_and_robust_keys():
    from synth._scanner import _field_key, _key

    w = ServoWorld(5, 50)
    assert w.scanner.field_cache_size == 64
    for bad in (0, -1, 2.5, True):
        with pytest.raises(ValueError, match="field_cache_size"):
            w.scanner.field_cache_size = bad
    M = np.eye(4)
    M2 = M.copy()
    M2[0, 1] = -0.0
    M2[1, 3] = 1e-12
    assert _key(M) == _key(M2)
    assert _field_key(M[:3, :3], -0.0) == _field_key(M2[:3, :3], 0.0)
    # the same pose computed two ways images from the same prepared field: no rebuild
    w.prepare(np.array([0.0, 5.0]))
    n = len(w.scanner._fields)
    w.image(10, np.array([1.0, 0.0, w.probe_z]))
    w.image(10, np.array([2.0, -0.0, w.probe_z]))
    assert len(w.scanner._fields) == n


def _rigid(yaw_deg, t):
    a = math.radians(yaw_deg)
    D = np.eye(4)
    D[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    D[:3, 3] = t
    return D


def test_volume_tracker_move_frame_chatelain():
    """The control points move as points (p_new = inv(D) p), their velocities rotate, the
    covariance rotates; moving back restores the state."""
    tr = VolumeTracker("chatelain")
    n = tr.params.n_control_points
    rng = np.random.default_rng(0)
    x = rng.normal(size=6 * n)
    A = rng.normal(size=(6 * n, 6 * n))
    P = A @ A.T + np.eye(6 * n)
    tr._kf = KalmanFilter(x.copy(), P.copy(), np.eye(6 * n), np.eye(6 * n)[: 3 * n],
                          np.eye(6 * n), np.eye(3 * n))
    tr._pending = (np.array([1.0, 2.0, 3.0]), 2)
    D = _rigid(30.0, [2.0, -1.0, 0.5])
    tr.move_frame(D)
    inv = np.linalg.inv(D)
    pos = x[: 3 * n].reshape(n, 3)
    assert np.allclose(tr._kf.x[: 3 * n].reshape(n, 3), pos @ inv[:3, :3].T + inv[:3, 3])
    assert np.allclose(tr._kf.x[3 * n:].reshape(n, 3), x[3 * n:].reshape(n, 3) @ inv[:3, :3].T)
    assert np.allclose(tr._pending[0], inv[:3, :3] @ [1.0, 2.0, 3.0] + inv[:3, 3])
    assert np.trace(tr._kf.P) == pytest.approx(np.trace(P))
    tr.move_frame(inv)
    assert np.allclose(tr._kf.x, x) and np.allclose(tr._kf.P, P)
    with pytest.raises(ValueError, match="rigid"):
        tr.move_frame(np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="4x4"):
        tr.move_frame(np.eye(3))


def test_volume_tracker_move_frame_roi_rk():
    tr = VolumeTracker("roi-rk")
    beta, alpha = 1.2, 0.4
    x = np.r_[beta, alpha, 0.01, -0.02, 5.0, 6.0, 30.0, 1.0, 0.5, -0.2]
    tr._kf = KalmanFilter(x.copy(), np.eye(10) * 0.1, np.eye(10), np.eye(10)[:8],
                          np.eye(10), np.eye(8))
    D = _rigid(-20.0, [1.0, 3.0, 0.0])
    tr.move_frame(D)
    inv = np.linalg.inv(D)
    u_new = angles_to_direction(tr._kf.x[0], tr._kf.x[1])
    assert np.allclose(u_new, inv[:3, :3] @ angles_to_direction(beta, alpha), atol=1e-9)
    assert np.allclose(tr._kf.x[4:7], inv[:3, :3] @ x[4:7] + inv[:3, 3])
    assert np.allclose(tr._kf.x[7:10], inv[:3, :3] @ x[7:10])
    tr.move_frame(D @ np.linalg.inv(D))  # identity: nothing changes
    tr.move_frame(inv)
    assert np.allclose(tr._kf.x, x, atol=1e-6)
