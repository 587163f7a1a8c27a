"""Chatelain 2013, section III: 3-DOF visual servoing of a 3D probe on the needle.

Features (eq. (23)): s = (X_tip, Z_tip, Theta), the tip's horizontal coordinates in the probe
frame and the angle between the needle's principal direction k0 and the probe's X axis;
desired s* = (X_C, Z_C, 0), the volume's centre and a null angle (eq. (24)); control law
v_c = -lambda L_s^+ e (eq. (25)) with v_c = (v_X, v_Z, omega_Y) and the interaction matrix of
eq. (27), L_s = [[-1, 0, -Z], [0, -1, X], [0, 0, 1]].

Frames. Chatelain's probe frame {X, Y, Z} has Y along the beams (depth, "the depth direction
with respect to the patient surface") and X, Z horizontal; ours (``synth``) has x lateral,
y elevation, z depth. With X = x and Y = z, a right-handed {X, Y, Z} needs Z = -y; omega_Y
is then the rotation about our z axis and Theta = atan2(k_Z, k_X) = atan2(-k_y, k_x). Eq. (27)
follows from the motion of a point fixed in the world seen from a probe moving with
(v, omega): dP/dt = -v - omega x P (:func:`interaction_matrix` is checked against finite
differences in the tests). Theta is an angle between axes, wrapped to (-90, 90] degrees (the
paper aligns the needle's axis with X; which way it points does not matter). Y (depth) is
Chatelain's force-controlled DOF; our probe keeps its depth.

Loop (one cycle per volume): the scanner images the world from the probe's current pose
(``MatrixProbe``, a Cartesian 3D probe, for speed), Chatelain's tracker (``VolumeTracker``
method ``"chatelain"``) estimates the needle with classical (intensity) or learned features,
the control law gives v_c, and the probe moves with it over the volume period (a robot
in velocity mode). The tracker's Kalman state lives in the probe frame; the probe's own motion
is known, so the state is carried into the new probe frame before the next volume (the paper
does not say how; without it the constant-velocity model would see the probe's motion as the
needle's).

Safety (section 5 of Ye asks for it; Chatelain is silent): per-axis velocity and acceleration
limits on v_c; a volume identical to the previous one (the feed repeating itself) is not given
to the tracker, and an estimate identical to the previous one to the last bit (a tracker stuck
at a stale position; a live volume's speckle moves every estimate) is no measurement; the
probe holds still until a needle is tracked; and a latched stop when the needle has not been
tracked for ``lost_timeout_s`` (``needle_lost``, or ``stale_feed`` / ``stuck_detector`` when
every one of those cycles was a repeat); it is logged in ``events``, never raised.

Runs: ``"misalignment"`` (Chatelain Fig. 5: insertion with the needle 40 degrees off the probe's
X axis, then the operator stops; the feature error at rest is the paper's 1.10 mm in X, 0.23 mm
in Z, 0.97 degrees) and ``"motion"`` (Fig. 6: the phantom moves during the insertion,
translations up to 4 cm peak to peak and rotations up to 20 degrees peak to peak, horizontal
and about the vertical: the DOF the servo controls).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..trackers import NeedleEstimate, Status
from ._faults import Fault

__all__ = ["ChatelainConfig", "chatelain_features", "control_velocity", "interaction_matrix",
           "move_probe", "run_chatelain", "CHATELAIN_REST"]

# Chatelain 2013, section IV-C: mean feature error at rest (X mm, Z mm, Theta degrees)
CHATELAIN_REST = {"x_mm": 1.10, "z_mm": 0.23, "theta_deg": 0.97}


def interaction_matrix(X: float, Z: float) -> np.ndarray:
    """Eq. (27): ds/dt = L_s v_c for s = (X, Z, Theta), v_c = (v_X, v_Z, omega_Y)."""
    return np.array([[-1.0, 0.0, -Z], [0.0, -1.0, X], [0.0, 0.0, 1.0]])


def _wrap_axis(theta: float) -> float:
    """An angle between axes, in (-pi/2, pi/2]."""
    return float((theta + 0.5 * np.pi) % np.pi - 0.5 * np.pi) if np.isfinite(theta) else theta


def chatelain_features(tip_mm, direction) -> np.ndarray:
    """Eq. (23) from a tip and a direction in our probe frame (x, y, z): (X, Z, Theta) with
    X = x, Z = -y, Theta = atan2(-k_y, k_x) wrapped to (-90, 90] degrees (radians here)."""
    tip = np.asarray(tip_mm, float)
    k = np.asarray(direction, float)
    return np.array([tip[0], -tip[1], _wrap_axis(math.atan2(-k[1], k[0]))])


def control_velocity(s: np.ndarray, s_star: np.ndarray, lam: float) -> np.ndarray:
    """Eq. (25): v_c = -lambda L_s^+ e, e = s - s* (eq. (24)), L_s of eq. (27) at s."""
    e = np.asarray(s, float) - np.asarray(s_star, float)
    e[2] = _wrap_axis(e[2])
    return -lam * np.linalg.pinv(interaction_matrix(s[0], s[1])) @ e


def move_probe(pose: np.ndarray, v_c: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The probe pose after moving for ``dt`` with v_c = (v_X, v_Z, omega_Y) in its own frame
    (our v = (v_X, -v_Z, 0), omega = (0, 0, omega_Y)); returns (new pose, D) with
    new pose = pose @ D (D: the motion in the old probe frame, exponential of the twist)."""
    vx, vy, w = float(v_c[0]), -float(v_c[1]), float(v_c[2])
    th = w * dt
    c, s = math.cos(th), math.sin(th)
    if abs(th) > 1e-9:  # SE(2) exponential in the horizontal plane
        a, b = s / th, (1.0 - c) / th
    else:
        a, b = 1.0, 0.0
    D = np.eye(4)
    D[:2, :2] = [[c, -s], [s, c]]
    D[0, 3] = (a * vx - b * vy) * dt
    D[1, 3] = (b * vx + a * vy) * dt
    return pose @ D, D


@dataclass(frozen=True)
class ChatelainConfig:
    """The 3D servo's settings. Volume: a Cartesian matrix probe of ``size``^3 voxels at
    ``spacing_mm`` (the volume model's 0.5 mm), ``depth_start_mm`` below the face."""

    size: int = 64
    spacing_mm: float = 0.5
    depth_start_mm: float = 12.0
    volume_rate_hz: float = 5.0
    lam: float = 0.8  # lambda of eq. (25), 1/s
    insertion_speed_mm_s: float = 3.0
    misalignment_deg: float = 40.0
    elevation_deg: float | None = None  # descent of the needle; None: the scenario's draw
    tip_offset_mm: tuple[float, float] = (3.0, -3.0)  # final tip's (x, y) from the centre
    rest_s: float = 4.0  # the operator stops; the error at rest is averaged over this
    settle_s: float = 1.0  # ... after this long
    motion_mm: float = 20.0  # phantom translation amplitude (4 cm peak to peak)
    motion_deg: float = 10.0  # phantom rotation amplitude about the vertical (20 deg p-p)
    motion_period_s: float = 10.0
    motion_start_s: float = 2.0
    v_limit_mm_s: float = 20.0
    w_limit_deg_s: float = 20.0
    a_limit_mm_s2: float = 40.0
    alpha_limit_deg_s2: float = 60.0
    lost_timeout_s: float = 1.0
    scatterers_per_cell: float = 10.0


def _move_tracker_frame(tracker, D: np.ndarray) -> None:
    """Carry the tracker's state into the probe frame after the probe moved by D (new = old @
    D), through its public ``move_frame`` (:meth:`VolumeTracker.move_frame`); a tracker
    without one (e.g. a test double that keeps no state) is left as it is."""
    move = getattr(tracker, "move_frame", None)
    if move is not None:
        move(D)


def _world(cfg: ChatelainConfig, run: str, seed: int):
    """The volume-motion scenario's tissue with a needle placed for the servo task."""
    from synth import MatrixProbe, NeedlePath, Scanner, World, scenario_params

    p = scenario_params("volume-motion", scatterers_per_cell=cfg.scatterers_per_cell)
    d = p.draw(np.random.default_rng(seed))
    base, _ = p.build(d)
    n, h = int(cfg.size), float(cfg.spacing_mm)
    probe = MatrixProbe(shape=(n, n, n), spacing_mm=(h, h, h), depth_start_mm=cfg.depth_start_mm)
    half = 0.5 * n * h
    zc = cfg.depth_start_mm + half
    az = math.radians(cfg.misalignment_deg if run == "misalignment"
                      else float(np.clip(d["azimuth_deg"], -40.0, 40.0)))
    el = math.radians(cfg.elevation_deg if cfg.elevation_deg is not None
                      else d["elevation_deg"])
    u = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    if d["side"] < 0:
        u[:2] *= -1.0  # inserted from the other side
    tip_end = np.array([cfg.tip_offset_mm[0], cfg.tip_offset_mm[1], zc])
    # the needle starts outside the volume: entry far back along u, tip 1 mm outside
    L_total = 3.0 * half / max(math.cos(el), 0.3) + 10.0
    entry = tip_end - L_total * u
    s = np.linspace(0.0, L_total, 2001)
    pts = entry + s[:, None] * u
    inside = np.all(np.abs(pts[:, :2]) < half, axis=1) & (pts[:, 2] > cfg.depth_start_mm) & (
        pts[:, 2] < cfg.depth_start_mm + 2 * half)
    s_in = float(s[np.argmax(inside)]) if inside.any() else 0.0
    path = NeedlePath(entry=entry, direction=u, max_length_mm=L_total + 1.0)
    world = World(base.world.tissue, path, base.world.needle, needle_in_tissue=True)
    scanner = Scanner(probe, base.params, world)
    centre = np.array([0.0, 0.0, zc])
    mdir = np.asarray(d["motion_dir"], float)
    mdir[2] = 0.0
    mdir = mdir / max(np.linalg.norm(mdir), 1e-9)
    return scanner, {"s_start": max(s_in - 1.0, 0.0), "s_end": L_total, "centre": centre,
                     "motion_dir": mdir, "motion_sign": 1.0 if d["motion_axis"][2] >= 0
                     else -1.0, "azimuth_deg": math.degrees(az),
                     "elevation_deg": math.degrees(el)}


def _tissue_pose(cfg: ChatelainConfig, geo: dict, t: float, run: str) -> np.ndarray:
    from synth import rigid_transform, rotation_matrix

    if run != "motion" or t <= cfg.motion_start_s:
        return np.eye(4)
    ph = math.sin(2 * math.pi * (t - cfg.motion_start_s) / cfg.motion_period_s)
    R = rotation_matrix([0.0, 0.0, 1.0], geo["motion_sign"] * math.radians(cfg.motion_deg) * ph)
    c = geo["centre"]
    return rigid_transform(R, cfg.motion_mm * ph * geo["motion_dir"] + c - R @ c)


def _limit(v: np.ndarray, v_prev: np.ndarray, vmax: np.ndarray, amax: np.ndarray,
           dt: float) -> tuple[np.ndarray, bool]:
    out = np.clip(v, v_prev - amax * dt, v_prev + amax * dt)
    out = np.clip(out, -vmax, vmax)
    return out, bool(np.any(np.abs(out - v) > 1e-12))


def run_chatelain(run: str = "misalignment", features: str = "classical", seed: int = 0, *,
                  config: ChatelainConfig | None = None, model=None, tracker=None,
                  fault: Fault | None = None, threads: int = 1) -> dict:
    """One closed-loop run of Chatelain's 3D visual servoing; returns per-cycle arrays,
    metrics and events. ``fault``: a :class:`~needlenet.servo.Fault` from a cycle on
    (``needle-lost``/``never-found``: the volumes hold no needle; ``frozen-feed``: the volume
    of the cycle before repeats; ``stuck-detector``: the tracker's last estimate repeats), to
    exercise the watchdogs; a stop's event then holds ``since_fault_s`` and
    ``travel_since_fault_mm``. Arrays (probe frame unless said): ``t``, ``s_true`` and
    ``s_hat`` (n, 3) features (X mm, Z mm, Theta rad), ``tip_true``, ``tip_hat`` (n, 3),
    ``probe`` (n, 3) the probe's position (world), ``probe_yaw_deg`` (n,), ``tip_world``
    (n, 3), ``tracking`` (n,) bool, ``in_volume`` (n,) bool, ``v_c`` (n, 3),
    ``latency_ms``, ``imaging_ms`` (n,)."""
    from synth import apply_transform, invert_rigid

    cfg = ChatelainConfig() if config is None else config
    if run not in ("misalignment", "motion"):
        raise ValueError(f"run must be 'misalignment' or 'motion', got {run!r}")
    if tracker is None:
        from ..trackers import make_tracker

        tracker = make_tracker("volume", "chatelain", features=features, model=model, rng=seed)
    t_setup = time.perf_counter()
    scanner, geo = _world(cfg, run, seed)
    setup_s = time.perf_counter() - t_setup
    dt = 1.0 / cfg.volume_rate_hz
    t_ins = (geo["s_end"] - geo["s_start"]) / cfg.insertion_speed_mm_s
    n = int(math.ceil((t_ins + cfg.rest_s) / dt)) + 1
    grid = scanner.probe.grid
    step = 0.5 * min(min(grid.spacing_mm), scanner.world.needle.radius_mm)
    rng = np.random.default_rng([seed, 11])
    s_star = np.array([0.0, 0.0, 0.0])  # eq. (24): X_C = Z_C = 0 is the volume's centre
    vmax = np.array([cfg.v_limit_mm_s, cfg.v_limit_mm_s, math.radians(cfg.w_limit_deg_s)])
    amax = np.array([cfg.a_limit_mm_s2, cfg.a_limit_mm_s2, math.radians(cfg.alpha_limit_deg_s2)])
    lost_limit = max(int(math.ceil(cfg.lost_timeout_s * cfg.volume_rate_hz - 1e-9)), 1)
    if fault is not None:
        fault = fault.at(int(0.5 * t_ins / dt))
    start = None if fault is None else fault.start

    from ..features import Frame

    out = {k: np.full((n, 3), np.nan) for k in ("s_true", "s_hat", "tip_true", "tip_hat",
                                                "probe", "tip_world", "v_c")}
    t_arr = np.arange(n) * dt
    tracking = np.zeros(n, bool)
    in_volume = np.zeros(n, bool)
    yaw = np.zeros(n)
    latency = np.zeros(n)
    imaging = np.zeros(n)
    events: list[dict] = []
    pose = np.eye(4)
    v_prev = np.zeros(3)
    misses = 0
    repeats = 0  # consecutive cycles whose volume or estimate repeated the previous one
    stuck = 0  # ... whose estimate did
    previous_img = None
    last_est = None
    ever_tracked = False
    stopped = False
    n_limited = 0
    for k in range(n):
        t = t_arr[k]
        c0 = time.perf_counter()
        s_tip = min(geo["s_start"] + cfg.insertion_speed_mm_s * t, geo["s_end"])
        tp = _tissue_pose(cfg, geo, t, run)
        inv = invert_rigid(pose)
        pts_w, tan_w, _ = scanner.world.needle_world(s_tip, tp, step)
        faulty = start is not None and k >= start
        if faulty and fault.kind in ("needle-lost", "never-found"):
            pts_w, tan_w = pts_w[:0], tan_w[:0]
        pts = apply_transform(inv, pts_w)
        if faulty and fault.kind == "frozen-feed" and previous_img is not None:
            img = previous_img
        else:
            img = scanner.render(inv @ tp, pts, tan_w @ inv[:3, :3].T, rng, step).image
        c1 = time.perf_counter()
        imaging[k] = (c1 - c0) * 1e3
        frozen = previous_img is not None and np.array_equal(img, previous_img)
        previous_img = img
        if frozen:  # the feed repeats itself: nothing new to measure
            est = NeedleEstimate(t=float(t), status=Status.LOST)
        elif faulty and fault.kind == "stuck-detector" and last_est is not None:
            est = last_est
        else:
            est = tracker.update(Frame(img, grid, t=float(t), index=k, probe_pose=pose))
        repeated = (not frozen and last_est is not None and est.tip_mm is not None
                    and est.status.value == "tracking"
                    and np.array_equal(est.tip_mm, last_est.tip_mm))
        if est.status.value == "tracking" and est.tip_mm is not None:
            last_est = est
        # truth: tip and direction in the probe frame
        tip_w = scanner.world.needle_path.point_at(s_tip)
        tip_w = apply_transform(scanner.world.needle_to_world(tp), tip_w[None])[0]
        u_w = tp[:3, :3] @ scanner.world.needle_path.direction
        tip_p = apply_transform(inv, tip_w[None])[0]
        out["tip_world"][k] = tip_w
        out["tip_true"][k] = tip_p
        out["s_true"][k] = chatelain_features(tip_p, inv[:3, :3] @ u_w)
        out["probe"][k] = pose[:3, 3]
        yaw[k] = math.degrees(math.atan2(pose[1, 0], pose[0, 0]))
        in_volume[k] = bool(grid.contains(tip_p[None])[0]) and not (
            faulty and fault.kind in ("needle-lost", "never-found"))
        ok = est.status.value == "tracking" and est.tip_mm is not None and not repeated
        tracking[k] = ok
        repeats = repeats + 1 if (frozen or repeated) else 0
        stuck = stuck + 1 if repeated else 0
        if ok:
            ever_tracked = True
            misses = 0
            out["tip_hat"][k] = est.tip_mm
            s = chatelain_features(est.tip_mm, est.direction)
            out["s_hat"][k] = s
            v = control_velocity(s, s_star, cfg.lam)  # eq. (25)
        else:
            misses += ever_tracked
            v = np.zeros(3)  # nothing seen: slow down to rest (within the limits)
        if not stopped and ever_tracked and misses >= lost_limit:
            stopped = True
            reason = "needle_lost" if repeats < misses else (
                "stuck_detector" if stuck >= misses else "stale_feed")
            ev = {"event": "safety_stop", "reason": reason, "cycle": k, "time_s": float(t),
                  "lost_for_s": misses * dt}
            if start is not None:
                ev.update(fault=fault.kind, since_fault_s=float(t - t_arr[start]),
                          travel_since_fault_mm=float(np.linalg.norm(
                              pose[:3, 3] - out["probe"][start])))
            events.append(ev)
        if stopped:
            v = np.zeros(3)
        v, limited = _limit(v, v_prev, vmax, amax, dt)
        n_limited += limited
        out["v_c"][k] = v
        v_prev = v
        pose, D = move_probe(pose, v, dt)
        _move_tracker_frame(tracker, D)
        latency[k] = (time.perf_counter() - c1) * 1e3
    if n_limited:
        events.append({"event": "limits_active", "cycles": int(n_limited)})

    rest = t_arr >= t_ins + cfg.settle_s
    metrics = _metrics(out, tracking, in_volume, rest)
    return {"t": t_arr, **out, "probe_yaw_deg": yaw, "tracking": tracking,
            "in_volume": in_volume, "latency_ms": latency, "imaging_ms": imaging,
            "events": events, "stopped": stopped, "metrics": metrics, "run": run,
            "features": features, "seed": seed, "setup_s": setup_s, "geometry": geo,
            "insertion_end_s": t_ins}


def _metrics(out: dict, tracking: np.ndarray, in_volume: np.ndarray, rest: np.ndarray) -> dict:
    def mean_abs(a):
        a = a[np.isfinite(a)]
        return float(np.mean(np.abs(a))) if a.size else float("nan")

    sh, st = out["s_hat"], out["s_true"]
    r = rest & tracking
    e_hat = sh - np.array([0.0, 0.0, 0.0])
    e_true = st.copy()
    e_true[:, 2] = np.vectorize(_wrap_axis)(e_true[:, 2])
    err = out["tip_hat"] - out["tip_true"]
    ok = np.all(np.isfinite(err), axis=1)
    return {
        "rest_err_x_mm": mean_abs(e_hat[r, 0]), "rest_err_z_mm": mean_abs(e_hat[r, 1]),
        "rest_err_theta_deg": math.degrees(mean_abs(e_hat[r, 2])),
        "rest_true_err_x_mm": mean_abs(e_true[rest, 0]),
        "rest_true_err_z_mm": mean_abs(e_true[rest, 1]),
        "rest_true_err_theta_deg": math.degrees(mean_abs(e_true[rest, 2])),
        "initial_theta_deg": math.degrees(float(st[0, 2])),
        "rmse_p_mm": float(np.sqrt(np.mean(np.sum(err[ok] ** 2, axis=1)))) if ok.any()
        else float("nan"),
        "in_plane_fraction": float(np.mean(in_volume)),
        "tracked_fraction": float(np.mean(tracking)),
    }
