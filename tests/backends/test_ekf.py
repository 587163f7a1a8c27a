"""Tests of the extended Kalman filter and Ye 2025's PV and PRV models
(needlenet/backends/_ekf.py)."""

import numpy as np
import pytest

from needlenet.backends import KalmanFilter, chatelain_control_points_model
from needlenet.backends._ekf import (
    AdaptiveNoise,
    ExtendedKalmanFilter,
    YeEKFParams,
    ye_prv_model,
    ye_pv_model,
)

FS_HZ = 25.0  # Ye 2025, section 4.1


def _central_difference(fun, x, *args, eps=1e-6):
    x = np.asarray(x, dtype=float)
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = eps
        cols.append((fun(x + e, *args) - fun(x - e, *args)) / (2.0 * eps))
    return np.column_stack(cols)


@pytest.mark.parametrize("make", [ye_pv_model, ye_prv_model])
def test_jacobians_match_central_differences(make):
    model = make()
    rng = np.random.default_rng(10)
    relative = make is ye_prv_model
    for _ in range(20):
        v_in = rng.uniform(0.5, 3.0)
        lateral = rng.uniform(-0.4, 0.4, 2) * (1.0 if relative else v_in)
        x = np.r_[rng.normal(0.0, 20.0, 3), lateral]
        np.testing.assert_allclose(model.F(x, v_in), _central_difference(model.f, x, v_in),
                                   rtol=0, atol=1e-6)
        np.testing.assert_allclose(model.H(x), _central_difference(model.h, x),
                                   rtol=0, atol=1e-6)


def test_prv_jacobian_differs_from_the_printed_eq_12():
    # Printed (1,5) entry -v_z / v'_x; with v_z = v_in v'_z the derivative is -T v_in v'_z / v'_x.
    model = ye_prv_model()
    T, v_in = 1.0 / FS_HZ, 2.0
    x = np.array([0.0, 0.0, 0.0, 0.2, 0.1])
    vx_rel = np.sqrt(1.0 - 0.2**2 - 0.1**2)
    A = model.F(x, v_in)
    assert A[0, 4] == pytest.approx(-T * v_in * 0.1 / vx_rel, rel=1e-12)
    assert A[0, 4] != pytest.approx(-(v_in * 0.1) / vx_rel, rel=1e-3)
    assert A[1, 3] == pytest.approx(T * v_in, rel=1e-12)  # printed 1 / v_in


def test_velocity_floor_keeps_the_model_finite():
    # |v_yz| above v_in (PV) or |v'_yz| above 1 (PRV): eq. (3) has no real root for v_x.
    for model, lateral in ((ye_pv_model(), 0.5), (ye_prv_model(), 0.8)):
        x = np.array([0.0, 0.0, 0.0, lateral, lateral])
        for v_in in (0.0, 0.1):
            assert np.all(np.isfinite(model.f(x, v_in)))
            A = model.F(x, v_in)
            assert np.all(np.isfinite(A)) and A[0, 3] == 0.0 and A[0, 4] == 0.0


def test_linear_ekf_matches_the_kalman_filter():
    F, H, Q, R = chatelain_control_points_model(1, dim=3, dt=0.1, q=1.0, r=0.5)
    x0, P0 = np.ones(6), 4.0 * np.eye(6)
    ekf = ExtendedKalmanFilter(lambda x, u: F @ x, lambda x, u: F, lambda x: H @ x,
                               lambda x: H, Q, R, x0, P0)
    kf = KalmanFilter(x0, P0, F, H, Q, R)
    zs = np.random.default_rng(11).normal(size=(500, 3))
    for z in zs:
        ekf.predict()
        kf.predict()
        res = ekf.update(z)
        kf.update(z)
        np.testing.assert_allclose(ekf.x, kf.x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ekf.P, kf.P, rtol=0, atol=1e-12)
        assert res.accepted and res.mahalanobis == pytest.approx(kf.mahalanobis, rel=1e-12)


# ----------------------------------------------------------------- simulated insertion


def _insertion(rng, n=2000):
    """Ye 2025, section 4.1: v_in 0 -> 2 mm/s over 100 samples, 3 mm/s from sample 500, 2 mm/s
    from 1500, plus 0.025 mm/s sinusoid of period 20 s, at 25 Hz. The tip bends gradually
    towards +Y and +Z (relative lateral velocities growing to 0.2 and 0.1). Measurements: X
    with N(0, 0.05^2) mm noise (taken from the probe), Y and Z with U(-2, 2) mm noise."""
    k = np.arange(n)
    v_plan = np.where(k < 100, 2.0 * k / 100.0, 2.0)
    v_plan = np.where((k >= 500) & (k < 1500), 3.0, v_plan)
    v_in = np.maximum(v_plan + 0.025 * np.sin(2.0 * np.pi * (k / FS_HZ) / 20.0), 0.0)
    rel_y, rel_z = 0.2 * k / n, 0.1 * k / n
    rel = np.column_stack([np.sqrt(1.0 - rel_y**2 - rel_z**2), rel_y, rel_z])
    velocity = v_in[:, None] * rel
    position = np.vstack([np.zeros(3), np.cumsum(velocity[:-1] / FS_HZ, axis=0)])
    noise = np.column_stack([rng.normal(0.0, 0.05, n), rng.uniform(-2.0, 2.0, (n, 2))])
    return v_in, position, velocity, position + noise


def _run(model, v_in, z, **kwargs):
    x0 = np.r_[z[0], 0.0, 0.0]  # start at the first measurement, moving along X
    P0 = np.diag(np.r_[np.diag(model.R), 0.01, 0.01])
    ekf = ExtendedKalmanFilter.from_model(model, x0, P0, **kwargs)
    states, velocities = [ekf.x.copy()], [model.velocity(ekf.x, v_in[0])]
    for k in range(1, len(z)):
        ekf.predict(v_in[k - 1])
        ekf.update(z[k])
        states.append(ekf.x.copy())
        velocities.append(model.velocity(ekf.x, v_in[k]))
    return np.array(states), np.array(velocities), ekf


@pytest.fixture(scope="module")
def insertion():
    return _insertion(np.random.default_rng(12))


@pytest.fixture(scope="module")
def runs(insertion):
    v_in, _, _, z = insertion
    return {name: _run(make(), v_in, z) for name, make in (("pv", ye_pv_model),
                                                           ("prv", ye_prv_model))}


def test_pv_and_prv_track_the_curved_tip_path(insertion, runs):
    _, position, _, z = insertion
    noise_rmse = np.sqrt(np.mean(np.sum((z - position) ** 2, axis=1)))  # about 1.63 mm
    rmse = {name: np.sqrt(np.mean(np.sum((states[:, :3] - position) ** 2, axis=1)))
            for name, (states, _, _) in runs.items()}
    assert rmse["pv"] < 0.45 * noise_rmse
    assert rmse["prv"] < 0.25 * noise_rmse
    assert rmse["prv"] < rmse["pv"]  # Table 2, first row: PRV slightly better


def test_prv_estimates_v_x_better_at_the_speed_steps(insertion, runs):
    _, _, velocity, _ = insertion
    steps = np.r_[500:700, 1500:1700]
    vx_rmse = {name: np.sqrt(np.mean((v[steps, 0] - velocity[steps, 0]) ** 2))
               for name, (_, v, _) in runs.items()}
    assert vx_rmse["prv"] < 0.8 * vx_rmse["pv"]
    assert vx_rmse["prv"] < 0.02  # mm/s; Table 2 reports 0.0076 (PRV) and 0.0247 (PV)


def test_gate_rejects_a_20_sigma_outlier(insertion):
    v_in, _, _, z = insertion
    model = ye_prv_model()
    _, _, ekf = _run(model, v_in[:300], z[:300], gate_sigmas=5.0)
    assert ekf.n_rejected == 0
    ekf.predict(v_in[299])
    x_prior, P_prior = ekf.x.copy(), ekf.P.copy()
    S = model.H(x_prior) @ P_prior @ model.H(x_prior).T + model.R
    outlier = model.h(x_prior) + np.array([0.0, 20.0 * np.sqrt(S[1, 1]), 0.0])
    res = ekf.update(outlier)
    assert not res.accepted and ekf.n_rejected == 1
    assert res.mahalanobis >= 20.0
    np.testing.assert_array_equal(ekf.x, x_prior)
    np.testing.assert_array_equal(ekf.P, P_prior)
    assert ekf.update(z[300]).accepted
    assert not np.array_equal(ekf.x, x_prior)


def test_adaptive_r_grows_when_the_measurement_noise_grows():
    rng = np.random.default_rng(13)
    v_in, position, _, _ = _insertion(rng)
    half = 1000
    sd = np.where(np.arange(2000) < half, 1.0, 3.0)  # Gaussian noise, sd x3 halfway
    z = position + np.column_stack([rng.normal(0.0, 0.05, 2000),
                                    sd[:, None] * rng.normal(size=(2000, 2))])
    params = YeEKFParams(r_prv=(0.05**2, 1.0, 1.0))  # R matched to the first half
    model = ye_prv_model(params)
    x0 = np.r_[z[0], 0.0, 0.0]
    ekf = ExtendedKalmanFilter.from_model(model, x0, np.diag([1.0, 1.0, 1.0, 0.01, 0.01]),
                                          adaptive=AdaptiveNoise(window=200))
    for k in range(1, 2000):
        ekf.predict(v_in[k - 1])
        ekf.update(z[k])
        if k == half - 1:
            r_before = np.diag(ekf.R).copy()
    r_after = np.diag(ekf.R)
    assert r_before[1:] == pytest.approx([1.0, 1.0], rel=0.3)
    assert r_after[1:] == pytest.approx([9.0, 9.0], rel=0.3)
    assert np.linalg.eigvalsh(ekf.R).min() > 0.0


def test_bad_input_names_the_argument():
    model = ye_pv_model()
    with pytest.raises(ValueError, match="dt_s"):
        YeEKFParams(dt_s=0.0)
    with pytest.raises(ValueError, match="dt_s"):
        YeEKFParams(dt_s=-0.04)
    with pytest.raises(ValueError, match="q_pv"):
        YeEKFParams(q_pv=(1e-6, 1e-6))
    with pytest.raises(ValueError, match="x0"):
        ExtendedKalmanFilter.from_model(model, np.zeros(4), np.eye(5))
    with pytest.raises(ValueError, match="P0"):
        ExtendedKalmanFilter.from_model(model, np.zeros(5), np.eye(4))
    ekf = ExtendedKalmanFilter.from_model(model, np.zeros(5), np.eye(5))
    with pytest.raises(ValueError, match="z"):
        ekf.update(np.zeros(2))
    with pytest.raises(ValueError, match="u"):
        ekf.predict(None)
    with pytest.raises(ValueError, match="u"):
        ekf.predict(-1.0)
    bad = ExtendedKalmanFilter(lambda x, u: x[:2], lambda x, u: np.eye(5), model.h, model.H,
                               model.Q, model.R, np.zeros(5), np.eye(5))
    with pytest.raises(ValueError, match="f"):
        bad.predict(1.0)
    with pytest.raises(ValueError, match="window"):
        AdaptiveNoise(window=1)
