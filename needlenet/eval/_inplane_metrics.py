"""Mathiassen 2017 Table III: needle axis and tip errors of an in-plane tracker.

- e_theta = theta - theta_hat (degrees), theta the insertion angle of the axis to the skin
  (the image's lateral axis); |e_theta| its absolute value (the arccos error of [10]);
- ||e|| = ||p - p_hat|| (mm), the tip position error;
- e_n, the error along the estimated axis v_n (from the entry towards the tip): the true tip
  projected on v_n minus the estimated tip (negative: the needle is shorter than estimated);
- e_p, the error perpendicular to the estimated axis.
Each as mean +- sd with the 95th percentile (unsigned) or the 2.5th-97.5th percentiles (signed).
"""

from __future__ import annotations

import numpy as np

__all__ = ["insertion_angle_deg", "inplane_errors", "inplane_metrics", "describe_errors"]


def insertion_angle_deg(direction: np.ndarray) -> np.ndarray:
    """Angle (degrees) between the needle axis (x, z) and the skin (the lateral axis)."""
    d = np.asarray(direction, float)
    return np.degrees(np.arctan2(d[..., 1], np.abs(d[..., 0])))


def inplane_errors(tip_true, dir_true, tip_est, dir_est) -> dict[str, np.ndarray]:
    """Per-frame Table III errors for arrays of (x, z) tips and unit directions."""
    p, v = np.asarray(tip_true, float), np.asarray(dir_true, float)
    ph, vh = np.asarray(tip_est, float), np.asarray(dir_est, float)
    vh = vh / np.linalg.norm(vh, axis=-1, keepdims=True)
    nh = np.stack([-vh[..., 1], vh[..., 0]], axis=-1)  # the estimated axis' normal
    diff = p - ph
    e_theta = insertion_angle_deg(v) - insertion_angle_deg(vh)
    return {
        "e_theta_deg": e_theta,
        "abs_e_theta_deg": np.abs(e_theta),
        "norm_e_mm": np.linalg.norm(diff, axis=-1),
        "e_n_mm": np.einsum("...d,...d->...", diff, vh),
        "e_p_mm": np.einsum("...d,...d->...", diff, nh),
    }


def describe_errors(values: np.ndarray, signed: bool) -> dict:
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"n": 0}
    out = {"n": int(v.size), "mean": float(v.mean()),
           "sd": float(v.std(ddof=1)) if v.size > 1 else 0.0}
    if signed:
        out["p2_5"], out["p97_5"] = (float(x) for x in np.percentile(v, [2.5, 97.5]))
    else:
        out["p95"] = float(np.percentile(v, 95))
    return out


def inplane_metrics(estimates, seq) -> dict:
    """Table III over the frames where the tip is visible and the tracker reports a tip.

    Also: ``tip_error_p95_mm`` (the inplane suite's headline), the fraction of visible frames
    with no estimate (``missed_fraction``), and the per-frame errors.
    """
    T = seq.n_frames
    if len(estimates) != T:
        raise ValueError(f"{len(estimates)} estimates for {T} frames")
    if seq.tip_mm is None or seq.direction is None:
        raise ValueError("the sequence has no labels (tip_mm, direction)")
    has = np.array([e.tip_mm is not None and e.direction is not None and
                    e.status.value == "tracking" for e in estimates])
    vis = np.asarray(seq.visible, bool)
    use = has & vis
    nan2 = np.full(2, np.nan)
    tip_est = np.array([e.tip_mm if h else nan2 for e, h in zip(estimates, has, strict=True)])
    dir_est = np.array([e.direction if h else nan2 for e, h in zip(estimates, has, strict=True)])
    errs = inplane_errors(seq.tip_mm, seq.direction, tip_est, dir_est)
    summary = {k: describe_errors(v[use], signed=not k.startswith(("abs", "norm")))
               for k, v in errs.items()}
    norm = errs["norm_e_mm"][use]
    summary["tip_error_p95_mm"] = float(np.percentile(norm, 95)) if norm.size else float("nan")
    summary["tip_error_median_mm"] = float(np.median(norm)) if norm.size else float("nan")
    summary["frames"] = int(T)
    summary["frames_evaluated"] = int(use.sum())
    summary["missed_fraction"] = float((vis & ~has).sum() / max(vis.sum(), 1))
    summary["false_alarm_fraction"] = float((~vis & has).sum() / max((~vis).sum(), 1))
    return {"summary": summary, "per_frame": {k: v.tolist() for k, v in errs.items()},
            "evaluated": use.tolist()}
