"""Zhao 2013's accuracy metrics for needle localisation and tracking in 3D volumes.

Zhao 2013, "Results" and Fig. 2b: with ``N_in`` the true insertion point, ``N_tip`` the true
tip, ``Q1`` and ``Q2`` their orthogonal projections on the estimated axis and ``Q'`` the
estimated tip,

* the tip accuracy is the error between ``Q'`` and ``N_tip`` on x, y and z separately (and
  here also its Euclidean norm ``|N_tip Q'|``);
* the axis accuracy is ``eps_axis = max(|N_in Q1|, |N_tip Q2|)``, the larger of the two true
  end points' distances to the estimated axis line;
* the angles alpha and beta of eq. (4) are compared with the true ones;
* a localisation fails when the tip error or the axis error exceeds 3 mm;
* errors are summarised by their mean (eq. (7)) and standard deviation with ``n - 1``
  (eq. (8)).

A frame counts when the needle is visible in it (``seq.visible``); a visible frame without a
tip estimate (searching, lost) is a failure. Statistics of the errors are over the visible
frames that have an estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..backends import direction_to_angles
from ..trackers import VolumeDetails

if TYPE_CHECKING:  # pragma: no cover
    from synth import Sequence

    from ..trackers import NeedleEstimate

__all__ = ["FAILURE_MM", "VolumeEvaluation", "axis_accuracy", "distance_to_line",
           "evaluate_volume"]

FAILURE_MM = 3.0  # Zhao 2013: "a Euclidean distance larger than 3 mm ... is considered to fail"


def distance_to_line(points, line_point, direction) -> np.ndarray:
    """Distance of points (..., 3) to the lines through ``line_point`` along ``direction``
    (both broadcastable to (..., 3)); the direction need not be unit length."""
    p = np.asarray(points, float)
    a = np.asarray(line_point, float)
    u = np.asarray(direction, float)
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    d = p - a
    along = np.sum(d * u, axis=-1, keepdims=True)
    return np.linalg.norm(d - along * u, axis=-1)


def axis_accuracy(entry, tip, line_point, direction) -> np.ndarray:
    """``eps_axis = max(|N_in Q1|, |N_tip Q2|)`` (Zhao 2013, Fig. 2b).

    ``entry`` and ``tip`` are the true insertion point and tip (..., 3), ``line_point`` and
    ``direction`` the estimated axis.
    """
    return np.maximum(distance_to_line(entry, line_point, direction),
                      distance_to_line(tip, line_point, direction))


def _wrap_deg(angle: np.ndarray) -> np.ndarray:
    """Angles in degrees wrapped to (-180, 180]."""
    return 180.0 - np.mod(180.0 - angle, 360.0)


@dataclass(frozen=True)
class VolumeEvaluation:
    """Per-frame errors (NaN where there is no estimate) and their summary.

    Attributes
    ----------
    tip_error_xyz : (T, 3)
        Estimated minus true tip on x, y, z (mm, signed).
    tip_error : (T,)
        Euclidean tip error ``|N_tip Q'|`` (mm).
    axis_error : (T,)
        eps_axis (mm).
    alpha_error_deg, beta_error_deg : (T,)
        Estimated minus true angle of eq. (4), degrees (alpha wrapped to (-180, 180]).
    visible : (T,) bool
        Frames that are evaluated (the needle is in the volume).
    estimated : (T,) bool
        Frames with a tip estimate.
    failure : (T,) bool
        Visible frames whose tip or axis error exceeds ``failure_mm``, or without estimate.
    ransac_trials, latency_ms : (T,)
        From the estimates (``details.ransac_trials``, NaN without details).
    summary : dict
        See :func:`evaluate_volume`.
    """

    tip_error_xyz: np.ndarray
    tip_error: np.ndarray
    axis_error: np.ndarray
    alpha_error_deg: np.ndarray
    beta_error_deg: np.ndarray
    visible: np.ndarray
    estimated: np.ndarray
    failure: np.ndarray
    ransac_trials: np.ndarray
    latency_ms: np.ndarray
    summary: dict


def _mean_std(values: np.ndarray) -> tuple[float, float]:
    """Mean (eq. (7)) and standard deviation with n - 1 (eq. (8)) of the finite values."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan
    std = float(np.std(v, ddof=1)) if v.size > 1 else math.nan
    return float(np.mean(v)), std


def _median(values: np.ndarray) -> float:
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else math.nan


def evaluate_volume(estimates: list[NeedleEstimate], seq: Sequence,
                    failure_mm: float = FAILURE_MM) -> VolumeEvaluation:
    """Zhao 2013's metrics of a tracker's estimates on a labelled volume sequence.

    Parameters
    ----------
    estimates : list of NeedleEstimate
        One per frame of ``seq``, as :meth:`Tracker.run` returns them. The estimated axis is
        the line through ``axis_point_mm`` (or the tip) along ``direction``.
    seq : synth.Sequence
        Needs the labels ``tip_mm``, ``entry_mm``, ``direction`` and ``visible``.
    failure_mm : float
        Failure threshold on the tip and axis errors (Zhao: 3 mm).

    Returns
    -------
    VolumeEvaluation
        ``summary`` holds: ``n_frames``, ``n_visible``, ``n_estimated``; for the tip on each
        axis ``tip_error_{x,y,z}_mean`` and ``_std`` (eqs. (7)-(8), signed); for the
        Euclidean tip error, eps_axis, alpha and beta errors ``*_mean``, ``*_std`` and
        ``*_median``; ``failure_rate`` (failures over visible frames); ``false_detections``
        (frames without a visible needle reported ``tracking``); ``ransac_trials_mean``;
        ``latency_ms_mean``, ``first_latency_ms`` (initialisation included) and
        ``volumes_per_s`` (1000 over the mean latency).
    """
    if seq.tip_mm is None or seq.entry_mm is None or seq.direction is None:
        raise ValueError("seq has no labels (tip_mm, entry_mm, direction)")
    n = seq.n_frames
    if len(estimates) != n:
        raise ValueError(f"got {len(estimates)} estimates for a sequence of {n} frames")
    if not (np.isfinite(failure_mm) and failure_mm > 0):
        raise ValueError(f"failure_mm must be finite and > 0, got {failure_mm}")
    tip_true = np.asarray(seq.tip_mm, float)
    entry_true = np.asarray(seq.entry_mm, float)
    dir_true = np.asarray(seq.direction, float)
    visible = (np.ones(n, bool) if seq.visible is None
               else np.asarray(seq.visible, bool).reshape(n))

    tip_est = np.full((n, 3), np.nan)
    point_est = np.full((n, 3), np.nan)
    dir_est = np.full((n, 3), np.nan)
    trials = np.full(n, np.nan)
    latency = np.array([float(e.latency_ms) for e in estimates])
    tracking = np.array([getattr(e.status, "value", e.status) == "tracking" for e in estimates])
    for i, e in enumerate(estimates):  # one estimate per frame: a loop over frames
        if isinstance(e.details, VolumeDetails):
            trials[i] = float(e.details.ransac_trials)
        if e.tip_mm is None or e.direction is None:
            continue
        tip_est[i] = np.asarray(e.tip_mm, float)
        dir_est[i] = np.asarray(e.direction, float)
        point_est[i] = np.asarray(e.tip_mm if e.axis_point_mm is None else e.axis_point_mm,
                                  float)
    estimated = np.all(np.isfinite(tip_est), axis=1) & np.all(np.isfinite(dir_est), axis=1)
    estimated &= np.linalg.norm(np.nan_to_num(dir_est), axis=1) > 0

    err_xyz = tip_est - tip_true
    tip_err = np.linalg.norm(err_xyz, axis=1)
    axis_err = np.full(n, np.nan)
    alpha_err = np.full(n, np.nan)
    beta_err = np.full(n, np.nan)
    if estimated.any():
        axis_err[estimated] = axis_accuracy(entry_true[estimated], tip_true[estimated],
                                            point_est[estimated], dir_est[estimated])
        b_est, a_est = direction_to_angles(dir_est[estimated])  # eq. (4)
        b_true, a_true = direction_to_angles(dir_true[estimated])
        alpha_err[estimated] = _wrap_deg(np.degrees(a_est - a_true))
        beta_err[estimated] = np.degrees(b_est - b_true)
    with np.errstate(invalid="ignore"):
        bad = ~((tip_err <= failure_mm) & (axis_err <= failure_mm))  # NaN (no estimate) fails
    failure = visible & bad

    scored = visible & estimated
    summary: dict = {"n_frames": n, "n_visible": int(visible.sum()),
                     "n_estimated": int(scored.sum())}
    for k, name in enumerate("xyz"):
        mean, std = _mean_std(err_xyz[scored, k])
        summary[f"tip_error_{name}_mean"], summary[f"tip_error_{name}_std"] = mean, std
    for name, values in (("tip_error", tip_err), ("axis_error", axis_err),
                         ("alpha_error_deg", alpha_err), ("beta_error_deg", beta_err)):
        mean, std = _mean_std(values[scored])
        summary[f"{name}_mean"], summary[f"{name}_std"] = mean, std
        summary[f"{name}_median"] = _median(values[scored])
    summary["failure_rate"] = (float(failure.sum() / visible.sum()) if visible.any()
                               else math.nan)
    summary["false_detections"] = int(np.sum(~visible & tracking))
    summary["ransac_trials_mean"] = _mean_std(trials)[0]
    mean_latency = float(np.mean(latency)) if n else math.nan
    summary["latency_ms_mean"] = mean_latency
    summary["first_latency_ms"] = float(latency[0]) if n else math.nan
    summary["volumes_per_s"] = 1e3 / mean_latency if mean_latency > 0 else math.nan
    return VolumeEvaluation(err_xyz, tip_err, axis_err, alpha_err, beta_err, visible, estimated,
                            failure, trials, latency, summary)
