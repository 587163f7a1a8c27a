"""``needlenet bench external`` on a set of axial sequences (``needlenet/data/external_axial``,
PyMUST; generator in ``needlenet.bench.external.axial_generate``): Carriere 2016's axial
tracker with its defaults (what ``needlenet track FILE`` runs on an axial file), with
classical and with learned features. Per sequence and pooled:

- centre error (mm, in the slice): the tracked cross-section centre against the labelled
  crossing of the needle axis with the slice (the axial ``tip_mm`` label), over the needle
  slices reported ``tracking``: median and 95th percentile (keys ``tip_error_*``, as the
  in-plane rows);
- ``tracked_fraction``: needle slices reported ``tracking``;
- ``false_tracking_fraction``: needle-free slices (past the tip, or a sequence without a
  needle) reported ``tracking``;
- tip prediction (Carriere 2016, section V): the bicycle model fitted to the slices up to
  ``PREDICT_AHEAD_MM`` before the last needle slice predicts the crossing in that slice;
  ``tip_prediction_error_mm`` is |u - u_hat| in the tracker's plane and
  ``tip_prediction_absolute_mm`` the distance to the labelled crossing
  (:func:`needlenet.eval._axial_metrics.axial_errors`). None when the tracker had no model by then.

The set is for testing only: nothing is trained or tuned on it.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

import synth

from ._external import _fmt, _pct, frame_classes, pooled_metrics, table_rows, trace_and_metrics

__all__ = ["PREDICT_AHEAD_MM", "axial_data_dir", "markdown_axial", "run_axial_set",
           "tip_prediction"]

PREDICT_AHEAD_MM = 5.0


def axial_data_dir() -> Path:
    """The committed axial set (``needlenet/data/external_axial``)."""
    return Path(str(resources.files("needlenet").joinpath("data", "external_axial")))


def tip_prediction(est, seq: synth.Sequence, needle: np.ndarray) -> dict:
    """The tip prediction errors of one run (see the module docstring); None where the
    sequence has no needle or the tracker had no model ``PREDICT_AHEAD_MM`` before the last
    needle slice."""
    from ..eval._axial_metrics import axial_errors

    none = {"tip_prediction_error_mm": None, "tip_prediction_absolute_mm": None}
    if not needle.any() or seq.probe_pose is None:
        return none
    last = int(np.flatnonzero(needle)[-1])
    pose = np.asarray(seq.probe_pose, float)
    depth_last = float(pose[last, :3, 3] @ pose[last, :3, 1])
    m = axial_errors(est, seq, prediction_depth_mm=depth_last - PREDICT_AHEAD_MM)
    if m.prediction_frame < 0 or not np.isfinite(m.tip_error_mm):
        return none
    return {"tip_prediction_error_mm": float(m.tip_error_mm),
            "tip_prediction_absolute_mm": float(m.tip_error_absolute_mm)}


def _describe(seq: synth.Sequence) -> dict:
    m = seq.meta
    return {"probe": m.get("probe"), "needle": bool(m.get("needle", True)),
            "gauge": m.get("gauge"), "target_cr": m.get("target_cr"),
            "feature": m.get("feature"), "side": None, "angle_deg": None}


def run_axial_set(seqs, seed: int, log, rows: list, model: str | None,
                  kinds: list[str]) -> dict:
    """Track every axial sequence with each feature kind of ``kinds``; one row per sequence
    and features, then one pooled row per features."""
    from ..trackers import make_tracker

    log(f"  external (axial): {len(seqs)} sequences, {sum(s.n_frames for _, s in seqs)} slices"
        + (f", learned features from {model}" if model else ""))
    traces = {}
    for kind in kinds:
        per, preds, abs_preds = [], [], []
        for i, (name, seq) in enumerate(seqs):
            tracker = make_tracker("axial", "carriere", kind,
                                   model if kind == "learned" else None, seed=seed + i)
            est = tracker.run(seq)
            traces[(name, kind)], m = trace_and_metrics(est, seq)
            pred = tip_prediction(est, seq, frame_classes(seq)[0])
            per.append(m)
            if pred["tip_prediction_error_mm"] is not None:
                preds.append(pred["tip_prediction_error_mm"])
                abs_preds.append(pred["tip_prediction_absolute_mm"])
            lat = np.array([e.latency_ms for e in est], float)
            row = {"suite": "external", "tracker": "axial", "method": "carriere",
                   "features": kind, "model": model if kind == "learned" else None,
                   "sequence": name, **_describe(seq), "frames": seq.n_frames,
                   "seed": seed + i, **{k: v for k, v in m.items() if k != "tip_errors_mm"},
                   **pred, "latency_median_ms": float(np.median(lat))}
            rows.append(row)
            log(f"  external {name:22s} {kind:9s} centre median "
                f"{_fmt(row['tip_error_median_mm'])} p95 {_fmt(row['tip_error_p95_mm'])} mm, "
                f"tracked {_fmt(row['tracked_fraction'])}, false "
                f"{_fmt(row['false_tracking_fraction'])}, in 95% "
                f"{_fmt(row['covered_fraction'])}, tip prediction "
                f"{_fmt(pred['tip_prediction_error_mm'])} mm")
        pm = pooled_metrics(per)
        row = {"suite": "external", "tracker": "axial", "method": "carriere", "features": kind,
               "model": model if kind == "learned" else None, "sequence": "pooled",
               "probe": None, "needle": None, "gauge": None, "target_cr": None,
               "feature": None, "side": None, "angle_deg": None,
               "frames": int(sum(s.n_frames for _, s in seqs)), "seed": seed,
               **{k: v for k, v in pm.items() if k != "tip_errors_mm"},
               "tip_prediction_error_mm": float(np.median(preds)) if preds else None,
               "tip_prediction_absolute_mm": float(np.median(abs_preds)) if abs_preds else None,
               "tip_predictions": len(preds)}
        rows.append(row)
        log(f"  external {'pooled':22s} {kind:9s} centre median "
            f"{_fmt(row['tip_error_median_mm'])} p95 {_fmt(row['tip_error_p95_mm'])} mm, "
            f"tracked {_fmt(row['tracked_fraction'])}, false "
            f"{_fmt(row['false_tracking_fraction'])}, in 95% {_fmt(row['covered_fraction'])}")
    return {"rows": rows, "traces": traces}


def markdown_axial(result: dict, machine: dict) -> str:
    lines = [f"Machine: {machine['cpu']}, {machine['cores']} cores", "",
             "Carriere 2016's axial tracker with its defaults (no gauge given). Centre error: "
             "tracked cross-section centre vs the labelled crossing of the needle axis, over "
             "needle slices reported `tracking`; tracked: needle slices reported `tracking`; "
             "false: needle-free slices (past the tip, or no needle) reported `tracking`; tip "
             f"prediction: |u - û| of the crossing in the last needle slice predicted "
             f"{PREDICT_AHEAD_MM:g} mm before it (pooled: median over sequences); in 95%: "
             "tracked needle slices whose labelled centre lies inside the reported 95% region.",
             "", "| sequence | probe | needle | features | median (mm) | 95th (mm) | tracked | "
             "false | tip prediction (mm) | in 95% |", "|---|---|---|---|---|---|---|---|---|---|"]
    lines += table_rows(result["rows"], lambda r: f"{r['gauge']} G, CR {r['target_cr']:g}",
                        lambda r: f"{_fmt(r.get('tip_prediction_error_mm'))} | "
                                  f"{_pct(r.get('covered_fraction'))}")
    return "\n".join(lines)
