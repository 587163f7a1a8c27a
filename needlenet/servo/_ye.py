"""Ye 2025: servoing a 2D transverse ultrasound probe on a needle tip (sections 2-4).

The needle tip P is estimated by the EKF of ``backends._ekf`` (PV or PRV state, Q and R of
eqs. (20)-(23)) from 25 Hz frames; between frames two controllers run 300 cycles each at
7500 Hz with the estimate held constant (section 4.1): a PI controller on the probe's X
velocity with reference K_e v_x_hat (eqs. (13)-(16)) and a PD controller on its Y position
with reference p_y_hat (eqs. (17)-(19)), each driving a mass-damper f = m a + b v (eq. (5)).
The plant and the controllers are in :mod:`._ye_control`; this module runs them in the loop
with the EKF and the measurement.

Time base of the mass-damper. Eqs. (15)-(16) and (18)-(19) write the acceleration as the
velocity difference over one control cycle, a(k) = v(k) - v(k-1), and advance the position by
v(k) per cycle (eq. (19)); that is, m = 150 and b = 20 are per-cycle constants and eq. (16) is
the implicit (backward) Euler step of eq. (5) with a step of one cycle. :class:`MassDamperAxis`
keeps that time base: its velocity is in mm per control cycle (``velocity_mm_s`` converts).
Since the PI loop is linear, running it in mm/cycle with the reference K_e v_x_hat / 7500 is
the same as running eq. (16) in mm/s. (Reading m, b in SI units with dt = 1/7500 s would give
a 7.5 s time constant, which cannot follow the tip at all; the paper's Table 2 errors of
~0.01 mm need the per-cycle reading.) ``integrator="exact"`` integrates eq. (5) exactly under
a force held over the cycle instead (steady state v = f / b either way).

The Y PD uses the derivative of the error as eq. (19) does: with the reference held,
e_y(k) - e_y(k-1) = -v_uy(k-1), so the reference jump at a new frame gives no derivative kick.

Measurement (section 4.2). The image plane is the yOz plane at the probe's X. The needle is
"detected" when the shaft crosses the plane, i.e. when the probe is behind the tip
(p_ux < p_x). Then z(k) is 3D: z_x is the probe's X (from the arm's encoder; "the measurement
of the tip in the X direction ... is taken directly from the position of the ultrasound
probe"), and z_y, z_z are the needle point seen in the image plus noise uniform on +-2 mm. We
use the true tip's Y and Z for the image point, as the paper's "ideal detected values" (the
shaft's crossing point differs from them by about (p_x - p_ux) tan(theta) ~ 0.01 mm, far below
the noise). When not detected the EKF only predicts (the paper says z_x at such a sample
"copies the value at the previous sample"; a held measurement would pull the estimate back, so
we skip the update instead).

Images (``measure``; see ``_images``). A detector that sees through an elevation beam of
finite thickness cannot tell, from one frame, a plane just ahead of the tip (the shaft still
inside the beam) from one far behind it (the shaft alone): both show a needle echo without the
tip's. Near the tip the echo is brighter, which the detector's calibrated threshold uses to
report "detected" only while the plane is behind the tip; the remaining case
(``Measurement.shaft_seen``) is resolved with the EKF's prediction: the plane is behind the
tip when the predicted p_x lies more than ``behind_margin_mm`` ahead of the probe. Then K_e
counts the frame as detected (eq. (13): the plane lags the tip, speed up), but the EKF gets no
update: z_x = p_ux is a lower bound there, not a measurement. Ye's control laws (eqs.
(13)-(19)) are unchanged; only the binary input of eq. (13) is formed from images.

Lead-lag ratio (Table 2). The paper's values (0.07-0.18) come with "all methods allow the
ultrasound probe to be located behind the tip most of the time", so the ratio is
(frames with the probe ahead of the tip) / (frames with it behind); small is mostly behind.
``behind_fraction`` is the fraction of frames with the probe behind.

Safety (section 5 asks for it; not in the paper's simulation): per-cycle velocity and
acceleration limits on each probe axis (the PI stops integrating while limited); K_e bounded
by ``max_gain`` (eq. (13) grows 1.01**t2 without end while the needle is seen); and watchdogs
that latch a stop (the X reference becomes 0 and Y holds its position; logged in ``events``,
never raised):

- a stale measurement is no measurement: a frame the feed repeats (the image identical to the
  previous one) or a detection identical to the previous one to the last bit (a detector
  stuck at a stale position; a live image's detection moves with its speckle);
- ``needle_lost`` / ``never_found``: no needle seen in the image (detected, or for images a
  shaft seen) for ``lost_timeout_s``, after having seen one or from the start;
  ``stale_feed`` / ``stuck_detector``: the same, every one of those frames a repeated frame
  or a repeated detection;
- ``unconfirmed_travel``: the probe has moved ``max_unconfirmed_travel_mm`` since the last
  fresh detection (the image loops' innovation gate rejects a detection inconsistent with
  the prediction from the EKF's update, but the probe may follow the needle through a
  stretch of rejections: up to 6.7 mm in nominal image runs).

Faults (:class:`Fault`) replace the measurement from a frame on, to exercise each watchdog.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from ..backends import (
    AdaptiveNoise,
    ExtendedKalmanFilter,
    YeEKFParams,
    chi2_gate,
    ye_prv_model,
    ye_pv_model,
)
from ._faults import Fault
from ._ye_control import MassDamperAxis, PositionPD, SpeedGain, VelocityPI

__all__ = [
    "YE_TABLE2",
    "Measurement",
    "YeServoConfig",
    "run_ye",
    "table2",
    "ye_insertion_velocity",
    "ye_tip_path",
]

# Table 2 of Ye 2025 (average over 100 repetitions), keyed like :func:`table2`.
YE_TABLE2 = {
    "dynamic-prv": {"rmse_P": 0.1803, "rmse_vx": 0.0076, "rmse_pux": 0.0113,
                    "rmse_puy": 0.1225, "lead_lag_ratio": 0.176},
    "constant-prv": {"rmse_P": 0.1858, "rmse_vx": 0.0075, "rmse_pux": 0.0266,
                     "rmse_puy": 0.1227, "lead_lag_ratio": 0.101},
    "dynamic-pv": {"rmse_P": 0.1898, "rmse_vx": 0.0247, "rmse_pux": 0.0122,
                   "rmse_puy": 0.1337, "lead_lag_ratio": 0.073},
    "constant-pv": {"rmse_P": 0.1950, "rmse_vx": 0.0277, "rmse_pux": 0.0353,
                    "rmse_puy": 0.1357, "lead_lag_ratio": 0.097},
}


def ye_insertion_velocity(n: int, fs_hz: float = 25.0, perturb_mm_s: float = 0.025,
                          perturb_period_s: float = 20.0) -> np.ndarray:
    """Section 4.1's v_in (mm/s) per sample; the same profile as ``synth``'s."""
    k = np.arange(int(n))
    v = np.where(k < 100, 2.0 * k / 100.0, 2.0)
    v = np.where((k >= 500) & (k < 1500), 3.0, v)
    return v + perturb_mm_s * np.sin(2 * np.pi * k / fs_hz / perturb_period_s)


def ye_tip_path(v_in: np.ndarray, fs_hz: float = 25.0, radius_mm: float = 400.0,
                bend_direction=(0.0, 1.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """Tip position and velocity per sample for the feed speeds ``v_in``.

    The tip starts at the origin along +X and bends on a circle of ``radius_mm`` towards
    ``bend_direction`` (orthogonalised against X), like ``synth``'s ServoScenario; the arc
    length is the trapezoidal integral of v_in. Returns (P (n, 3) mm, V (n, 3) mm/s), with
    ||V|| = v_in (eq. (3)).
    """
    v_in = np.asarray(v_in, dtype=float)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v_in[1:] + v_in[:-1]) / fs_hz)])
    ex = np.array([1.0, 0.0, 0.0])
    eb = np.asarray(bend_direction, dtype=float) - np.dot(bend_direction, ex) * ex
    eb = eb / np.linalg.norm(eb)
    th = s / radius_mm
    P = radius_mm * (np.sin(th)[:, None] * ex + (1.0 - np.cos(th))[:, None] * eb)
    V = v_in[:, None] * (np.cos(th)[:, None] * ex + np.sin(th)[:, None] * eb)
    return P, V


# --------------------------------------------------------------------------- simulation


class Measurement(NamedTuple):
    """One frame's measurement for :func:`run_ye`: whether the needle was detected, z (3,)
    in world mm (z_x from the probe's position, section 4.2), the scanner's imaging time
    spent to get it (excluded from the loop's own latency) and ``shaft_seen``: not detected,
    but a needle echo too weak for the plane to be at the tip was seen (see
    ``YeServoConfig.behind_margin_mm``)."""

    detected: bool
    z: np.ndarray | None = None
    imaging_s: float = 0.0
    shaft_seen: bool = False
    stale: bool = False  # the feed repeated its last frame: no measurement at all


@dataclass(frozen=True)
class YeServoConfig:
    """Section 4.1's simulation, plus our safety settings (limits None: off).

    Ye's per-cycle loops settle within ~30 cycles (~4 ms), so unlimited the Y axis jumps to
    each new reference p_y_hat at up to ~150 mm/s and ~1e6 mm/s^2 for a fraction of a
    millisecond. The default limits (50 mm/s, 1e4 mm/s^2 ~ 1 g) clip those first cycles of a
    frame but leave the frame-rate results of the nominal run unchanged to about 4 decimals;
    an arm-like 20 mm/s, 2000 mm/s^2 raises the p_uy RMSE by a few per cent.
    """

    frame_rate_hz: float = 25.0
    steps_per_frame: int = 300  # 7500 Hz
    m: float = 150.0
    b: float = 20.0
    kp1: float = 100.0
    ki: float = 20.0
    kp2: float = 30.0
    kd: float = 50.0
    integrator: str = "implicit"
    radius_mm: float = 400.0
    bend_direction: tuple[float, float, float] = (0.0, 1.0, 1.0)
    noise_mm: float = 2.0  # uniform +- on z_y, z_z
    v_limit_mm_s: float | None = 50.0
    a_limit_mm_s2: float | None = 1e4
    lost_timeout_s: float = 1.0
    # K_e's ceiling: eq. (13) reaches 1.23 at most over Table 2's 20 nominal runs; a detector
    # that never lets go had driven it to 1e6 and the probe to the velocity limit
    max_gain: float = 1.5
    # the probe's travel in X-Y since the last fresh detection that stops the loop (nominal
    # runs, ideal and imaged: at most 0.31 mm, the plane passing the tip and waiting for it)
    max_unconfirmed_travel_mm: float = 1.5
    gate_probability: float = 0.997
    adaptive_window: int = 50
    # adaptive R never below this fraction of the smallest initial R (AdaptiveNoise's floor);
    # image measurements raise it to the detector's resolution (a pixel), or the gate locks
    # out a detector's small systematic offset once R has shrunk to nothing
    adaptive_floor_fraction: float = 1e-3
    p0_diag: tuple[float, ...] = (1e-2, 1e-2, 1e-2, 1e-4, 1e-4)
    ekf: YeEKFParams = YeEKFParams()
    probe_z_mm: float = 0.0  # the probe's fixed Z (world); Ye moves it in X and Y only
    # images only (Measurement.shaft_seen): a needle echo with the tip's echo gone is the
    # shaft either just ahead of the tip (inside the elevation beam) or far behind it; it
    # counts as detected for K_e when the EKF's predicted tip is this far ahead of the plane.
    # Below the slice's half-width (the synth scanner's -6 dB elevation half-width is
    # 0.54-0.68 mm over the servo world's depths), so the gain speeds the probe up before the
    # tip leaves the slice: with 0.75 mm the probe fell 0.9 mm behind and the tip was in the
    # slice in 76-88% of frames; with 0.3 mm in 96-100% (learned, 2 seeds, 2000 frames)
    behind_margin_mm: float = 0.3


def run_ye(filter: str = "pv", gain: str = "dynamic", n_samples: int = 2000, seed: int = 0,
           gating: bool = False, adaptive: bool = False, *,
           config: YeServoConfig | None = None, fault: Fault | None = None,
           measure: Callable[[int, np.ndarray], Measurement] | None = None) -> dict:
    """Simulate Ye 2025's tracking; returns per-frame arrays, Table 2 metrics and events.

    ``measure(k, probe_xyz)``: the measurement of frame k with the probe at ``probe_xyz``
    (world, mm), a :class:`Measurement`; ``None`` is section 4.2's ideal noisy measurement.
    ``fault``: a :class:`Fault` injected into that measurement. Arrays: ``tip`` (n, 3),
    ``tip_velocity`` (n, 3), ``estimate`` (n, 3) and ``vx_hat`` (n,), the EKF's posterior at
    each frame; ``probe`` (n, 3) at each frame; ``detected``, ``accepted``, ``stale`` (n,)
    bool; ``K_e`` (n,); ``v_in`` (n,); ``latency_ms`` (n,), the wall time of each cycle
    (measurement, EKF, control) without the scanner's imaging time, and ``imaging_ms`` (n,),
    that imaging time. A safety stop's event holds its ``reason``, ``frame`` and ``time_s``,
    and with a fault ``since_fault_s`` and ``travel_since_fault_mm`` (X-Y).
    """
    cfg = YeServoConfig() if config is None else config
    if filter not in ("pv", "prv"):
        raise ValueError(f"filter must be 'pv' or 'prv', got {filter!r}")
    n = int(n_samples)
    rng = np.random.default_rng(seed)
    fs = cfg.frame_rate_hz
    dt_c = 1.0 / (fs * cfg.steps_per_frame)
    params = replace(cfg.ekf, dt_s=1.0 / fs)
    model = ye_pv_model(params) if filter == "pv" else ye_prv_model(params)
    ekf = ExtendedKalmanFilter.from_model(
        model, np.zeros(5), np.diag(cfg.p0_diag),
        gate_sigmas=chi2_gate(3, cfg.gate_probability) if gating else None,
        adaptive=AdaptiveNoise(window=cfg.adaptive_window,
                               floor_fraction=cfg.adaptive_floor_fraction)
        if adaptive else None)

    v_in = ye_insertion_velocity(n, fs)
    tip, tip_v = ye_tip_path(v_in, fs, cfg.radius_mm, cfg.bend_direction)
    noise = rng.uniform(-cfg.noise_mm, cfg.noise_mm, size=(n, 2))

    vl = None if cfg.v_limit_mm_s is None else cfg.v_limit_mm_s * dt_c
    al = None if cfg.a_limit_mm_s2 is None else cfg.a_limit_mm_s2 * dt_c * dt_c
    ax_x = MassDamperAxis(cfg.m, cfg.b, integrator=cfg.integrator, dt_s=dt_c)
    ax_y = MassDamperAxis(cfg.m, cfg.b, integrator=cfg.integrator, dt_s=dt_c)
    pi = VelocityPI(ax_x, cfg.kp1, cfg.ki, cfg.steps_per_frame, vl, al)
    pd = PositionPD(ax_y, cfg.kp2, cfg.kd, cfg.steps_per_frame, vl, al)
    ke = SpeedGain(gain, cfg.max_gain)
    lost_limit = max(int(math.ceil(cfg.lost_timeout_s * fs - 1e-9)), 1)

    if measure is None:
        def measure(k: int, probe_xyz: np.ndarray) -> Measurement:
            # section 4.2: detected iff the plane is behind the tip
            return Measurement(bool(probe_xyz[0] < tip[k, 0]), np.array(
                [probe_xyz[0], tip[k, 1] + noise[k, 0], tip[k, 2] + noise[k, 1]]))
    if fault is not None:
        fault = fault.at(n // 2)
        measure = fault.wrap(measure)

    est = np.empty((n, 3))
    vx_hat = np.empty(n)
    probe = np.zeros((n, 3))
    detected = np.zeros(n, bool)
    accepted = np.zeros(n, bool)
    stale = np.zeros(n, bool)
    K_e = np.empty(n)
    events: list[dict] = []
    stopped = False
    y_hold = 0.0
    latency = np.zeros(n)
    imaging = np.zeros(n)
    unseen = 0  # consecutive frames without any needle in the image
    stale_run = 0  # consecutive stale frames
    stuck_run = 0  # consecutive frames whose detection repeats the last one
    found = False  # a needle has been detected
    last_yz = None  # the last detection's (z_y, z_z)
    confirmed_at = np.zeros(2)  # the probe's X-Y at the last fresh detection
    for k in range(n):
        t_cycle = time.perf_counter()
        probe[k, 0], probe[k, 1], probe[k, 2] = ax_x.p, ax_y.p, cfg.probe_z_mm
        m = measure(k, probe[k].copy())
        imaging[k] = m.imaging_s * 1e3
        z = None if m.z is None else np.asarray(m.z, float)
        repeat = z is not None and last_yz is not None and np.array_equal(z[1:], last_yz)
        if z is not None and m.detected:
            last_yz = z[1:].copy()
        stale[k] = m.stale or (m.detected and repeat)
        stuck_run = stuck_run + 1 if (m.detected and repeat and not m.stale) else 0
        det = bool(m.detected) and not stale[k]
        shaft = bool(m.shaft_seen) and not stale[k]
        if k > 0:
            ekf.predict(v_in[k - 1])
        if not det and shaft and ekf.x[0] - ax_x.p > cfg.behind_margin_mm:
            # the shaft crosses a plane well behind the predicted tip: detected for eq. (13),
            # but z_x = probe X would drag the estimate back, so no update
            det, z = True, None
        detected[k] = det
        if det and z is not None:
            accepted[k] = ekf.update(z).accepted
        if det:
            confirmed_at = probe[k, :2].copy()
        found = found or det
        est[k] = ekf.x[:3]
        vx_hat[k] = model.velocity(ekf.x, v_in[k])[0]
        K_e[k] = ke.update(det)
        # lost: no needle in the image at all (a shaft seen with the plane at the tip is the
        # loop working, not a loss)
        unseen = 0 if (det or shaft) else unseen + 1
        stale_run = stale_run + 1 if stale[k] else 0
        if not stopped:
            reason = None
            if unseen >= lost_limit:
                if stale_run >= unseen:
                    reason = "stuck_detector" if stuck_run >= unseen else "stale_feed"
                else:
                    reason = "needle_lost" if found else "never_found"
            elif np.linalg.norm(probe[k, :2] - confirmed_at) > cfg.max_unconfirmed_travel_mm:
                reason = "unconfirmed_travel"
            if reason is not None:
                stopped, y_hold = True, ax_y.p
                ev = {"event": "safety_stop", "reason": reason, "frame": k, "time_s": k / fs,
                      "lost_for_s": unseen / fs}
                if fault is not None:
                    ev["fault"] = fault.kind
                    ev["since_fault_s"] = (k - fault.start) / fs
                    ev["travel_since_fault_mm"] = float(
                        np.linalg.norm(probe[k, :2] - probe[fault.start, :2]))
                events.append(ev)
        if stopped:
            pi.run(0.0)
            pd.run(y_hold)
        else:
            pi.run(K_e[k] * vx_hat[k] * dt_c)
            pd.run(est[k, 1])
        latency[k] = (time.perf_counter() - t_cycle) * 1e3 - imaging[k]
    if pi.n_limited or pd.n_limited:
        events.append({"event": "limits_active", "frames_x": pi.n_limited,
                       "frames_y": pd.n_limited})

    ahead = probe[:, 0] > tip[:, 0]
    behind = probe[:, 0] < tip[:, 0]
    metrics = {
        "rmse_P": float(np.sqrt(np.mean(np.sum((est - tip) ** 2, axis=1)))),
        "rmse_vx": float(np.sqrt(np.mean((vx_hat - tip_v[:, 0]) ** 2))),
        "rmse_pux": float(np.sqrt(np.mean((probe[:, 0] - tip[:, 0]) ** 2))),
        "rmse_puy": float(np.sqrt(np.mean((probe[:, 1] - tip[:, 1]) ** 2))),
        "lead_lag_ratio": float(ahead.sum() / max(behind.sum(), 1)),
        "behind_fraction": float(behind.mean()),
    }
    return {"tip": tip, "tip_velocity": tip_v, "estimate": est, "vx_hat": vx_hat,
            "probe": probe, "detected": detected, "accepted": accepted, "stale": stale,
            "K_e": K_e,
            "v_in": v_in, "metrics": metrics, "events": events, "stopped": stopped,
            "filter": filter, "gain": gain, "seed": seed, "latency_ms": latency,
            "imaging_ms": imaging}


def table2(repeats: int = 100, n_samples: int = 2000, seed: int = 0, gating: bool = False,
           adaptive: bool = False, config: YeServoConfig | None = None) -> dict:
    """Table 2: metrics averaged over ``repeats`` seeded runs (seeds seed .. seed+repeats-1)
    for dynamic/constant gain x PRV/PV, keyed "dynamic-prv", "constant-prv", "dynamic-pv",
    "constant-pv" like :data:`YE_TABLE2`."""
    out = {}
    for filt in ("prv", "pv"):
        for gain in ("dynamic", "constant"):
            runs = [run_ye(filt, gain, n_samples, seed + i, gating, adaptive, config=config)
                    ["metrics"] for i in range(int(repeats))]
            out[f"{gain}-{filt}"] = {key: float(np.mean([r[key] for r in runs]))
                                     for key in runs[0]}
    return {k: out[k] for k in YE_TABLE2}
