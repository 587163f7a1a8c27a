"""Suite registry and the shared output of ``needlenet bench``: a JSON of rows, a Markdown
table in the paper's layout, a learned-vs-classical comparison on the suite's headline metric,
and (with ``--report DIR``) plots and a report.

Every row is written to the JSON as soon as it is measured (``"complete": false`` until the
suite ends), so an interrupted or killed run keeps the rows it finished.
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from ._machine import machine_description

SUITES = ("synth", "models", "latency", "inplane", "axial", "volume", "servo", "external",
          "honesty")

# the headline metric of each suite: a fixed key present in every row (lower is better for
# the four tracking suites and latency; higher for the models' AUC and the simulator's speed)
HEADLINE = {
    "inplane": "tip_error_p95_mm", "volume": "failure_rate",
    "axial": "tip_prediction_error_mm", "servo": "rmse_p_mm", "latency": "latency_p99_ms",
    "models": "shaft_auc_mean", "synth": "frames_per_s", "external": "tip_error_p95_mm",
    "honesty": "false_tracking_fraction",
}
LOWER_IS_BETTER = {"inplane": True, "volume": True, "axial": True, "servo": True,
                   "latency": True, "models": False, "synth": False, "external": True,
                   "honesty": True}
# the fields that identify a configuration apart from its features (for the comparison)
GROUP_BY = {
    "inplane": ("method",), "axial": ("method", "D_mm"),
    "volume": ("table", "method", "alpha_deg", "cr"),
    "servo": ("scenario", "method", "run"),
    "latency": ("tracker", "method", "frame"),
    "external": ("sequence",), "honesty": ("method",),
}
PAPERS = {
    "inplane": "Mathiassen et al. 2017, Table III", "volume": "Zhao et al. 2013, Tables 2-3",
    "axial": "Carriere et al. 2016, Tables I-II", "servo": "Ye et al. 2025, Table 2",
}


class BenchInterrupted(Exception):
    """A suite stopped early (Ctrl-C); the rows it finished were written."""

    def __init__(self, suite: str, n_rows: int, paths: list[Path]):
        where = ", ".join(str(p) for p in paths) or "nowhere (no --json or --report given)"
        super().__init__(f"bench {suite}: interrupted; kept {n_rows} finished rows in {where}")
        self.n_rows, self.paths = n_rows, paths


class _RowSink(list):
    """A list of rows that saves the partial result whenever a row is added."""

    def __init__(self, on_append):
        super().__init__()
        self._on_append = on_append

    def append(self, row) -> None:
        super().append(row)
        self._on_append()


def _suite_module(name: str):
    if name == "synth":
        from . import _synth as mod
    elif name == "models":
        from . import _models as mod
    elif name == "latency":
        from . import _latency as mod
    elif name == "servo":
        from . import _servo as mod
    elif name == "external":
        from . import _external as mod
    elif name == "honesty":
        from . import _honesty as mod
    else:
        from . import _trackers as tr

        class mod:  # noqa: N801 - a namespace with the module interface
            run = staticmethod(getattr(tr, f"run_{name}"))
            markdown = staticmethod(getattr(tr, f"markdown_{name}"))
    return mod


def jsonable(x):
    """``x`` with numpy scalars/arrays and tuples made JSON types, non-finite floats None."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    return x


def write_json_atomic(path: Path, obj) -> None:
    """Write JSON to a temporary file beside ``path`` and rename it over ``path``."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(json.dumps(jsonable(obj), indent=2))
    os.replace(tmp, path)


def check_report_dir(path: str | Path, overwrite: bool) -> Path:
    """The report directory, checked before any work: not a file, writable, and not holding
    a report already unless ``overwrite``."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ValueError(f"--report {p}: exists and is not a directory")
    if p.is_dir() and (p / "report.md").exists() and not overwrite:
        raise FileExistsError(f"--report {p} already holds a report (report.md); "
                              f"pass --overwrite to replace it")
    probe = p if p.is_dir() else p.parent if str(p.parent) else Path(".")
    if not probe.is_dir():
        raise ValueError(f"--report {p}: directory {probe} does not exist")
    if not os.access(probe, os.W_OK):
        raise PermissionError(f"--report {p}: directory {probe} is not writable")
    return p


def compare(suite: str, rows: list[dict]) -> list[dict]:
    """Learned against classical features on the suite's headline metric, per configuration.

    Where the classical source has several settings for one configuration (Zhao's intensity
    thresholds) the learned value is compared with the best and the worst of them.
    """
    key, by = HEADLINE.get(suite), GROUP_BY.get(suite)
    if key is None or by is None:
        return []
    lower = LOWER_IS_BETTER[suite]
    groups: dict[tuple, dict[str, list[float]]] = {}
    for r in rows:
        g = tuple(r.get(f) for f in by)
        v = r.get(key)
        if v is None or not np.isfinite(v):
            v = np.nan
        groups.setdefault(g, {}).setdefault(r.get("features"), []).append(float(v))
    out = []
    for g, kinds in groups.items():
        cl, le = kinds.get("classical"), kinds.get("learned")
        if not cl or not le:
            continue
        best = (min if lower else max)(cl)
        worst = (max if lower else min)(cl)
        lv = le[0]
        sign = 1.0 if lower else -1.0
        if not (np.isfinite(lv) and np.isfinite(best)):
            verdict = "not measured"
        elif abs(lv - best) <= 1e-9 * max(1.0, abs(best)) and abs(lv - worst) <= 1e-9 * max(
                1.0, abs(worst)):
            verdict = "tie"
        elif sign * (lv - best) < 0:
            verdict = "learned better"
        elif sign * (lv - worst) > 0 or len(cl) == 1:
            verdict = "classical better"
        else:
            verdict = "learned within the classical range"
        out.append({**dict(zip(by, g, strict=True)), "metric": key,
                    "classical_best": best, "classical_worst": worst,
                    "classical_settings": len(cl), "learned": lv, "verdict": verdict})
    return out


def comparison_markdown(suite: str, comp: list[dict]) -> str:
    if not comp:
        return ""
    key = HEADLINE[suite]
    by = GROUP_BY[suite]
    direction = "lower" if LOWER_IS_BETTER[suite] else "higher"
    multi = any(c["classical_settings"] > 1 for c in comp)
    head = "| " + " | ".join(by) + " | classical" + (" best / worst" if multi else "") + \
        " | learned | verdict |"
    lines = [f"Headline `{key}` ({direction} is better):", "", head,
             "|" + "---|" * (len(by) + 3)]

    def f(v):
        return "-" if v is None or not np.isfinite(v) else f"{v:.3g}"

    for c in comp:
        cl = f(c["classical_best"]) + (f" / {f(c['classical_worst'])}" if multi else "")
        lines.append("| " + " | ".join("-" if c[b] is None else str(c[b]) for b in by) +
                     f" | {cl} | {f(c['learned'])} | {c['verdict']} |")
    n = len(comp)
    wins = sum(c["verdict"] == "learned better" for c in comp)
    losses = sum(c["verdict"] == "classical better" for c in comp)
    lines += ["", f"Learned features win {wins} of {n} configurations, lose {losses}"
              + (f", and tie or fall within the classical range in {n - wins - losses}"
                 if n - wins - losses else "") + "."]
    return "\n".join(lines)


def run_suite(name: str, quick: bool = False, json_out: str | Path | None = None,
              seed: int = 0, log=print, report_dir: str | Path | None = None,
              tier: str | None = None, overwrite: bool = False, data: str | Path | None = None,
              model: str | Path | None = None) -> dict:
    """Run suite ``name`` and return its result (``rows``, ``markdown``, ``comparison``; the
    per-frame ``traces`` for plots stay out of the JSON). The external suite also takes
    ``data`` (a directory of labelled sequence files instead of the shipped set) and
    ``model`` (an in-plane ONNX model for the learned features instead of the shipped one)."""
    if name not in SUITES:
        raise ValueError(f"unknown suite {name!r}; available: {', '.join(SUITES)}")
    own = {"directory": data, "model": model} if name == "external" else {}
    if name != "external" and (data is not None or model is not None):
        raise ValueError(f"bench {name}: --data and --model belong to the external suite")
    tier = tier or ("quick" if quick else "full")
    if report_dir is not None:
        report_dir = check_report_dir(report_dir, overwrite)
    mod = _suite_module(name)
    machine = machine_description()
    result: dict = {"suite": name, "tier": tier, "quick": tier != "full", "seed": seed,
                    "headline": HEADLINE.get(name), "paper": PAPERS.get(name),
                    "machine": machine, "complete": False,
                    "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    paths: list[Path] = []
    if json_out is not None:
        paths.append(Path(json_out))
    if report_dir is not None:
        report_dir.mkdir(parents=True, exist_ok=True)
        paths.append(report_dir / "results.json")

    def finish_row(row: dict) -> None:
        row.setdefault("suite", name)
        row.setdefault("machine", f"{machine['cpu']}, {machine['cores']} cores")
        if result["headline"] is not None:
            row.setdefault(result["headline"], None)

    def save() -> None:
        for row in rows:
            finish_row(row)
        data = {k: v for k, v in result.items() if k not in ("traces", "markdown")}
        data["rows"] = list(rows)
        for p in paths:
            write_json_atomic(p, data)

    rows = _RowSink(save)
    result["rows"] = rows
    t0 = time.perf_counter()
    try:
        out = mod.run(tier=tier, seed=seed, log=log, rows=rows, **own)
    except KeyboardInterrupt:
        result["interrupted"] = True
        result["elapsed_s"] = time.perf_counter() - t0
        save()
        if report_dir is not None:
            _write_report(report_dir, name, result, mod, {}, partial=True)
        raise BenchInterrupted(name, len(rows), paths) from None
    traces = out.pop("traces", {})
    out.pop("rows", None)
    result.update(out)
    result["elapsed_s"] = time.perf_counter() - t0
    result["complete"] = True
    save()
    result["rows"] = list(rows)
    result["comparison"] = compare(name, result["rows"])
    result["markdown"] = mod.markdown(result, machine)
    cm = comparison_markdown(name, result["comparison"])
    if cm:
        result["markdown"] += "\n\n" + cm
    save()
    if report_dir is not None:
        result["report"] = str(_write_report(report_dir, name, result, mod, traces))
    result["traces"] = traces
    return result


def _write_frames(out_dir: Path, traces: dict) -> bool:
    """``frames.csv``: the per-frame records of traces keyed (sequence, features) that carry
    them (``frames``, :func:`~._external.frame_records`); False when none does."""
    from ._external import FRAME_FIELDS

    keyed = [(key, t["frames"]) for key, t in traces.items()
             if isinstance(t, dict) and "frames" in t and isinstance(key, tuple)]
    if not keyed:
        return False
    tmp = out_dir / ".frames.csv.tmp"
    with open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FRAME_FIELDS)
        w.writeheader()
        for (sequence, features), records in keyed:
            for r in records:
                w.writerow({"sequence": sequence, "features": features, **r})
    os.replace(tmp, out_dir / "frames.csv")
    return True


def _write_report(out_dir: Path, name: str, result: dict, mod, traces: dict,
                  partial: bool = False) -> Path:
    m = result["machine"]
    lines = [f"# needlenet bench {name}" + (" (interrupted: partial)" if partial else ""), "",
             f"Machine: {m['cpu']}, {m['cores']} cores, {m.get('memory_gb')} GB, "
             f"Python {m['python']}, numpy {m['numpy']}. Tier: {result['tier']}; seed "
             f"{result['seed']}; started {result['started']}; "
             f"{result.get('elapsed_s', 0):.0f} s.", ""]
    if result.get("paper"):
        lines += [f"Protocol: {result['paper']} (the paper's figures are quoted beside ours).",
                  ""]
    if partial:
        lines += [f"The run was interrupted after {len(result['rows'])} rows; "
                  "the rows below are the ones it finished.", ""]
        try:
            lines += [mod.markdown(result, m), ""]
        except (KeyError, TypeError, ValueError, IndexError):
            lines += ["(the table needs the full run; see results.json)", ""]
    else:
        lines += [result["markdown"], ""]
        from ._plots import PLOTS

        if name in PLOTS:
            figs = PLOTS[name](result, traces, out_dir)
            if figs:
                lines += ["## Plots", ""]
                for caption, fname in figs:
                    lines += [f"![{caption}]({fname})", "", f"*{caption}*", ""]
    if not partial and _write_frames(out_dir, traces):
        lines += ["Each frame's status, tip error and the tracker's reason: `frames.csv`."]
    lines += ["Rows: `results.json` in this directory."]
    path = out_dir / "report.md"
    tmp = out_dir / ".report.md.tmp"
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)
    return path
