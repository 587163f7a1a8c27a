"""Ye 2025 probe servoing: plant, controllers, gains and full seeded runs."""

import numpy as np
import pytest

from needlenet.servo import (
    Fault,
    MassDamperAxis,
    PositionPD,
    SpeedGain,
    VelocityPI,
    YeServoConfig,
    run_ye,
    ye_insertion_velocity,
    ye_tip_path,
)


@pytest.fixture(scope="module")
def runs():
    return {(f, g): run_ye(f, g, n_samples=2000, seed=0)
            for f in ("pv", "prv") for g in ("dynamic", "constant")}


def test_velocity_profile():
    v = ye_insertion_velocity(2000)
    assert v.shape == (2000,)
    assert abs(v[0]) < 1e-12
    assert v[50] == pytest.approx(1.0 + 0.025 * np.sin(2 * np.pi * 50 / 25 / 20))
    sinus = 0.025 * np.sin(2 * np.pi * np.arange(2000) / 25 / 20)
    base = v - sinus
    assert np.allclose(base[100:500], 2.0)
    assert np.allclose(base[500:1500], 3.0)
    assert np.allclose(base[1500:], 2.0)
    assert np.max(np.abs(sinus)) == pytest.approx(0.025, rel=1e-3)


def test_tip_path_matches_synth_and_feed_speed():
    from synth._world import NeedlePath

    v = ye_insertion_velocity(2000)
    P, V = ye_tip_path(v)
    assert np.allclose(np.linalg.norm(V, axis=1), v)  # eq. (3)
    assert np.allclose(P[0], 0.0) and np.allclose(V[1] / v[1], [1, 0, 0], atol=1e-3)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) / 25.0)])
    path = NeedlePath(entry=np.zeros(3), direction=[1, 0, 0], radius_of_curvature_mm=400.0,
                      bend_direction=[0, 1, 1], max_length_mm=250.0)
    idx = [0, 700, 1999]
    assert np.allclose(path.point_at(s[idx]), P[idx], atol=1e-2)
    assert P[-1, 1] > 10 and P[-1, 1] == pytest.approx(P[-1, 2])


@pytest.mark.parametrize("integrator", ["implicit", "exact"])
def test_mass_damper_steady_state(integrator):
    ax = MassDamperAxis(150.0, 20.0, integrator=integrator)
    for _ in range(3000):
        ax.step(4.0)
    assert ax.v == pytest.approx(4.0 / 20.0, rel=1e-9)
    assert ax.steady_velocity(4.0) == 0.2


def test_mass_damper_implicit_is_eq16():
    ax = MassDamperAxis(150.0, 20.0)
    ax.v = 0.3
    ax.step(7.0)
    assert ax.v == pytest.approx((7.0 + 150.0 * 0.3) / 170.0)


def test_pi_drives_speed_to_reference():
    ax = MassDamperAxis(dt_s=1 / 7500)
    pi = VelocityPI(ax, 100.0, 20.0, n_steps=300)
    v = pi.run_mm_s(2.5)
    assert v[-1] == pytest.approx(2.5, rel=1e-6)
    assert ax.velocity_mm_s == pytest.approx(2.5, rel=1e-6)
    p0 = ax.p
    pi.run_mm_s(2.5)
    assert ax.p - p0 == pytest.approx(2.5 * 300 / 7500, rel=1e-6)  # 0.1 mm in one frame


def test_pi_closed_form_equals_stepping():
    a1, a2 = MassDamperAxis(), MassDamperAxis()
    pi1 = VelocityPI(a1, n_steps=300)
    pi2 = VelocityPI(a2, n_steps=300, v_limit=1e9, a_limit=1e9)
    pi1.run(1e-3)
    pi2._run_limited(1e-3)
    assert a1.p == pytest.approx(a2.p, rel=1e-9) and a1.v == pytest.approx(a2.v, rel=1e-9)


def test_pd_tracks_y_step():
    ax = MassDamperAxis()
    pd = PositionPD(ax, 30.0, 50.0, n_steps=300)
    v = pd.run(1.0)
    assert ax.p == pytest.approx(1.0, abs=1e-6)
    assert abs(ax.v) < 1e-6 and np.all(np.isfinite(v))


def test_pd_with_limits_still_tracks_and_respects_them():
    dt = 1 / 7500
    ax = MassDamperAxis(dt_s=dt)
    pd = PositionPD(ax, n_steps=300, v_limit=20 * dt, a_limit=2000 * dt * dt)
    v = pd.run(0.2)
    assert np.max(np.abs(v)) <= 20 * dt * (1 + 1e-12)
    assert np.max(np.abs(np.diff(v, prepend=0.0))) <= 2000 * dt * dt * (1 + 1e-9)
    for _ in range(6):  # the clipped PD overshoots, then settles within a few frames
        pd.run(0.2)
    assert ax.p == pytest.approx(0.2, abs=1e-6)
    assert pd.n_limited >= 1


def test_speed_gain_schedules():
    g = SpeedGain("dynamic")
    assert [g.update(False) for _ in range(3)] == pytest.approx([0.8, 0.64, 0.512])
    assert [g.update(True) for _ in range(2)] == pytest.approx([1.01, 1.0201])
    c = SpeedGain("constant")
    assert (c.update(True), c.update(False)) == (1.05, 0.5)
    with pytest.raises(ValueError):
        SpeedGain("fast")


@pytest.mark.parametrize("filt", ["pv", "prv"])
def test_full_run_tracks(runs, filt):
    r = runs[(filt, "dynamic")]
    n = 2000
    for key in ("tip", "estimate", "probe"):
        assert r[key].shape == (n, 3) and np.all(np.isfinite(r[key]))
    assert r["detected"].shape == (n,) and r["detected"].dtype == bool
    err_x = r["probe"][:, 0] - r["tip"][:, 0]
    assert np.max(np.abs(err_x)) < 2.0  # bounded, a few mm at most
    m = r["metrics"]
    assert m["rmse_pux"] < 0.05
    assert m["behind_fraction"] > 0.75  # probe behind the tip most of the time
    assert m["lead_lag_ratio"] < 0.3  # ahead / behind, Table 2's 0.07-0.18
    assert np.array_equal(r["detected"], err_x < 0)
    assert not r["stopped"] and not any(e["event"] == "safety_stop" for e in r["events"])


def test_seeded_reproducible():
    a = run_ye("prv", "dynamic", n_samples=300, seed=3)
    b = run_ye("prv", "dynamic", n_samples=300, seed=3)
    assert np.array_equal(a["estimate"], b["estimate"])


def test_prv_vx_better_than_pv(runs):
    for g in ("dynamic", "constant"):
        assert runs[("prv", g)]["metrics"]["rmse_vx"] < runs[("pv", g)]["metrics"]["rmse_vx"]


def test_dynamic_gain_pux_better_than_constant(runs):
    for f in ("pv", "prv"):
        assert (runs[(f, "dynamic")]["metrics"]["rmse_pux"]
                < runs[(f, "constant")]["metrics"]["rmse_pux"])


def test_gating_and_adaptive_run():
    r = run_ye("prv", "dynamic", n_samples=600, seed=1, gating=True, adaptive=True)
    assert np.all(np.isfinite(r["estimate"]))
    assert r["accepted"].sum() <= r["detected"].sum()
    assert r["metrics"]["rmse_pux"] < 0.05


def test_safety_stop_when_needle_lost():
    cfg = YeServoConfig(lost_timeout_s=0.5)
    r = run_ye("pv", "dynamic", n_samples=800, seed=0, config=cfg,
               fault=Fault("needle-lost", 400))
    stops = [e for e in r["events"] if e["event"] == "safety_stop"]
    assert len(stops) == 1 and r["stopped"]
    ev = stops[0]
    assert ev["reason"] == "needle_lost"
    assert 400 <= ev["frame"] <= 400 + int(0.5 * 25)  # lost for 0.5 s
    assert ev["lost_for_s"] >= 0.5
    assert not r["detected"][ev["frame"] - int(0.5 * 25):].any()
    assert not r["detected"][400:].any()
    x = r["probe"][:, 0]
    assert np.ptp(x[ev["frame"] + 25:]) < 1e-3  # the probe has come to rest
