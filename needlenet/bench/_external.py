"""``needlenet bench external``: the default in-plane tracker on sequences that synth did not
make (PyMUST, ``needlenet/data/external``; generator in ``needlenet.bench.external``).

What a user gets from ``needlenet track FILE``: the default in-plane method with no insertion
angle and no gauge given, with classical and with learned features. Per sequence and pooled:

- tip error (mm, Euclidean) over the needle frames the tracker reports ``tracking``: median
  and 95th percentile;
- ``tracked_fraction``: needle frames reported ``tracking`` over needle frames;
- ``false_tracking_fraction``: needle-free frames reported ``tracking`` over needle-free frames;
- ``wrong_fraction``: needle frames reported ``tracking`` with the tip more than 3 mm off, over
  needle frames (a confident wrong answer, worse than none);
- ``covered_fraction``: of the needle frames reported ``tracking`` with a tip covariance, those
  whose labelled tip lies inside the reported 95% region (Mahalanobis distance within the
  chi-square 95% point of the tip's dimension): 95% when the reported uncertainty is honest,
  less when it is overconfident.

A needle frame has the needle visible (label ``visible``: the tip in the image with at least
3 mm of shaft in view); a needle-free frame has no needle in it at all (tip label NaN). The set
is for testing only: nothing is trained or tuned on it. A set of axial sequence files (``--data
needlenet/data/external_axial``) runs the axial tracker instead (:mod:`._external_axial`), a set
of volume files (``--data needlenet/data/external_volume``) the volume tracker
(:mod:`._external_volume`).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

import synth

from ..eval._coverage import region_coverage, reported_tips
from ..io import RecordingError, load_recording

__all__ = ["data_dir", "external_sequences", "frame_classes", "frame_records", "markdown",
           "run", "sequence_metrics", "pooled_metrics", "trace_and_metrics"]

QUICK_SEQUENCES = ("lin_left_top_30", "ph_interface_no_needle")


def data_dir() -> Path:
    """The committed set (``needlenet/data/external``)."""
    return Path(str(resources.files("needlenet").joinpath("data", "external")))


LABELLED_SUFFIXES = (".npz", ".mha", ".mhd")  # sequence files, PLUS sequence metafiles


def labelled_files(directory: str | Path) -> list[Path]:
    """The labelled recordings of a set: needlenet's sequence files and PLUS sequence
    metafiles (whose ``NeedleTipToReference`` transforms are the labels), sorted by name."""
    d = Path(directory)
    return sorted(f for f in d.iterdir() if f.suffix.lower() in LABELLED_SUFFIXES and
                  f.is_file())


def external_sequences(directory: str | Path | None = None,
                       names: tuple[str, ...] | None = None) -> list[tuple[str, synth.Sequence]]:
    """(name, sequence) of every labelled recording in ``directory`` (default: the committed
    set; :func:`labelled_files`), sorted by name; ``names`` keeps those only. A PLUS file
    without needle labels is refused: its frames would count as needle-free."""
    d = Path(directory) if directory is not None else data_dir()
    files = labelled_files(d)
    if not files:
        raise FileNotFoundError(f"no labelled recordings ({', '.join(LABELLED_SUFFIXES)}) in {d}")
    if names is not None:
        files = [f for f in files if _name(f) in names]
    out = []
    for f in files:
        # read as ``needlenet track`` reads a recording (marks drawn over a live one filled in)
        seq = load_recording(f)
        if f.suffix.lower() != ".npz" and seq.tip_mm is None:
            raise RecordingError(
                f"{f}: no NeedleTipToReference transforms, so no needle labels to measure "
                "against (a needle-free recording: save it as a sequence file with meta needle "
                "false)")
        out.append((_name(f), seq))
    return out


def _name(f: Path) -> str:
    """A recording's name in the tables: its file name without ``.npz``, ``.seq.mha`` or
    ``.mha``."""
    name = f.name[:-len(f.suffix)]
    return name[:-4] if name.lower().endswith(".seq") else name


def frame_classes(seq: synth.Sequence) -> tuple[np.ndarray, np.ndarray]:
    """Boolean (T,) masks: needle frames (labelled visible) and needle-free frames (no needle
    in the frame: no tip label, or a sequence whose meta says ``needle: false``)."""
    T = seq.n_frames
    if seq.tip_mm is None or seq.meta.get("needle") is False:
        return np.zeros(T, bool), np.ones(T, bool)
    tip = np.asarray(seq.tip_mm, float)
    absent = ~np.all(np.isfinite(tip), axis=1)
    vis = np.zeros(T, bool) if seq.visible is None else np.asarray(seq.visible, bool)
    return vis & ~absent, absent


def sequence_metrics(tracking: np.ndarray, tip_est: np.ndarray, tip_true: np.ndarray,
                     needle: np.ndarray, free: np.ndarray,
                     tip_cov: np.ndarray | None = None) -> dict:
    """The suite's metrics of one sequence from per-frame arrays.

    ``tracking`` (T,) bool: the tracker reported ``tracking``; ``tip_est`` and ``tip_true``
    (T, D) mm (NaN where none); ``needle`` and ``free`` (T,) bool from :func:`frame_classes`;
    ``tip_cov`` (T, D, D) mm^2, the reported tip covariances (NaN where none). Returns the
    counts and the per-frame tip errors as well, so sequences can be pooled.
    """
    tracking = np.asarray(tracking, bool)
    needle, free = np.asarray(needle, bool), np.asarray(free, bool)
    tip_est = np.asarray(tip_est, float)
    tip_true = np.asarray(tip_true, float)
    # a needle frame counts as tracked when the tracker says so and gives a tip
    scored = needle & tracking & np.all(np.isfinite(tip_est), axis=1)
    err = np.linalg.norm(tip_est[scored] - tip_true[scored], axis=1)
    n_cov = n_covered = 0
    if tip_cov is not None:
        n_cov, n_covered = region_coverage(tip_est[scored] - tip_true[scored],
                                           np.asarray(tip_cov, float)[scored])
    return _summary(err, int(needle.sum()), int(scored.sum()), int(free.sum()),
                    int((free & tracking).sum()), n_covered, n_cov)


def estimate_metrics(est: list, seq: synth.Sequence) -> tuple[np.ndarray, np.ndarray, dict]:
    """A tracker's estimates on ``seq``: which frames it reported `tracking`, its tips (NaN
    where none) and :func:`sequence_metrics` against the labels."""
    needle, free = frame_classes(seq)
    tracking = np.array([e.status.value == "tracking" for e in est])
    nd = seq.ndim  # points (x, z) in 2D frames, (x, y, z) in volumes
    tip_est, tip_cov = reported_tips(est, nd)
    tip_true = np.full((seq.n_frames, nd), np.nan) if seq.tip_mm is None \
        else np.asarray(seq.tip_mm, float)
    return tracking, tip_est, sequence_metrics(tracking, tip_est, tip_true, needle, free,
                                               tip_cov)


FRAME_FIELDS = ("sequence", "features", "frame", "class", "status", "tip_error_mm", "reason")


def frame_records(est: list, seq: synth.Sequence, tip_est: np.ndarray) -> list[dict]:
    """One record per frame of a tracked sequence (the report's ``frames.csv``, without the
    sequence and features): its class (``needle``, ``needle-free``, or ``-``: a needle not
    visible enough to count either way), the reported status, the tip error (mm, when a tip
    was reported on a labelled frame) and the tracker's reason for a frame without one."""
    needle, free = frame_classes(seq)
    tip_true = None if seq.tip_mm is None else np.asarray(seq.tip_mm, float)
    out = []
    for i, e in enumerate(est):
        err = None
        if tip_true is not None and np.all(np.isfinite(tip_true[i])) and \
                np.all(np.isfinite(tip_est[i])):
            err = round(float(np.linalg.norm(tip_est[i] - tip_true[i])), 3)
        out.append({"frame": i, "class": "needle" if needle[i] else
                    ("needle-free" if free[i] else "-"), "status": e.status.value,
                    "tip_error_mm": err, "reason": e.reason or ""})
    return out


def trace_and_metrics(est: list, seq: synth.Sequence) -> tuple[dict, dict]:
    """A tracked sequence's trace (which frames were reported ``tracking``, the tips, the
    :func:`frame_records`) and its :func:`estimate_metrics`."""
    tracking, tip_est, m = estimate_metrics(est, seq)
    return {"tracking": tracking, "tip_est": tip_est,
            "frames": frame_records(est, seq, tip_est)}, m


def pooled_metrics(per_sequence: list[dict]) -> dict:
    """The metrics over all frames of several sequences (errors and counts pooled)."""
    err = np.concatenate([np.asarray(m["tip_errors_mm"], float) for m in per_sequence]) \
        if per_sequence else np.zeros(0)
    return _summary(err, *(int(sum(m[k] for m in per_sequence)) for k in
                           ("needle_frames", "tracked_frames", "needle_free_frames",
                            "false_tracking_frames", "covered_frames", "covariance_frames")))


# the model-choice score (docs/notes/inplane.md): the share of needle frames tracked within
# GOOD_MM of the labelled tip (the 95th-percentile target) less the share of
# needle-free frames reported tracking
GOOD_MM = 3.0


def _summary(err, n_needle, n_tracked, n_free, n_false, n_covered=0, n_cov=0) -> dict:
    n_good = int(np.count_nonzero(err <= GOOD_MM))
    n_wrong = int(np.count_nonzero(err > GOOD_MM))
    score = None
    if n_needle or n_free:
        score = (n_good / n_needle if n_needle else 0.0) - (n_false / n_free if n_free else 0.0)
    return {
        "score": score, "within_3mm_frames": n_good,
        "tip_error_median_mm": float(np.median(err)) if err.size else None,
        "tip_error_p95_mm": float(np.percentile(err, 95)) if err.size else None,
        "tracked_fraction": n_tracked / n_needle if n_needle else None,
        "false_tracking_fraction": n_false / n_free if n_free else None,
        "wrong_fraction": n_wrong / n_needle if n_needle else None, "wrong_frames": n_wrong,
        "needle_frames": n_needle, "tracked_frames": n_tracked,
        "needle_free_frames": n_free, "false_tracking_frames": n_false,
        "covered_fraction": n_covered / n_cov if n_cov else None,
        "covered_frames": n_covered, "covariance_frames": n_cov,
        "tip_errors_mm": err.tolist(),
    }


def _track(seq: synth.Sequence, kind: str, seed: int, model: str | None = None):
    from ..trackers import _registry

    method = getattr(_registry, "DEFAULT_METHODS", {"inplane": "kf+f"})["inplane"]
    tracker = _registry.make_tracker("inplane", method, kind,
                                     model if kind == "learned" else None, seed=seed)
    return method, tracker.run(seq)


def _describe(seq: synth.Sequence) -> dict:
    m = seq.meta
    return {"probe": m.get("probe"), "needle": bool(m.get("needle", True)),
            "side": m.get("side"), "angle_deg": m.get("angle_deg"),
            "feature": m.get("feature")}


def run(quick: bool = False, seed: int = 0, log=print, rows=None, tier=None,
        directory: str | Path | None = None, model: str | Path | None = None,
        features: tuple[str, ...] = ("classical", "learned")) -> dict:
    """Track every sequence of the set with classical and learned features; one row per
    sequence and features, then one pooled row per features. ``directory``: another set of
    labelled recordings (every ``.npz`` sequence file and PLUS ``.mha``/``.mhd`` in it, all
    of them even with ``quick``), all in-plane, all axial or all volume; ``model``: the
    learned features' ONNX model (default: the shipped one of the set's modality);
    ``features``: the kinds to run (learned ones only where a model is installed)."""
    from ._trackers import _feature_kinds, _tier

    tier = _tier(quick, tier)
    rows = [] if rows is None else rows
    names = QUICK_SEQUENCES if tier == "quick" and directory is None else None
    seqs = external_sequences(directory, names)
    first = seqs[0][1].modality if seqs else "inplane"
    modality = first if first in ("axial", "volume") else "inplane"
    for name, seq in seqs:
        if seq.modality != modality:
            raise ValueError(f"bench external: {name} holds a {seq.modality!r} sequence; "
                             f"the suite tracks a set of {modality} sequences (the set's "
                             f"first recording is {seqs[0][0]})")
    model = None if model is None else str(model)
    kinds = [k for k in _feature_kinds(modality, log) if k in features]
    if modality in ("axial", "volume"):
        if modality == "axial":
            from ._external_axial import run_axial_set as run_set
        else:
            from ._external_volume import run_volume_set as run_set
        out = run_set(seqs, seed, log, rows, model, kinds)
        return {**out, "data": str(Path(directory) if directory is not None else data_dir())}
    log(f"  external: {len(seqs)} sequences, {sum(s.n_frames for _, s in seqs)} frames"
        + (f", learned features from {model}" if model else ""))

    traces = {}
    for kind in kinds:
        per = []
        method = None
        for i, (name, seq) in enumerate(seqs):
            method, est = _track(seq, kind, seed + i, model)
            traces[(name, kind)], m = trace_and_metrics(est, seq)
            per.append(m)
            lat = np.array([e.latency_ms for e in est], float)
            row = {"suite": "external", "tracker": "inplane", "method": method,
                   "features": kind, "model": model if kind == "learned" else None,
                   "sequence": name, **_describe(seq),
                   "frames": seq.n_frames, "seed": seed + i,
                   **{k: v for k, v in m.items() if k != "tip_errors_mm"},
                   "latency_median_ms": float(np.median(lat))}
            rows.append(row)
            log(f"  external {name:28s} {kind:9s} median {_fmt(row['tip_error_median_mm'])} "
                f"p95 {_fmt(row['tip_error_p95_mm'])} mm, tracked "
                f"{_fmt(row['tracked_fraction'])}, false {_fmt(row['false_tracking_fraction'])}"
                f", wrong {_fmt(row['wrong_fraction'])}, in 95% {_fmt(row['covered_fraction'])}")
        pm = pooled_metrics(per)
        row = {"suite": "external", "tracker": "inplane", "method": method, "features": kind,
               "model": model if kind == "learned" else None,
               "sequence": "pooled", "probe": None, "needle": None, "side": None,
               "angle_deg": None, "feature": None,
               "frames": int(sum(s.n_frames for _, s in seqs)), "seed": seed,
               **{k: v for k, v in pm.items() if k != "tip_errors_mm"}}
        rows.append(row)
        log(f"  external {'pooled':28s} {kind:9s} median {_fmt(row['tip_error_median_mm'])} "
            f"p95 {_fmt(row['tip_error_p95_mm'])} mm, tracked {_fmt(row['tracked_fraction'])}, "
            f"false {_fmt(row['false_tracking_fraction'])}, wrong {_fmt(row['wrong_fraction'])}, "
            f"in 95% {_fmt(row['covered_fraction'])}, score {_fmt(row['score'], 3)}")
    return {"rows": rows, "traces": traces,
            "data": str(Path(directory) if directory is not None else data_dir())}


def _fmt(v, digits: int = 2) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:.{digits}f}"


def markdown(result: dict, machine: dict) -> str:
    if any(r.get("tracker") == "axial" for r in result["rows"]):
        from ._external_axial import markdown_axial

        return markdown_axial(result, machine)
    if any(r.get("tracker") == "volume" for r in result["rows"]):
        from ._external_volume import markdown_volume_set

        return markdown_volume_set(result, machine)
    lines = [f"Machine: {machine['cpu']}, {machine['cores']} cores", "",
             "Default in-plane tracker (no angle, no gauge given). Tip error over needle frames "
             "reported `tracking`; tracked: needle frames reported `tracking`; false: "
             "needle-free frames reported `tracking`; wrong: needle frames reported `tracking` "
             f"more than {GOOD_MM:g} mm from the tip; score: needle frames tracked within "
             f"{GOOD_MM:g} mm of the tip over needle frames, less the false fraction (how models "
             "are chosen, docs/notes/inplane.md); in 95%: tracked needle frames whose tip lies "
             "inside the reported 95% region (95% when the reported uncertainty is honest).", "",
             "| sequence | probe | needle | features | median (mm) | 95th (mm) | tracked | "
             "false | wrong | score | in 95% |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    lines += table_rows(result["rows"], lambda r: " ".join(
        v for v in (r["side"], None if r["angle_deg"] is None else f"{r['angle_deg']:g}°")
        if v) or "yes", lambda r: f"{_pct(r.get('wrong_fraction'))} | "
                                  f"{_fmt(r.get('score'), 3)} | {_pct(r.get('covered_fraction'))}")
    return "\n".join(lines)


def table_rows(rows: list[dict], needle_text, last_cell) -> list[str]:
    """The markdown rows of an external set's table (per sequence and pooled): sequence,
    probe, needle (``needle_text(row)`` for a needle sequence), features, median, 95th,
    tracked, false and ``last_cell(row)``."""
    out = []
    for r in rows:
        if r["sequence"] == "pooled":
            needle = "-"
        elif r["needle"]:
            needle = needle_text(r)
        else:
            needle = "none"
        name = f"**{r['sequence']}**" if r["sequence"] == "pooled" else r["sequence"]
        out.append(f"| {name} | {r['probe'] or '-'} | {needle} | {r['features']} | "
                   f"{_fmt(r['tip_error_median_mm'])} | {_fmt(r['tip_error_p95_mm'])} | "
                   f"{_pct(r['tracked_fraction'])} | {_pct(r['false_tracking_fraction'])} | "
                   f"{last_cell(r)} |")
    return out


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.0f}%"
