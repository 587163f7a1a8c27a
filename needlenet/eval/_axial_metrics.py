"""Carriere 2016's metrics for axial tracking and needle shape prediction.

* Cross-section tracking error per frame: the distance (mm) between the tracked centre and the
  labelled crossing of the shaft with the slice (``seq.tip_mm``), on frames where the needle
  is visible and the tracker reports ``tracking``.
* Tip prediction error (section V): TipError = |u - u_hat| at the final depth, where u_hat is
  the shape predicted from the data up to the rotation depth D (the estimate of the last
  frame at or before D) and u the true deflection in the tracker's (u, v) plane.
* Shape error, eq. (8): the integral of |u - u_hat| dv (mm^2) from the origin of the (u, v)
  plane to the final depth, by the trapezoidal rule over the labelled slices.
* Timing as Table II: image processing, particle filter update and total, ms/frame, mean
  and sd.

The true deflection u of a slice is the labelled crossing, relative to the labelled crossing
at the depth of the tracker's origin, projected on the tracker's u axis: the prediction is
judged on the shape it predicts, not on the constant offset between the tracked centre of the
echo and the shaft's axis (that is the tracking error). ``tip_error_transverse_mm`` adds the
part normal to the tracker's plane (a wrong phi), and ``tip_error_absolute_mm`` is the
distance between the predicted and the labelled crossing in the final slice with no offset
removed. The plane's origin and axis, reported in the probe frame of the predicting frame,
are carried to every slice by the probe poses (exact for slices translated along their
elevation axis, as in the axial scenario).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from synth import invert_rigid

from ..backends import shape_error, tip_error
from ..trackers import AxialDetails, NeedleEstimate, Status

__all__ = ["AxialMetrics", "axial_errors", "axial_metrics", "eq8_shape_error"]


def eq8_shape_error(v_mm, u_mm, u_hat_mm) -> float:
    """Carriere 2016, eq. (8): integral of |u - u_hat| dv (mm^2), trapezoidal rule over the
    depths ``v_mm`` (sorted first; NaN samples dropped)."""
    v = np.asarray(v_mm, dtype=float)
    u = np.asarray(u_mm, dtype=float)
    u_hat = np.asarray(u_hat_mm, dtype=float)
    keep = np.isfinite(v) & np.isfinite(u) & np.isfinite(u_hat)
    order = np.argsort(v[keep], kind="stable")
    if order.size < 2:
        return float("nan")
    return shape_error(v[keep][order], u[keep][order], u_hat[keep][order])  # eq. (8)


@dataclass
class AxialMetrics:
    """Per-frame errors and the summary of Tables I and II (mm, mm^2, ms)."""

    tracking_error_mm: np.ndarray  # (T,), NaN where not tracked or not visible
    depth_mm: np.ndarray  # (T,) slice depths reported by the tracker
    u_true_mm: np.ndarray  # (T,) true deflection in the tracker's (u, v) plane
    u_pred_mm: np.ndarray  # (T,) the predicted deflection at each slice's depth
    prediction_frame: int  # the frame whose prediction is judged (-1: none)
    final_frame: int  # the deepest labelled frame (-1: none)
    tip_error_mm: float  # |u - u_hat| at the final depth (Carriere 2016, section V)
    tip_error_transverse_mm: float  # adds the out-of-plane part
    tip_error_absolute_mm: float  # predicted vs labelled crossing, no offset removed
    shape_error_mm2: float  # eq. (8)
    detection_rate: float  # visible frames reported as tracking
    false_tracking_rate: float  # invisible frames reported as tracking
    latency_ms: np.ndarray  # (T,)
    image_ms: np.ndarray  # (T,)
    filter_ms: np.ndarray  # (T,)

    def summary(self) -> dict:
        """Table I (tip and shape errors), the tracking error and Table II (ms/frame, mean
        and sd), flat and JSON-ready."""

        def mean_sd(a):
            a = a[np.isfinite(a)]
            return (float(a.mean()), float(a.std())) if a.size else (np.nan, np.nan)

        e = self.tracking_error_mm[np.isfinite(self.tracking_error_mm)]
        out = {
            "tracking_error_mean_mm": float(e.mean()) if e.size else np.nan,
            "tracking_error_sd_mm": float(e.std()) if e.size else np.nan,
            "tracking_error_median_mm": float(np.median(e)) if e.size else np.nan,
            "tracking_error_max_mm": float(e.max()) if e.size else np.nan,
            "tip_error_mm": self.tip_error_mm,
            "tip_prediction_error_mm": self.tip_error_mm,  # the axial suite's headline key
            "tip_error_transverse_mm": self.tip_error_transverse_mm,
            "tip_error_absolute_mm": self.tip_error_absolute_mm,
            "shape_error_mm2": self.shape_error_mm2,
            "detection_rate": self.detection_rate,
            "false_tracking_rate": self.false_tracking_rate,
            "prediction_frame": self.prediction_frame,
            "final_frame": self.final_frame,
            "frames": int(self.depth_mm.size),
            "frames_evaluated": int(e.size),
        }
        for name, a in (("image", self.image_ms), ("filter", self.filter_ms),
                        ("total", self.latency_ms)):
            out[f"{name}_ms_mean"], out[f"{name}_ms_sd"] = mean_sd(a)
        return out


def _poses(seq, T: int) -> np.ndarray:
    if seq.probe_pose is None:
        return np.repeat(np.eye(4)[None], T, axis=0)
    return np.asarray(seq.probe_pose, dtype=float)


def _map_xz(xz, src_pose, dst_pose, vector: bool = False) -> np.ndarray:
    """(x, z) in the probe frame ``src_pose`` (a point on its slice, or a vector) to the probe
    frame ``dst_pose``."""
    M = invert_rigid(dst_pose) @ src_pose
    q = M[:3, :3] @ np.array([xz[0], 0.0, xz[1]])
    if not vector:
        q = q + M[:3, 3]
    return q[[0, 2]]


def axial_metrics(estimates: list[NeedleEstimate], seq,
                  prediction_depth_mm: float | None = None) -> dict:
    """Carriere 2016's metrics as ``{"summary": ..., "per_frame": ...}`` (the form of
    :func:`needlenet.eval.evaluate`): :meth:`AxialMetrics.summary` and the per-frame
    tracking error, depth and true and predicted deflections. See :func:`axial_errors`."""
    m = axial_errors(estimates, seq, prediction_depth_mm)

    def jsonable(a):
        return [None if not np.isfinite(x) else float(x) for x in a]

    return {"summary": m.summary(),
            "per_frame": {"tracking_error_mm": jsonable(m.tracking_error_mm),
                          "depth_mm": jsonable(m.depth_mm),
                          "u_true_mm": jsonable(m.u_true_mm),
                          "u_pred_mm": jsonable(m.u_pred_mm)}}


def axial_errors(estimates: list[NeedleEstimate], seq,
                 prediction_depth_mm: float | None = None) -> AxialMetrics:
    """Carriere 2016's metrics of an :class:`~needlenet.trackers.AxialTracker` run.

    Parameters
    ----------
    estimates : one :class:`NeedleEstimate` per frame of ``seq``
    seq : synth.Sequence
        An axial sequence with labels (``tip_mm``, ``visible``, ``probe_pose``).
    prediction_depth_mm : float, optional
        The prediction judged is that of the last frame at or before this depth that has a
        model. Default: the rotation depth D the tracker reports (``details.model.
        rotation_depth_mm``), else the sequence's ``meta["params"]["rotation_depth_mm"]``,
        else the last frame with a model.
    """
    T = seq.n_frames
    if len(estimates) != T:
        raise ValueError(f"{len(estimates)} estimates for a sequence of {T} frames")
    truth = np.asarray(seq.tip_mm, dtype=float)
    visible = (np.asarray(seq.visible, dtype=bool) if seq.visible is not None
               else np.all(np.isfinite(truth), axis=1))
    visible &= np.all(np.isfinite(truth), axis=1)
    poses = _poses(seq, T)
    tracking = np.array([e.status == Status.TRACKING and e.tip_mm is not None
                         for e in estimates])
    err = np.full(T, np.nan)
    for k in np.flatnonzero(tracking & visible):
        err[k] = float(np.linalg.norm(np.asarray(estimates[k].tip_mm, float) - truth[k]))
    # a frame the tracker could not measure (a constant image) has no details
    details = [e.details if isinstance(e.details, AxialDetails) else None for e in estimates]
    depth = np.array([np.nan if d is None else float(d.depth_mm) for d in details])
    image_ms = np.array([np.nan if d is None else float(d.image_ms) for d in details])
    filter_ms = np.array([np.nan if d is None else float(d.filter_ms) for d in details])
    latency = np.array([float(e.latency_ms) for e in estimates])
    n_vis, n_inv = int(visible.sum()), int((~visible).sum())
    det = float((tracking & visible).sum() / n_vis) if n_vis else np.nan
    false = float((tracking & ~visible).sum() / n_inv) if n_inv else np.nan

    # the prediction made from the data up to D
    D = prediction_depth_mm
    if D is None:
        reported = [d.model.rotation_depth_mm for d in details
                    if d is not None and d.model.rotation_depth_mm is not None]
        params = seq.meta.get("params", {}) if isinstance(seq.meta, dict) else {}
        D = reported[-1] if reported else params.get("rotation_depth_mm")
    has_model = np.array([d is not None and d.model.shape_u_mm is not None for d in details])
    candidates = np.flatnonzero(has_model & (depth <= (np.inf if D is None else D) + 1e-9))
    u_true = np.full(T, np.nan)
    u_pred = np.full(T, np.nan)
    nan = float("nan")
    final = int(np.flatnonzero(visible)[-1]) if n_vis else -1
    if candidates.size == 0 or final < 0:
        return AxialMetrics(err, depth, u_true, u_pred, -1, final, nan, nan, nan, nan, det,
                            false, latency, image_ms, filter_ms)
    j = int(candidates[-1])
    model = details[j].model
    origin_j = np.asarray(model.origin_xz_mm, dtype=float)
    axis_j = np.asarray(model.u_axis_xz, dtype=float)
    shape_v = np.asarray(model.shape_v_mm, dtype=float)
    shape_u = np.asarray(model.shape_u_mm, dtype=float)
    origin_depth = float(model.origin_depth_mm)

    # labelled crossing at the origin's depth (interpolated between labelled slices)
    lab = np.flatnonzero(visible & np.isfinite(depth))
    order = lab[np.argsort(depth[lab], kind="stable")]
    truth_0 = np.array([np.interp(origin_depth, depth[order], truth[order, i]) for i in (0, 1)])
    k0 = order[int(np.argmin(np.abs(depth[order] - origin_depth)))]
    truth_0_pose = poses[k0]
    normal = np.array([-axis_j[1], axis_j[0]])
    w_true = np.full(T, np.nan)
    for k in lab:
        axis_k = _map_xz(axis_j, poses[j], poses[k], vector=True)
        normal_k = _map_xz(normal, poses[j], poses[k], vector=True)
        d = truth[k] - _map_xz(truth_0, truth_0_pose, poses[k])
        u_true[k], w_true[k] = d @ axis_k, d @ normal_k
        u_pred[k] = np.interp(depth[k], shape_v, shape_u, left=np.nan, right=np.nan)
    tip = tip_error(u_true[final], u_pred[final])  # section V: |u - u_hat|
    transverse = float(np.hypot(u_true[final] - u_pred[final], w_true[final]))
    pred_xz = (_map_xz(origin_j, poses[j], poses[final])
               + u_pred[final] * _map_xz(axis_j, poses[j], poses[final], vector=True))
    absolute = float(np.linalg.norm(pred_xz - truth[final]))
    inside = lab[depth[lab] >= origin_depth - 1e-9]
    shape = eq8_shape_error(depth[inside], u_true[inside], u_pred[inside])  # eq. (8)
    return AxialMetrics(err, depth, u_true, u_pred, j, final, float(tip), transverse, absolute,
                        shape, det, false, latency, image_ms, filter_ms)
