"""Evaluation: the papers' metrics, one code path for ``needlenet track`` and the benchmarks."""

from __future__ import annotations

import numpy as np

from ._auc import roc_auc
from ._coverage import tip_coverage
from ._inplane_metrics import inplane_errors, inplane_metrics, insertion_angle_deg

__all__ = ["evaluate", "latency_summary", "inplane_metrics", "inplane_errors",
           "insertion_angle_deg", "roc_auc", "tip_coverage"]


def latency_summary(estimates) -> dict:
    lat = np.array([e.latency_ms for e in estimates], float)
    if lat.size == 0:
        return {}
    return {"latency_median_ms": float(np.median(lat)),
            "latency_p99_ms": float(np.percentile(lat, 99)),
            "frames_per_s": float(1000.0 / max(lat.mean(), 1e-9))}


def evaluate(modality: str, estimates, seq) -> dict:
    """The paper's metrics for a tracked sequence with labels (Table III for ``inplane``,
    Zhao's for ``volume``, Carriere's for ``axial``), ``tip_in_95_fraction`` (the tracked frames
    whose labelled tip lies inside the reported 95% region: 0.95 when the reported covariance
    is honest; :func:`tip_coverage`) and latency."""
    if modality == "inplane":
        out = inplane_metrics(estimates, seq)
    elif modality == "volume":
        from ._volume_metrics import evaluate_volume

        ev = evaluate_volume(estimates, seq)
        summary = dict(ev.summary)
        per = {k: np.asarray(getattr(ev, k)).tolist() for k in
               ("tip_error", "axis_error", "alpha_error_deg", "beta_error_deg")}
        out = {"summary": summary, "per_frame": per}
    elif modality == "axial":
        from ._axial_metrics import axial_metrics

        out = axial_metrics(estimates, seq)
    else:
        raise ValueError(f"unknown modality {modality!r}")
    summary = out.setdefault("summary", {})
    summary["tip_in_95_fraction"] = tip_coverage(estimates, seq)
    summary.update(latency_summary(estimates))
    return out
