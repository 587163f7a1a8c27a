"""Tests for needlenet.backends._bicycle: Carriere 2016's bicycle model (eqs. (2)-(5)), its
particle filter (section IV, steps 1-10) and metrics (section V, eq. (8))."""

import numpy as np
import pytest

from needlenet.backends._bicycle import (
    CarriereParams,
    CarriereParticleFilter,
    bicycle_path,
    bicycle_step,
    curvature_radius,
    fit_plane_angle_pca,
    heading_increment,
    shape_error,
    tip_error,
    uv_to_xyz,
    xyz_to_uv,
)


def _fit_circle(x, y):
    """Algebraic (Kasa) least-squares circle: x^2 + y^2 = 2 a x + 2 b y + c."""
    A = np.stack([2 * x, 2 * y, np.ones_like(x)], axis=1)
    (a, b, c), *_ = np.linalg.lstsq(A, x**2 + y**2, rcond=None)
    return a, b, np.sqrt(c + a**2 + b**2)


def _integrate(theta0, phi, radius, alpha, n_steps, turn_step=None):
    """Iterate eq. (2) over time steps (one call per step, vectorised over nothing)."""
    state = np.array([0.0, 0.0, 0.0, theta0, phi])
    beta = heading_increment(alpha, radius)
    states = [state]
    for k in range(n_steps):
        if turn_step is not None and k == turn_step:
            beta = -beta  # 180-degree bevel rotation
        state = bicycle_step(state, alpha, beta)
        states.append(state)
    return np.array(states)


def test_curvature_radius_is_l_over_sin_beta():
    assert curvature_radius(10.0, np.pi / 6) == pytest.approx(20.0)
    np.testing.assert_allclose(curvature_radius([1.0, 2.0], np.pi / 2), [1.0, 2.0])


def test_bicycle_step_hand_computed():
    out = bicycle_step([1.0, 2.0, 3.0, np.pi / 6, np.pi / 3], 2.0, 0.1)
    # x += 2 sin(30) cos(60) = 0.5, y += 2 sin(30) sin(60) = 0.866, z += 2 cos(30) = 1.732
    np.testing.assert_allclose(
        out, [1.5, 2.0 + np.sqrt(3) / 2, 3.0 + np.sqrt(3), np.pi / 6 + 0.1, np.pi / 3]
    )


def test_bicycle_step_is_vectorised_over_states():
    rng = np.random.default_rng(0)
    states = rng.standard_normal((7, 4, 5))
    alpha = rng.random((7, 4))
    out = bicycle_step(states, alpha, 0.01)
    assert out.shape == (7, 4, 5)
    single = bicycle_step(states[3, 2], alpha[3, 2], 0.01)
    np.testing.assert_allclose(out[3, 2], single)
    with pytest.raises(ValueError, match=r"\(\.\.\., 5\)"):
        bicycle_step(np.zeros(4), 1.0, 0.0)


@pytest.mark.parametrize("phi", [0.0, 0.6])
def test_small_steps_trace_a_circle_of_radius_l_over_sin_beta(phi):
    wheelbase, steering = 50.0, np.deg2rad(2.0)
    R = curvature_radius(wheelbase, steering)  # 1432.7 mm
    states = _integrate(0.0, phi, R, alpha=0.5, n_steps=600)
    u = states[:, 0] * np.cos(phi) + states[:, 1] * np.sin(phi)
    # the motion stays in the plane of angle phi about z
    np.testing.assert_allclose(
        -states[:, 0] * np.sin(phi) + states[:, 1] * np.cos(phi), 0.0, atol=1e-12
    )
    uc, vc, radius = _fit_circle(u, states[:, 2])
    assert radius == pytest.approx(R, rel=1e-6)
    # exactly: eq. (2) is an Euler step, so the points are the vertices of a regular polygon
    # with chord alpha and turn beta = alpha / R, whose circumradius is alpha / (2 sin(beta/2))
    # and whose centre sits half a chord up the insertion axis, at v = alpha / 2.
    beta = 0.5 / R
    assert radius == pytest.approx(0.5 / (2 * np.sin(beta / 2)), rel=1e-9)
    assert uc == pytest.approx(radius * np.cos(beta / 2), rel=1e-9)
    assert vc == pytest.approx(0.25, abs=1e-6)


def test_closed_form_path_matches_integrated_model_through_a_turn():
    theta0, R, alpha = np.deg2rad(1.5), 800.0, 0.05
    states = _integrate(theta0, 0.0, R, alpha, n_steps=2400, turn_step=1200)
    v_turn = states[1200, 2]
    u = bicycle_path(states[:, 2], R, theta0, turn_depths=(v_turn,))
    np.testing.assert_allclose(u, states[:, 0], atol=2e-3)


def test_path_for_theta0_zero_is_a_circle_through_the_origin():
    v = np.linspace(0.0, 150.0, 301)
    R = 1500.0
    np.testing.assert_allclose(bicycle_path(v, R, 0.0), R - np.sqrt(R**2 - v**2), atol=1e-12)
    np.testing.assert_allclose(bicycle_path(v, -R, 0.0), -(R - np.sqrt(R**2 - v**2)), atol=1e-12)


def test_path_starts_at_the_origin_with_heading_theta0():
    theta0 = np.deg2rad(3.0)
    u = bicycle_path(np.array([0.0, 1e-4]), 1200.0, theta0)
    assert u[0] == pytest.approx(0.0, abs=1e-12)
    assert (u[1] - u[0]) / 1e-4 == pytest.approx(np.tan(theta0), rel=1e-4)


def test_turn_keeps_value_and_slope_and_mirrors_the_curvature():
    R, theta0, vt, h = 1000.0, np.deg2rad(-1.0), 60.0, 1e-3
    v = vt + h * np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
    u = bicycle_path(v, R, theta0, turn_depths=(vt,))
    u_straight = bicycle_path(v, R, theta0)
    assert u[2] == pytest.approx(u_straight[2], abs=1e-12)  # value continuous at the turn
    slope_left = (u[2] - u[1]) / h
    slope_right = (u[3] - u[2]) / h
    assert slope_right == pytest.approx(slope_left, abs=2e-5)  # slope continuous
    curv_left = (u[2] - 2 * u[1] + u[0]) / h**2
    curv_right = (u[4] - 2 * u[3] + u[2]) / h**2
    assert curv_left == pytest.approx(1 / R, rel=1e-2)
    assert curv_right == pytest.approx(-1 / R, rel=1e-2)
    # the new circle is the old one reflected through the turn point (eq. (4)):
    # u(vt + s) = 2 u(vt) - u_without_turn(vt - s)
    s = np.linspace(0.0, 50.0, 11)
    after = bicycle_path(vt + s, R, theta0, turn_depths=(vt,))
    before = bicycle_path(vt - s, R, theta0)
    np.testing.assert_allclose(after, 2 * u[2] - before, atol=1e-10)


def test_two_turns_and_broadcast_over_particles():
    rng = np.random.default_rng(4)
    R = rng.normal(1500.0, 300.0, 6)
    th = np.deg2rad(rng.normal(0.0, 2.0, 6))
    v = np.linspace(0.0, 200.0, 41)
    u = bicycle_path(v, R, th, turn_depths=(120.0, 60.0))
    assert u.shape == (6, 41)
    for i in range(6):
        np.testing.assert_allclose(u[i], bicycle_path(v, R[i], th[i], (60.0, 120.0)))


def test_path_without_solution_is_nan_and_bad_turns_raise():
    u = bicycle_path(np.array([10.0, 30.0]), 20.0, 0.0)
    assert np.isfinite(u[0]) and np.isnan(u[1])  # v beyond the radius
    assert np.all(np.isnan(bicycle_path(np.array([1.0]), 0.0, 0.0)))
    with pytest.raises(ValueError, match="positive"):
        bicycle_path(np.array([1.0]), 100.0, 0.0, turn_depths=(0.0,))


@pytest.mark.parametrize("phi", [0.7, -1.2, 2.0])
def test_pca_plane_angle_and_uv_round_trip(phi):
    v = np.linspace(0.0, 100.0, 201)
    uv = np.stack([bicycle_path(v, 400.0, np.deg2rad(2.0)), v], axis=1)
    origin = np.array([3.0, -2.0, 5.0])
    xyz = uv_to_xyz(uv, phi, origin)
    phi_hat = fit_plane_angle_pca(xyz)
    assert -np.pi / 2 < phi_hat <= np.pi / 2
    # the plane is recovered up to its direction: phi_hat = phi (mod pi)
    assert np.sin(phi_hat - phi) == pytest.approx(0.0, abs=1e-9)
    back = xyz_to_uv(xyz, phi_hat)  # origin defaults to the first point
    np.testing.assert_allclose(np.abs(back), np.abs(uv), atol=1e-9)
    np.testing.assert_allclose(uv_to_xyz(back, phi_hat, xyz[0]), xyz, atol=1e-9)
    if np.cos(phi_hat - phi) > 0:
        np.testing.assert_allclose(back, uv, atol=1e-9)


def test_pca_with_noise_and_bad_input():
    rng = np.random.default_rng(8)
    v = np.linspace(0.0, 120.0, 241)
    uv = np.stack([bicycle_path(v, 300.0, 0.0), v], axis=1)
    xyz = uv_to_xyz(uv, 0.4) + 0.05 * rng.standard_normal((v.size, 3))
    assert fit_plane_angle_pca(xyz) == pytest.approx(0.4, abs=0.01)
    assert fit_plane_angle_pca(np.stack([np.zeros(5), np.zeros(5), np.arange(5.0)], 1)) == 0.0
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        fit_plane_angle_pca(np.zeros((5, 2)))


def _observed_needle(seed, R=1500.0, theta0_deg=2.0, D=80.0, step=0.5, noise=0.2):
    rng = np.random.default_rng(seed)
    v = np.arange(0.0, D + 1e-9, step)  # the experimental images' 0.5 mm spacing
    u = bicycle_path(v, R, np.deg2rad(theta0_deg)) + noise * rng.standard_normal(v.size)
    u[0] = 0.0  # the first point is the origin of the (u, v) plane
    return v, u


def test_carriere_filter_recovers_a_noisy_needle():
    R, theta0_deg, D, final = 1500.0, 2.0, 80.0, 140.0
    v, u = _observed_needle(0, R, theta0_deg, D)
    pf = CarriereParticleFilter(CarriereParams(rotation_depth_mm=D), rng=1)
    outcomes = [pf.update(vk, uk) for vk, uk in zip(v, u, strict=True)]
    assert not any(outcomes[:20]) and "10 mm" in outcomes[0].reason  # v < 10 mm: waiting
    assert all(outcomes[20:]) and pf.n_updates == v.size - 20
    assert pf.stopped
    late = pf.update(80.5, 2.0)
    assert not late and "rotation depth" in late.reason
    assert pf.theta0_deg == pytest.approx(theta0_deg, abs=0.2)
    assert pf.radius_mm == pytest.approx(R, rel=0.1)
    # the needle is rotated at D and inserted to 140 mm: predict the final tip
    v_all = np.linspace(0.0, final, 281)
    u_true = bicycle_path(v_all, R, np.deg2rad(theta0_deg), (D,))
    u_pred = pf.predict_shape(v_all, (D,))
    assert tip_error(u_true[-1], u_pred[-1]) < 0.5  # mm
    assert shape_error(v_all, u_true, u_pred) < 20.0  # mm^2 (Table I, Beef D80: 18.4)


def test_carriere_filter_initial_distribution():
    pf = CarriereParticleFilter(rng=3)  # step 1: R ~ N(1500, 600), theta_0 ~ N(0, 5 deg)
    assert pf.particles.shape == (500, 2)
    assert pf.particles[:, 0].mean() == pytest.approx(1500.0, abs=3 * 600 / np.sqrt(500))
    assert pf.particles[:, 0].std() == pytest.approx(600.0, rel=0.1)
    assert pf.particles[:, 1].mean() == pytest.approx(0.0, abs=3 * 5 / np.sqrt(500))
    assert pf.particles[:, 1].std() == pytest.approx(5.0, rel=0.1)


def test_carriere_steps_2_to_8_with_full_gain():
    """gamma = 1 and c = 0: every particle but the per-point winners lands on the mean of the
    p winners (steps 5-7, a particle that wins twice counts twice), and mu, sigma are the
    particles' mean and std (step 8)."""
    params = CarriereParams(gain=1.0, n_replaced=0, n_particles=50)
    pf = CarriereParticleFilter(params, rng=5)
    before = pf.particles.copy()
    obs_v = np.array([0.0, 3.0, 4.5, 7.0, 10.0])
    obs_u = np.array([0.0, 0.05, 0.1, 0.1, 0.2])
    outcomes = [pf.update(vk, uk) for vk, uk in zip(obs_v, obs_u, strict=True)]
    assert [bool(o) for o in outcomes] == [False] * 4 + [True]
    # steps 2-4 by hand: depths 2, 4, 6, 8, 10 mm pick the observations at 3, 4.5, 7, 7, 10
    pick = np.array([1, 2, 3, 3, 4])
    u_hat = bicycle_path(obs_v[pick], before[:, 0], np.deg2rad(before[:, 1]))
    best = np.argmin(np.abs(obs_u[pick] - u_hat), axis=0)  # step 5
    target = before[best].mean(axis=0)  # step 6
    kept = np.zeros(50, dtype=bool)
    kept[best] = True
    np.testing.assert_array_equal(pf.particles[kept], before[kept])
    np.testing.assert_allclose(pf.particles[~kept], np.broadcast_to(target, (50 - kept.sum(), 2)))
    np.testing.assert_allclose(pf.mu, pf.particles.mean(axis=0))
    np.testing.assert_allclose(pf.sigma, pf.particles.std(axis=0))


def test_metrics_hand_computed():
    assert tip_error(3.0, 2.5) == pytest.approx(0.5)
    np.testing.assert_allclose(tip_error([1.0, -1.0], [0.0, 1.0]), [1.0, 2.0])
    # |u - u_hat| = [0, 1, 2] over v = [0, 1, 2]: 0.5 (0 + 1) + 0.5 (1 + 2) = 2 mm^2
    assert shape_error([0.0, 1.0, 2.0], [0.0, 1.0, 2.0], [0.0, 0.0, 0.0]) == pytest.approx(2.0)
    # uneven spacing: |u - u_hat| = [1, 1, 3] over v = [0, 2, 3]: 2 * 1 + 1 * 2 = 4
    assert shape_error([0.0, 2.0, 3.0], [1.0, 0.0, 3.0], [0.0, 1.0, 0.0]) == pytest.approx(4.0)
    with pytest.raises(ValueError, match="one length"):
        shape_error([0.0, 1.0], [0.0, 1.0, 2.0], [0.0, 1.0])
