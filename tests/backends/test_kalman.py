"""Tests of the linear Kalman filter and the models of Chatelain 2013, Zhao 2013 and
Mathiassen 2017 (needlenet/backends/_kalman.py, _mathiassen_kf.py)."""

import numpy as np
import pytest

from needlenet.backends import (
    KalmanFilter,
    MathiassenAngleFilter,
    MathiassenAngleParams,
    MathiassenTipFilter,
    MathiassenTipParams,
    angles_to_direction,
    candidate_posterior,
    chatelain_control_points_model,
    chi2_gate,
    direction_to_angles,
    mahalanobis,
    predict,
    tip_candidates,
    update,
    zhao_model,
)


def _cv_2d(dt=0.1, q=0.5, r=0.3):
    """A 2-D constant-velocity model, state [x, y, vx, vy], measuring position."""
    return chatelain_control_points_model(1, dim=2, dt=dt, q=q, r=r)


def _cv_measurements(rng, n, model):
    """Seeded positions of a constant-velocity target with process and measurement noise."""
    F, H, Q, R = model
    x = np.array([0.0, 1.0, 2.0, -1.0])
    w = rng.multivariate_normal(np.zeros(4), Q, size=n)
    v = rng.multivariate_normal(np.zeros(2), R, size=n)
    zs = np.empty((n, 2))
    for k in range(n):
        x = F @ x + w[k]
        zs[k] = H @ x + v[k]
    return zs


# ----------------------------------------------------------------- the filter


def test_class_matches_functions_over_2000_steps():
    model = _cv_2d()
    zs = _cv_measurements(np.random.default_rng(1), 2000, model)
    x0, P0 = np.zeros(4), 10.0 * np.eye(4)
    kf = KalmanFilter(x0, P0, model.F, model.H, model.Q, model.R)
    x, P = x0, P0
    for z in zs:
        kf.predict()
        res_kf = kf.update(z)
        x, P = predict(x, P, model.F, model.Q)
        res = update(x, P, z, model.R, model.H)
        x, P = res.x, res.P
        np.testing.assert_allclose(kf.x, x, rtol=0, atol=1e-12)
        np.testing.assert_allclose(kf.P, P, rtol=0, atol=1e-12)
        np.testing.assert_allclose(kf.y, res.y, rtol=0, atol=1e-12)
        np.testing.assert_allclose(kf.S, res.S, rtol=0, atol=1e-12)
        assert abs(kf.mahalanobis - res.mahalanobis) < 1e-12
        assert abs(res_kf.log_likelihood - res.log_likelihood) < 1e-12


def test_matches_filterpy_on_constant_velocity_data():
    # FilterPy's KalmanFilter.update uses the Joseph form too (kalman_filter.py, update()), so
    # the two filters do the same arithmetic up to S^-1 (FilterPy inverts, we solve).
    filterpy_kalman = pytest.importorskip("filterpy.kalman")
    model = _cv_2d(dt=0.05, q=2.0, r=0.5)
    zs = _cv_measurements(np.random.default_rng(2), 500, model)
    x0, P0 = np.array([0.5, 0.5, 0.0, 0.0]), 25.0 * np.eye(4)
    ours = KalmanFilter(x0, P0, model.F, model.H, model.Q, model.R)
    ref = filterpy_kalman.KalmanFilter(dim_x=4, dim_z=2)
    ref.x = x0.reshape(4, 1).copy()
    ref.P, ref.F, ref.H, ref.Q, ref.R = P0.copy(), model.F, model.H, model.Q, model.R
    for z in zs:
        ours.predict()
        ref.predict()
        ours.update(z)
        ref.update(z.reshape(2, 1))
        np.testing.assert_allclose(ours.x, ref.x.ravel(), rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ours.P, ref.P, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ours.K, ref.K, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ours.S, ref.S, rtol=1e-9, atol=1e-9)
        assert ours.mahalanobis == pytest.approx(ref.mahalanobis, rel=1e-9)
        assert ours.log_likelihood == pytest.approx(ref.log_likelihood, rel=1e-9)


def test_joseph_equals_short_form_for_the_optimal_gain():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(4, 4))
    P = A @ A.T + np.eye(4)
    H = rng.normal(size=(2, 4))
    R = np.diag([0.3, 0.7])
    res = update(rng.normal(size=4), P, rng.normal(size=2), R, H)
    short = (np.eye(4) - res.K @ H) @ P  # Zhao 2013 eq. (C7), Chatelain 2013 eq. (14)
    np.testing.assert_allclose(res.P, short, rtol=0, atol=1e-12)


def test_joseph_form_keeps_P_symmetric_psd_with_precise_measurements():
    # A nearly perfect sensor (R tiny next to P) is where (I - KH)P loses symmetry.
    model = _cv_2d(dt=1.0, q=1e-3, r=1e-9)
    zs = _cv_measurements(np.random.default_rng(4), 2000, model)
    kf = KalmanFilter(np.zeros(4), 1e6 * np.eye(4), model.F, model.H, model.Q, model.R)
    for z in zs:
        kf.predict()
        kf.update(z)
        scale = np.abs(kf.P).max()
        assert np.abs(kf.P - kf.P.T).max() <= 1e-12 * scale
        assert np.linalg.eigvalsh(kf.P).min() >= -1e-12 * scale


def test_mahalanobis_and_log_likelihood_by_hand():
    # S = P + R = [[2, .5], [.5, 1.5]], det S = 2.75, y = [1, 2]:
    # y^T S^-1 y = (1.5*1 - 2*0.5*1*2 + 2*4) / 2.75 = 7.5 / 2.75 = 30/11.
    P = np.array([[1.0, 0.5], [0.5, 0.5]])
    res = update(np.zeros(2), P, [1.0, 2.0], np.eye(2), np.eye(2))
    np.testing.assert_allclose(res.S, [[2.0, 0.5], [0.5, 1.5]])
    assert res.mahalanobis == pytest.approx(np.sqrt(30.0 / 11.0), rel=1e-14)
    assert mahalanobis([1.0, 2.0], res.S) == pytest.approx(np.sqrt(30.0 / 11.0), rel=1e-14)
    expected_ll = -0.5 * (30.0 / 11.0 + np.log(2.75) + 2.0 * np.log(2.0 * np.pi))
    assert res.log_likelihood == pytest.approx(expected_ll, rel=1e-14)


def test_gate_uses_the_chi_square_distance():
    model = _cv_2d(dt=1.0, q=1e-6, r=1.0)
    kf = KalmanFilter(np.zeros(4), 1e-12 * np.eye(4), model.F, model.H, model.Q, model.R)
    threshold = chi2_gate(2, 0.99)
    assert threshold**2 == pytest.approx(-2.0 * np.log(0.01), rel=1e-9)  # chi2 with 2 dof
    # S is I (P ~ 0), so the distance of z is |z|.
    assert kf.gate([2.0, 2.0], threshold)  # |z| = 2.83 < 3.03
    assert not kf.gate([3.0, 2.0], threshold)  # 3.61
    assert chi2_gate(1, 0.9973002039367398) == pytest.approx(3.0, rel=1e-9)
    np.testing.assert_array_equal(kf.x, np.zeros(4))  # gating does not change the state


def test_bad_input_names_the_argument():
    F, H, Q, R = _cv_2d()
    with pytest.raises(ValueError, match="P"):
        predict(np.zeros(4), np.eye(3), F, Q)
    with pytest.raises(ValueError, match="x"):
        predict(np.zeros((4, 1)), np.eye(4), F, Q)
    with pytest.raises(ValueError, match="z"):
        update(np.zeros(4), np.eye(4), np.zeros(3), R, H)
    with pytest.raises(ValueError, match="H"):
        update(np.zeros(4), np.eye(4), np.zeros(2), R, H.T)
    with pytest.raises(ValueError, match="R"):
        update(np.zeros(4), np.eye(4), np.zeros(2), np.eye(3), H)
    with pytest.raises(ValueError, match="dt"):
        chatelain_control_points_model(2, dt=0.0, q=1.0, r=1.0)
    with pytest.raises(ValueError, match="dt"):
        zhao_model(-0.1)


# ----------------------------------------------------------------- Chatelain 2013


def test_chatelain_model_for_two_control_points():
    dt, q, r = 0.05, 2.0, 0.3
    F, H, Q, R = chatelain_control_points_model(2, dt=dt, q=q, r=r)
    assert F.shape == (12, 12) and H.shape == (6, 12) and Q.shape == (12, 12)
    I6 = np.eye(6)
    # eq. (8): A = [[I_3n, dt I_3n], [0, I_3n]]; eq. (9): C = [I_3n 0]
    np.testing.assert_array_equal(F[:6, :6], I6)
    np.testing.assert_array_equal(F[:6, 6:], dt * I6)
    np.testing.assert_array_equal(F[6:, :6], np.zeros((6, 6)))
    np.testing.assert_array_equal(F[6:, 6:], I6)
    np.testing.assert_array_equal(H, np.hstack([I6, np.zeros((6, 6))]))
    np.testing.assert_array_equal(R, r * I6)
    # state order of eq. (3): p_1, p_2, then their velocities; z of control point 2 is state 3..5
    x = np.arange(12.0)
    np.testing.assert_array_equal(H @ x, x[:6])
    np.testing.assert_allclose((F @ x)[3:6], x[3:6] + dt * x[9:12])
    # white-noise acceleration: Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]] per coordinate
    assert Q[0, 0] == pytest.approx(q * dt**3 / 3.0)
    assert Q[0, 6] == pytest.approx(q * dt**2 / 2.0)
    assert Q[6, 6] == pytest.approx(q * dt)
    assert Q[0, 7] == 0.0 and Q[0, 1] == 0.0


# ----------------------------------------------------------------- Zhao 2013


def test_zhao_model_blocks():
    dt = 0.5
    F, H, Q, R = zhao_model(dt)
    assert F.shape == (10, 10) and H.shape == (8, 10) and Q.shape == (10, 10)
    assert R.shape == (8, 8)
    expected_F = np.eye(10)
    expected_F[0, 2] = expected_F[1, 3] = dt  # beta, alpha advance by their rates
    expected_F[4, 7] = expected_F[5, 8] = expected_F[6, 9] = dt  # tip by its velocity
    np.testing.assert_array_equal(F, expected_F)
    expected_H = np.zeros((8, 10))
    expected_H[:2, :2] = np.eye(2)  # [I_2 0_2x8]
    expected_H[2:, 4:] = np.eye(6)  # [0_6x4 I_6]
    np.testing.assert_array_equal(H, expected_H)


def test_zhao_tracks_a_needle_at_constant_velocity_with_vanishing_error():
    dt = 0.2
    model = zhao_model(dt, r_angle=1e-4, r_position=0.01, r_velocity=0.01)
    beta_rate, alpha_rate = np.deg2rad(0.5), np.deg2rad(-0.3)  # rad/s
    tip_velocity = np.array([1.0, 0.4, -0.2])  # mm/s
    truth = np.r_[np.deg2rad(73.0), np.deg2rad(30.0), beta_rate, alpha_rate,
                  10.0, 20.0, 30.0, tip_velocity]
    x0 = truth.copy()
    x0[[0, 1]] += np.deg2rad([5.0, -5.0])  # wrong angles
    x0[[2, 3]] = 0.0  # "The initial velocities v_alpha, v_beta are set to zero"
    x0[4:7] += [2.0, -1.0, 1.5]  # wrong tip
    kf = KalmanFilter(x0, np.diag([0.1] * 4 + [10.0] * 6), *model)
    errors = []
    for _ in range(300):
        truth = model.F @ truth
        kf.predict()
        kf.update(model.H @ truth)  # exact RANSAC and speckle-tracking measurements
        errors.append(np.abs(kf.x - truth).max())
    assert errors[0] > 1e-2
    assert errors[-1] < 1e-9


def test_angle_conversions():
    beta, alpha = direction_to_angles([1.0, 1.0, 0.0])
    assert beta == pytest.approx(np.pi / 2) and alpha == pytest.approx(np.pi / 4)
    beta, alpha = direction_to_angles([0.0, 0.0, 2.0])
    assert beta == pytest.approx(0.0)
    u = np.random.default_rng(5).normal(size=(1000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    beta, alpha = direction_to_angles(3.0 * u)  # eq. (4) normalises by |u|
    np.testing.assert_allclose(angles_to_direction(beta, alpha), u, atol=1e-12)
    # eq. (4) as printed, arctan(u_y / u_x), agrees wherever u_x > 0
    front = u[:, 0] > 0
    np.testing.assert_allclose(alpha[front], np.arctan(u[front, 1] / u[front, 0]), atol=1e-12)
    with pytest.raises(ValueError, match="u"):
        direction_to_angles([1.0, 0.0])


# ----------------------------------------------------------------- Mathiassen 2017


def test_angle_filter_reaches_the_riccati_gain_of_section_III_B():
    # Random walk with Q = 1, R = 16: P^- solves P^2 - Q P - Q R = 0, K = P^- / (P^- + R).
    q, r = 1.0, 16.0
    p_prior = (q + np.sqrt(q * q + 4.0 * q * r)) / 2.0
    rng = np.random.default_rng(6)
    filt = MathiassenAngleFilter(MathiassenAngleParams())
    measured = 40.0 + rng.normal(0.0, 4.0, 400)
    filtered = np.array([filt.step(t) for t in measured])
    assert filt.gain == pytest.approx(p_prior / (p_prior + r), rel=1e-9)  # 0.2207
    assert filt.gain == pytest.approx(0.2207, abs=1e-4)
    assert np.std(filtered[100:] - 40.0) < 0.6 * np.std(measured[100:] - 40.0)


def test_tip_candidates_are_the_local_maxima_of_eq_12():
    x = np.arange(60.0)
    peaks, heights = np.array([5.0, 12.0, 30.0, 50.0]), np.array([1.0, 2.0, 3.0, 0.5])
    h = np.sum(heights * np.exp(-((x[:, None] - peaks) ** 2) / 8.0), axis=1)
    np.testing.assert_array_equal(tip_candidates(h, radius_px=10), [12, 30, 50])
    np.testing.assert_array_equal(tip_candidates(h, radius_px=3), [5, 12, 30, 50])


def test_candidate_posterior_by_hand():
    c, s, x_bar, sigma = np.array([105.0, 400.0]), np.array([1.0, 3.0]), 100.0, 200.0
    prior = s / s.sum()  # eq. (16)
    lik = np.exp(-((c - x_bar) ** 2) / (2 * sigma**2))  # eq. (14), up to 1/(sigma sqrt(2 pi))
    paper = lik * prior / np.exp(-(x_bar**2) / (2 * sigma**2))  # eq. (15) as printed
    np.testing.assert_allclose(candidate_posterior(c, s, x_bar, sigma), paper, rtol=1e-12)
    np.testing.assert_allclose(candidate_posterior(c, s, x_bar, sigma, "marginal"),
                               lik * prior / np.sum(lik * prior), rtol=1e-12)
    # Eq. (15) is not the marginal: far along the axis the "posterior" exceeds 1, so
    # R_k = R_MIN / P falls below R_MIN.
    assert candidate_posterior([460.0], [1.0], 460.0, 200.0)[0] == pytest.approx(
        np.exp(460.0**2 / (2 * 200.0**2)), rel=1e-12)  # 14.1
    assert candidate_posterior([460.0], [1.0], 460.0, 200.0, "marginal")[0] == 1.0


def test_tip_filter_prefers_the_candidate_near_the_prediction():
    filt = MathiassenTipFilter(x0_px=100.0)
    est = filt.step([104.0, 700.0], [1.0, 2.0])  # the outlier scores twice as high
    assert est.accepted and est.candidate_index == 0 and est.measurement_px == 104.0
    # R_k = R_MIN / P(j | x_bar), eq. (18)
    post = candidate_posterior([104.0, 700.0], [1.0, 2.0], est.predicted_px, 300.0)[0]
    assert est.posterior == pytest.approx(post, rel=1e-12)
    assert est.measurement_variance_px2 == pytest.approx(30.0**2 / post, rel=1e-12)
    assert 100.0 < est.position_px < 104.0
    # A close, strong candidate wins over a closer weak one.
    est = MathiassenTipFilter(x0_px=100.0).step([98.0, 130.0], [0.1, 1.0])
    assert est.candidate_index == 1


def test_tip_filter_sigma_shrinks_with_measurements_and_grows_without():
    p = MathiassenTipParams()
    filt = MathiassenTipFilter(x0_px=200.0, params=p)
    sigmas = [filt.step([200.0], [1.0]).sigma_px for _ in range(25)]
    assert sigmas[:3] == [300.0, 295.0, 290.0]  # sigma_MAX - k Delta sigma
    assert filt.sigma_px == 200.0  # floored at sigma_MIN
    far = 200.0 + p.window_sigmas * p.sigma_min_px + 50.0
    rejected = [filt.step([far], [1.0]) for _ in range(3)]
    assert not any(e.accepted for e in rejected)
    assert [e.sigma_px for e in rejected] == [200.0, 205.0, 210.0]
    assert filt.sigma_px == 215.0
    assert rejected[-1].measurement_px is None and rejected[-1].posterior is None
    assert rejected[-1].reason == "no candidate in the window"
    est = filt.step([], [])  # no candidate at all: predict only, window grows
    assert not est.accepted and est.reason == "no candidates" and filt.sigma_px == 220.0
    for _ in range(40):
        filt.step([], [])
    assert filt.sigma_px == p.sigma_max_px


def _constant_speed_insertion(use_velocity, seed=7, n=120):
    rng = np.random.default_rng(seed)
    p = MathiassenTipParams()
    speed = 100.0  # px/s: 10 mm/s at 0.1 mm/px (section III)
    truth = 150.0 + speed * p.dt_s * np.arange(1, n + 1)
    filt = MathiassenTipFilter(x0_px=150.0, params=p)
    positions = np.empty(n)
    for k in range(n):
        candidates = [truth[k] + rng.normal(0.0, 5.0), rng.uniform(0.0, 600.0)]
        v = speed + rng.normal(0.0, 1.0) if use_velocity else None
        positions[k] = filt.step(candidates, [1.0, 0.4], velocity_measurement=v).position_px
    return np.abs(positions - truth)


def test_velocity_measurements_make_the_tip_filter_converge_faster():
    without = _constant_speed_insertion(False)
    with_v = _constant_speed_insertion(True)
    assert with_v[10:60].mean() < 0.2 * without[10:60].mean()
    assert with_v[10:].max() < 10.0


def test_tip_filter_bad_input():
    filt = MathiassenTipFilter(x0_px=0.0)
    with pytest.raises(ValueError, match="candidate_scores"):
        filt.step([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="candidate_scores"):
        filt.step([1.0, 2.0], [1.0, -0.5])
    with pytest.raises(ValueError, match="dt_s"):
        MathiassenTipFilter(0.0, params=MathiassenTipParams(dt_s=0.0))
