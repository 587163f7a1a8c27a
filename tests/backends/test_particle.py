"""Tests for needlenet.backends._particle: resamplers, the generic particle filter and
Mathiassen 2017's tip particle filter (section II-D)."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from needlenet.backends._particle import (
    MathiassenPFParams,
    MathiassenTipParticleFilter,
    ParticleFilter,
    effective_sample_size,
    h_pdf,
    multinomial_resample,
    residual_resample,
    stratified_resample,
    systematic_resample,
)

ALL_RESAMPLERS = [systematic_resample, stratified_resample, multinomial_resample, residual_resample]


# ---------------------------------------------------------------------------- resamplers


@pytest.mark.parametrize("resampler", [systematic_resample, residual_resample])
@pytest.mark.parametrize("seed", range(5))
def test_counts_within_floor_and_ceil_of_n_w(resampler, seed):
    rng = np.random.default_rng(seed)
    n = 57
    w = rng.dirichlet(np.full(n, 0.3))
    idx = resampler(w, rng)
    counts = np.bincount(idx, minlength=n)
    assert counts.sum() == n
    assert np.all(counts >= np.floor(n * w - 1e-9))
    assert np.all(counts <= np.ceil(n * w + 1e-9))


@pytest.mark.parametrize("resampler", ALL_RESAMPLERS)
def test_resampler_output_sorted_in_range_and_reproducible(resampler):
    w = np.random.default_rng(3).random(40)
    idx = resampler(w, 11)
    assert idx.shape == (40,)
    assert np.issubdtype(idx.dtype, np.integer)
    assert np.all(np.diff(idx) >= 0)
    assert idx.min() >= 0 and idx.max() < 40
    np.testing.assert_array_equal(idx, resampler(w, 11))  # seed reproduces exactly


@pytest.mark.parametrize("resampler", ALL_RESAMPLERS)
def test_resampler_never_draws_zero_weight(resampler):
    w = np.array([0.0, 0.5, 0.0, 0.5, 0.0])
    idx = resampler(w, 2)
    assert set(idx.tolist()) <= {1, 3}


def test_systematic_resample_hand_computed():
    # default_rng(0).random() = 0.63696...; positions (u + i) / 4 = 0.159, 0.409, 0.659, 0.909
    # against the cumulative weights [0.1, 0.3, 0.6, 1.0] -> bins 1, 2, 3, 3.
    u = np.random.default_rng(0).random()
    assert u == pytest.approx(0.6369616873214543)
    idx = systematic_resample([0.1, 0.2, 0.3, 0.4], np.random.default_rng(0))
    np.testing.assert_array_equal(idx, [1, 2, 3, 3])


def test_residual_resample_hand_computed():
    # N w = [0.4, 0.8, 1.2, 1.6]: deterministic copies of 2 and 3; residuals [.4, .8, .2, .6]
    # normalised [.2, .4, .1, .3] (cumsum .2 .6 .7 1); two systematic positions
    # (0.637 + [0, 1]) / 2 = 0.318, 0.818 -> bins 1, 3.
    idx = residual_resample([0.1, 0.2, 0.3, 0.4], np.random.default_rng(0))
    np.testing.assert_array_equal(idx, [1, 2, 3, 3])
    # integer N w: no random part at all
    np.testing.assert_array_equal(residual_resample([0.5, 0.25, 0.25, 0.0], 123), [0, 0, 1, 2])


def test_multinomial_resample_frequencies():
    w = np.array([0.1, 0.6, 0.3])
    idx = multinomial_resample(np.tile(w, 10_000) / 10_000, 5) % 3
    freq = np.bincount(idx, minlength=3) / idx.size
    np.testing.assert_allclose(freq, w, atol=0.01)


@pytest.mark.parametrize(
    ("weights", "match"),
    [
        ([0.5, -0.1, 0.6], "non-negative"),
        ([0.0, 0.0], "all be zero"),
        ([0.5, np.nan], "finite"),
        ([[0.5, 0.5]], "1-D"),
        ([], "non-empty"),
    ],
)
def test_bad_weights_raise(weights, match):
    with pytest.raises(ValueError, match=match):
        systematic_resample(weights, 0)


def test_effective_sample_size():
    assert effective_sample_size(np.full(8, 0.3)) == pytest.approx(8.0)
    assert effective_sample_size([0.0, 1.0, 0.0]) == pytest.approx(1.0)
    # normalised [1/4, 1/4, 1/2]: 1 / (1/16 + 1/16 + 1/4) = 8/3
    assert effective_sample_size([1.0, 1.0, 2.0]) == pytest.approx(8.0 / 3.0)


# ---------------------------------------------------------------------------- generic filter


def test_weighted_mean_and_covariance_hand_computed():
    pf = ParticleFilter([[0.0, 1.0], [2.0, 1.0]], weights=[1.0, 3.0])
    mean, cov = pf.estimate()
    np.testing.assert_allclose(mean, [1.5, 1.0])
    # 0.25 * 1.5^2 + 0.75 * 0.5^2 = 0.75 on x; no spread on the second coordinate
    np.testing.assert_allclose(cov, [[0.75, 0.0], [0.0, 0.0]], atol=1e-15)


def test_update_with_zero_likelihood_everywhere_keeps_weights_and_says_why():
    pf = ParticleFilter(np.arange(5.0), weights=[1, 2, 3, 4, 5], rng=0)
    before = pf.weights.copy()
    outcome = pf.update(lambda x: np.zeros(len(x)))
    assert not outcome
    assert "zero likelihood" in outcome.reason
    np.testing.assert_array_equal(pf.weights, before)


def test_update_resamples_below_threshold_only():
    pf = ParticleFilter(np.arange(10.0), resample_threshold=0.5, rng=0)
    # mild likelihood: N_eff stays above 5, no resampling
    out = pf.update(lambda x: 1.0 + 0.01 * x[:, 0])
    assert out and not out.resampled
    assert not np.allclose(pf.weights, 0.1)
    # sharp likelihood: N_eff ~ 1, resampled to uniform weights on the best particle
    out = pf.update(lambda x: np.exp(-50.0 * (x[:, 0] - 7.0) ** 2), log=False)
    assert out.resampled and out.ess < 5
    np.testing.assert_allclose(pf.weights, 0.1)
    np.testing.assert_array_equal(pf.particles[:, 0], 7.0)


def test_log_likelihood_update_survives_underflow():
    pf = ParticleFilter(np.array([0.0, 1.0]), resample_threshold=0.0)
    out = pf.update(lambda x: -1e4 * (1 + x[:, 0]), log=True)  # exp() underflows to 0
    assert out
    np.testing.assert_allclose(pf.weights, [1.0, 0.0], atol=1e-300)


def test_particle_filter_tracks_constant_velocity_target():
    """1-D constant-velocity target, noisy positions: the PF beats the raw measurements and
    agrees with FilterPy's Kalman filter, the optimal estimator for this linear model."""
    rng = np.random.default_rng(42)
    dt, r_std, q_std, n_steps = 1.0, 2.0, 0.05, 60
    F = np.array([[1.0, dt], [0.0, 1.0]])
    truth = np.stack([np.arange(1, n_steps + 1) * 1.5, np.full(n_steps, 1.5)], axis=1)
    z = truth[:, 0] + r_std * rng.standard_normal(n_steps)

    x0, p0 = np.array([0.0, 1.0]), np.array([2.0, 1.0])
    pf = ParticleFilter(x0 + p0 * rng.standard_normal((4000, 2)), rng=rng)
    kf = KalmanFilter(dim_x=2, dim_z=1)
    kf.x, kf.P, kf.F = x0.copy(), np.diag(p0**2), F
    kf.H = np.array([[1.0, 0.0]])
    kf.R *= r_std**2
    kf.Q = np.diag([q_std**2, q_std**2])

    def transition(p, g):
        return p @ F.T + q_std * g.standard_normal(p.shape)

    pf_est, kf_est = [], []
    for zk in z:
        pf.predict(transition)
        pf.update(lambda p, zk=zk: np.exp(-0.5 * ((p[:, 0] - zk) / r_std) ** 2))
        kf.predict()
        kf.update(zk)
        pf_est.append(pf.mean[0])
        kf_est.append(kf.x[0])
    pf_est, kf_est = np.array(pf_est), np.array(kf_est)

    def rms(e):
        return np.sqrt(np.mean(e**2))

    rms_raw = rms(z - truth[:, 0])
    rms_pf = rms(pf_est - truth[:, 0])
    assert rms_pf < 0.6 * rms_raw
    assert rms(pf_est - kf_est) < 0.2 * r_std
    assert pf.mean[1] == pytest.approx(1.5, abs=0.15)


# ---------------------------------------------------------------------------- Mathiassen 2017


def test_h_pdf_is_a_density_over_the_axis():
    rng = np.random.default_rng(1)
    x = np.arange(0.0, 300.0)
    h = rng.standard_normal(300)
    pdf = h_pdf(h, x, x_bar_px=120.0, sigma_s_px=75.0)
    assert pdf.sum() == pytest.approx(1.0)  # eq. (20)
    assert np.all(pdf >= 0)
    assert pdf[np.argmin(h)] == 0.0  # h - min h of eq. (21)


def test_h_pdf_hand_computed():
    # eq. (21): h - min h = [0, 1, 1, 0], Gaussian at x_bar = 1, sigma_s = 1: [., 1, e^-1/2, .]
    pdf = h_pdf([2.0, 3.0, 3.0, 2.0], [0.0, 1.0, 2.0, 3.0], x_bar_px=1.0, sigma_s_px=1.0)
    g = np.exp(-0.5)
    np.testing.assert_allclose(pdf, [0.0, 1.0 / (1.0 + g), g / (1.0 + g), 0.0])
    # a very wide window leaves (h - min h) / sum(h - min h)
    h = np.array([1.0, 4.0, 2.0, 3.0])
    np.testing.assert_allclose(h_pdf(h, np.arange(4.0), 0.0, 1e9), (h - 1) / 6.0)
    # flat h carries no information: uniform
    np.testing.assert_allclose(h_pdf(np.ones(5), np.arange(5.0), 2.0, 10.0), 0.2)


def test_h_pdf_bad_input():
    with pytest.raises(ValueError, match="strictly increasing"):
        h_pdf([1.0, 2.0, 3.0], [0.0, 2.0, 1.0], 1.0, 1.0)
    with pytest.raises(ValueError, match="shape"):
        h_pdf([1.0, 2.0, 3.0], [0.0, 1.0], 1.0, 1.0)
    with pytest.raises(ValueError, match="sigma_s_px"):
        h_pdf([1.0, 2.0], [0.0, 1.0], 1.0, 0.0)


def test_mathiassen_parameters_of_section_3b():
    pf, pf_v = MathiassenPFParams.pf(), MathiassenPFParams.pf_v()
    assert pf.n_particles == pf_v.n_particles == 200
    assert pf.init_position_std_px == pytest.approx(0.05 / np.sqrt(2) * 50)
    assert pf.process_position_std_px == pytest.approx(0.05 / np.sqrt(2) * 100)
    assert (pf.sigma_s_px, pf_v.sigma_s_px) == (150.0, 75.0)
    assert (pf.init_velocity_std_px_s, pf_v.init_velocity_std_px_s) == (50.0, 5.0)
    assert (pf.process_velocity_std_px_s, pf_v.process_velocity_std_px_s) == (100.0, 5.0)
    assert pf_v.velocity_variance_px2_s2 == 1.0
    with pytest.raises(ValueError, match="window_centre"):
        MathiassenPFParams(window_centre="middle")


def _insertion(seed, n_frames=80, dt=0.05, speed_px_s=100.0, x0_px=100.0):
    """A tip moving at 10 mm/s (0.1 mm/px) along a 600 px axis; h(x) is a peak at the tip
    plus noise, and 30 % of the frames add a stronger spurious peak somewhere on the axis."""
    rng = np.random.default_rng(seed)
    x_axis = np.arange(0.0, 600.0)
    tips = x0_px + speed_px_s * dt * np.arange(1, n_frames + 1)
    h = np.exp(-0.5 * ((x_axis - tips[:, None]) / 6.0) ** 2)
    h += 0.15 * rng.standard_normal(h.shape)
    clutter = rng.random(n_frames) < 0.3
    centres = rng.uniform(0.0, 600.0, n_frames)
    h += 1.2 * clutter[:, None] * np.exp(-0.5 * ((x_axis - centres[:, None]) / 6.0) ** 2)
    velocity = speed_px_s + rng.standard_normal(n_frames)  # robot, R_v = 1
    return x_axis, tips, h, velocity


@pytest.mark.parametrize("seed", [0, 1])
def test_pf_v_beats_pf_and_both_beat_the_raw_maximum(seed):
    x_axis, tips, h, velocity = _insertion(seed)
    pf = MathiassenTipParticleFilter(100.0, 0.0, MathiassenPFParams.pf(), rng=seed + 10)
    pf_v = MathiassenTipParticleFilter(100.0, velocity[0], MathiassenPFParams.pf_v(), rng=seed + 10)
    est = np.array([pf.step(hk, x_axis).position_px for hk in h])
    est_v = np.array(
        [pf_v.step(hk, x_axis, vk).position_px for hk, vk in zip(h, velocity, strict=True)]
    )
    raw = x_axis[np.argmax(h, axis=1)]

    def rms(e):
        return np.sqrt(np.mean(e**2))

    rms_raw, rms_pf, rms_pf_v = rms(raw - tips), rms(est - tips), rms(est_v - tips)
    assert rms_pf < 0.1 * rms_raw  # the spurious peaks throw the raw maximum off
    assert rms_pf_v < 0.75 * rms_pf
    assert rms_pf_v < 1.5  # px


def test_step_off_axis_returns_the_prediction_with_a_reason():
    pf = MathiassenTipParticleFilter(1000.0, 0.0, rng=0)
    est = pf.step(np.arange(50.0), np.arange(50.0))  # every particle beyond the axis
    assert not est
    assert "zero likelihood" in est.reason
    assert est.position_px == pytest.approx(1000.0, abs=10.0)
