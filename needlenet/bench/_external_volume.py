"""``needlenet bench external`` on a set of volume sequences (``needlenet/data/external_volume``
and ``needlenet/data/validation_volume``, PyMUST; generator in
``needlenet.bench.external.volume_generate``): the volume tracker with its defaults (what
``needlenet track FILE`` runs on a volume file: Zhao 2013's ROI-RK), with classical and with
learned features. Per sequence and pooled:

- tip error (mm, 3-D Euclidean) over the needle volumes reported ``tracking``: median and 95th
  percentile;
- ``tracked_fraction``: needle volumes (tip labelled and visible) reported ``tracking``;
- ``false_tracking_fraction``: needle-free volumes reported ``tracking``;
- ``score``: needle volumes tracked within 3 mm of the tip over needle volumes, less the false
  fraction (as the in-plane set's);
- ``failure_rate``: Zhao 2013's, over the needle volumes: no estimate, or a tip or axis error
  over 3 mm (:func:`needlenet.eval._volume_metrics.evaluate_volume`); None without a needle;
- ``covered_fraction``: tracked needle volumes whose tip lies inside the reported 95% region.

The sets are for testing and choosing only: nothing is trained or tuned on them.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

import synth

from ._external import (
    _fmt,
    _pct,
    frame_classes,
    pooled_metrics,
    table_rows,
    trace_and_metrics,
)

__all__ = ["markdown_volume_set", "run_volume_set", "volume_data_dir", "zhao_failures"]


def volume_data_dir(validation: bool = False) -> Path:
    """The committed volume test set (``needlenet/data/external_volume``), or its validation
    set (``needlenet/data/validation_volume``)."""
    name = "validation_volume" if validation else "external_volume"
    return Path(str(resources.files("needlenet").joinpath("data", name)))


def zhao_failures(est, seq: synth.Sequence) -> tuple[int, int]:
    """(failed, needle volumes) of one run by Zhao 2013's rule: a needle volume fails without
    an estimate or with a tip or axis error over 3 mm; (0, 0) without a needle."""
    from ..eval._volume_metrics import evaluate_volume

    needle, _ = frame_classes(seq)
    if not needle.any():
        return 0, 0
    ev = evaluate_volume(est, seq)
    return int(np.count_nonzero(ev.failure & needle)), int(needle.sum())


def _describe(seq: synth.Sequence) -> dict:
    m = seq.meta
    return {"probe": m.get("probe"), "needle": bool(m.get("needle", True)),
            "gauge": m.get("gauge"), "target_cr": m.get("target_cr"),
            "alpha_deg": m.get("alpha_deg"), "beta_deg": m.get("beta_deg"),
            "feature": m.get("feature"), "side": None, "angle_deg": None}


def _failure_rate(failed: int, volumes: int) -> float | None:
    return failed / volumes if volumes else None


def run_volume_set(seqs, seed: int, log, rows: list, model: str | None,
                   kinds: list[str]) -> dict:
    """Track every volume sequence with the default volume method and each feature kind of
    ``kinds``; one row per sequence and features, then one pooled row per features."""
    from ..trackers import make_tracker
    from ..trackers._registry import DEFAULT_METHODS

    method = DEFAULT_METHODS["volume"]
    log(f"  external (volume): {len(seqs)} sequences, "
        f"{sum(s.n_frames for _, s in seqs)} volumes"
        + (f", learned features from {model}" if model else ""))
    traces = {}
    for kind in kinds:
        per, failed, needle_volumes = [], 0, 0
        for i, (name, seq) in enumerate(seqs):
            tracker = make_tracker("volume", method, kind,
                                   model if kind == "learned" else None, seed=seed + i)
            est = tracker.run(seq)
            traces[(name, kind)], m = trace_and_metrics(est, seq)
            f, n = zhao_failures(est, seq)
            failed, needle_volumes = failed + f, needle_volumes + n
            per.append(m)
            lat = np.array([e.latency_ms for e in est], float)
            row = {"suite": "external", "tracker": "volume", "method": method,
                   "features": kind, "model": model if kind == "learned" else None,
                   "sequence": name, **_describe(seq), "frames": seq.n_frames,
                   "seed": seed + i, **{k: v for k, v in m.items() if k != "tip_errors_mm"},
                   "failure_rate": _failure_rate(f, n),
                   "latency_median_ms": float(np.median(lat))}
            rows.append(row)
            log(f"  external {name:22s} {kind:9s} median {_fmt(row['tip_error_median_mm'])} "
                f"p95 {_fmt(row['tip_error_p95_mm'])} mm, tracked "
                f"{_fmt(row['tracked_fraction'])}, false {_fmt(row['false_tracking_fraction'])}"
                f", failure {_fmt(row['failure_rate'])}, in 95% {_fmt(row['covered_fraction'])}")
        pm = pooled_metrics(per)
        row = {"suite": "external", "tracker": "volume", "method": method, "features": kind,
               "model": model if kind == "learned" else None, "sequence": "pooled",
               "probe": None, "needle": None, "gauge": None, "target_cr": None,
               "alpha_deg": None, "beta_deg": None, "feature": None, "side": None,
               "angle_deg": None, "frames": int(sum(s.n_frames for _, s in seqs)),
               "seed": seed, **{k: v for k, v in pm.items() if k != "tip_errors_mm"},
               "failure_rate": _failure_rate(failed, needle_volumes)}
        rows.append(row)
        log(f"  external {'pooled':22s} {kind:9s} median {_fmt(row['tip_error_median_mm'])} "
            f"p95 {_fmt(row['tip_error_p95_mm'])} mm, tracked {_fmt(row['tracked_fraction'])}"
            f", false {_fmt(row['false_tracking_fraction'])}, score {_fmt(row['score'], 3)}"
            f", in 95% {_fmt(row['covered_fraction'])}")
    return {"rows": rows, "traces": traces}


def markdown_volume_set(result: dict, machine: dict) -> str:
    method = next((r["method"] for r in result["rows"]), "roi-rk")
    lines = [f"Machine: {machine['cpu']}, {machine['cores']} cores", "",
             f"The default volume tracker ({method}, Zhao 2013), as `needlenet track` runs it. "
             "Tip error (3-D) over needle volumes reported `tracking`; tracked: needle volumes "
             "reported `tracking`; false: needle-free volumes reported `tracking`; score: "
             "needle volumes tracked within 3 mm of the tip over needle volumes, less the false "
             "fraction; failure: Zhao's (no estimate, or tip or axis error over 3 mm) over "
             "needle volumes; in 95%: tracked needle volumes whose tip lies inside the reported "
             "95% region.", "",
             "| sequence | probe | needle | features | median (mm) | 95th (mm) | tracked | "
             "false | score | failure | in 95% |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    lines += table_rows(result["rows"], lambda r: f"{r['gauge']} G, CR {r['target_cr']:g}",
                        lambda r: f"{_fmt(r.get('score'), 3)} | {_pct(r.get('failure_rate'))} | "
                                  f"{_pct(r.get('covered_fraction'))}")
    return "\n".join(lines)
