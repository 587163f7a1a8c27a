"""``needlenet demo``: the main job on its defaults.

With the shipped ONNX models (no training), it simulates a few seeded sequences of each
modality, tracks them with classical and with learned features through the same back ends
(the ``demo`` tier of the benchmark suites: one code path with ``needlenet bench``), runs a
short servo loop, tracks the external in-plane sequences of an independent simulator (PyMUST)
with the default tracker, and writes a report directory:

- ``report.md``: the headline comparison of every suite (learned against classical), the
  papers' tables and plots, and an overlay animation of the in-plane tracking;
- one sub-directory per suite with its own ``report.md``, ``results.json`` and plots.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from .bench import HEADLINE, LOWER_IS_BETTER, PAPERS, run_suite

DEMO_SUITES = ("inplane", "axial", "volume", "servo", "external")
# what each suite measures against: a paper's protocol, or the data set
TITLES = {**PAPERS, "external": "sequences from an independent simulator (PyMUST)"}


class _Log:
    def __init__(self, quiet: bool):
        self.quiet, self.t0 = quiet, time.perf_counter()

    def __call__(self, msg: str) -> None:
        if not self.quiet:
            print(f"[{time.perf_counter() - self.t0:6.1f} s] {msg.strip()}", flush=True)

    def step(self, msg: str) -> None:
        print(f"[{time.perf_counter() - self.t0:6.1f} s] {msg}", flush=True)


def _f(v) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:.3g}"


def run_demo(out_dir: str | Path, seed: int = 0, quiet: bool = False,
             suites=DEMO_SUITES) -> Path:
    """Run the demo into ``out_dir`` (created) and return the path of its report."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    log = _Log(quiet)
    results = {}
    for i, name in enumerate(suites, 1):
        log.step(f"({i}/{len(suites)}) {name}: {TITLES.get(name, '')}, classical and "
                 f"learned features")
        results[name] = run_suite(name, tier="demo", seed=seed, log=log,
                                  report_dir=out / name, overwrite=True)
    gif = None
    ex = results.get("inplane", {}).get("traces", {}).get("example", {})
    key = next((k for k in ex if k[1] == "learned"), None) or next(iter(ex), None)
    if key is not None:
        from .io import write_overlay

        seq, est, _ = ex[key]
        gif = out / "inplane_overlay.gif"
        write_overlay(gif, seq, est, max_size=256)
        log.step(f"overlay animation: {gif}")
    report = _write(out, results, gif, time.perf_counter() - log.t0)
    log.step(f"done in {time.perf_counter() - log.t0:.0f} s")
    return report


def _write(out: Path, results: dict, gif: Path | None, elapsed: float) -> Path:
    m = next(iter(results.values()))["machine"] if results else {}
    lines = ["# needlenet demo", "",
             "Seeded synth sequences of each modality, tracked with classical features (the "
             "papers' own) and with learned likelihood maps (the shipped ONNX models) through "
             "the same back ends. These are small runs; `needlenet bench SUITE` runs the full "
             "protocols.", "",
             f"Machine: {m.get('cpu')}, {m.get('cores')} cores; {elapsed:.0f} s in all.", "",
             "## Headline metrics: learned against classical", "",
             "| suite | paper | metric | configuration | classical | learned | verdict |",
             "|---|---|---|---|---|---|---|"]
    for name, res in results.items():
        comp = res.get("comparison", [])
        key = HEADLINE.get(name)
        better = "lower" if LOWER_IS_BETTER.get(name, True) else "higher"
        for c in comp:
            conf = ", ".join(f"{k}={c[k]}" for k in c if k not in (
                "metric", "classical_best", "classical_worst", "classical_settings", "learned",
                "verdict") and c[k] is not None)
            cl = _f(c["classical_best"])
            if c["classical_settings"] > 1:
                cl += f" to {_f(c['classical_worst'])}"
            lines.append(f"| {name} | {TITLES.get(name, '')} | `{key}` ({better} is better) "
                         f"| {conf} | {cl} | {_f(c['learned'])} | {c['verdict']} |")
        if not comp:
            lines.append(f"| {name} | {TITLES.get(name, '')} | `{key}` | - | - | - | "
                         "learned features not run |")
    if gif is not None:
        lines += ["", "## In-plane tracking", "",
                  f"![in-plane overlay]({gif.name})", "",
                  "*Tracked tip (red cross) and axis against the true tip (green circle).*"]
    for name, res in results.items():
        lines += ["", f"## {name}: {TITLES.get(name, '')}", "", res["markdown"], ""]
        rep = out / name / "report.md"
        if rep.exists():
            for ln in rep.read_text().splitlines():
                if ln.startswith("!["):  # the suite's plots, re-linked from here
                    cap, fname = ln[2:].split("](", 1)
                    lines += [f"![{cap}]({name}/{fname}", ""]
    lines += ["", "Rows of every suite: `*/results.json`."]
    path = out / "report.md"
    tmp = out / ".report.md.tmp"
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)
    return path
