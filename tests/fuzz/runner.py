"""Run fuzz cases through ``needlenet.cli.main`` in a worker process bounded in time and memory,
and classify what happened.

    python -m tests.fuzz.runner --cases 2000 --seed 0 [--report out.json]
    python -m tests.fuzz.runner --seed 0 --only 123,456 --keep /tmp/fz   # reproduce two cases

**The worker** (:mod:`._worker`): one process runs case after case, bounded in time (20 s a
case by default) and memory (its data segment capped at its warmed-up size plus 2 GiB), and
is replaced after a hang, a memory failure, a crash and every 250 cases.

**Outcomes** (:data:`OUTCOMES`), first match wins:

- ``damage``: a file that existed before the case changed or vanished (an input always;
  another file unless it is one of the case's outputs and ``--overwrite`` was given);
- ``crash``: the worker died (a signal other than our kill), ``hang``: over the time limit;
- ``memory``: MemoryError, over the data cap, a resident peak over 2 GiB above the worker's
  baseline, or an error message that says an allocation failed;
- ``traceback``: any other exception out of ``main``;
- ``nan``: exit 0 but a NaN or infinity where a number is reported (stdout, ``--json``), a
  status outside searching/tracking/lost, or a ``tracking`` frame without a finite tip;
- ``bad-output``: exit 0 but an output that does not read back (``--out-plus``, ``synth
  --out``) or is missing;
- ``messy-error``: a non-zero exit that is not exit status 2 with the one line
  ``needlenet: error: ...`` (warnings and notes the CLI prints before it are allowed; Python
  warnings are counted apart, see ``py_warnings``) or an argparse usage error;
- ``litter``: a file the case did not ask for was left behind (a temporary file);
- ``clean-error`` and ``ok``.

A case passes when its outcome is one of those its :class:`~tests.fuzz.cases.Case` expects
(by default clean-error or ok; an existing output without ``--overwrite`` must be a
clean-error, a valid input ok); the failures list says what was expected.

Measured here (2 cores shared with other jobs): 2,000 cases in 105-130 s, the slowest case
5 s (a model's dry run stopped at its time limit), the largest resident peak +610 MB (a
volume model made for 0.2 mm voxels).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

from ._worker import MEM_EXTRA, TIME_LIMIT_S, Worker, worker_main

__all__ = ["OUTCOMES", "Worker", "run_fuzz", "run_cases", "summary_table", "failures_text"]

OUTCOMES = ("ok", "clean-error", "damage", "crash", "hang", "memory", "traceback", "nan",
            "bad-output", "messy-error", "litter")
RECYCLE_EVERY = 250
_ALLOC_TEXT = re.compile(r"Unable to allocate|MemoryError|bad_alloc|Failed to allocate|"
                         r"Insufficient memory|Cannot allocate memory|out of memory", re.I)
_ERROR_LINE = re.compile(r"^needlenet: error: \S")
_USAGE_ERROR = re.compile(r"^needlenet(?: [\w-]+)?: error: \S")
_ALLOWED_BEFORE = re.compile(r"^(needlenet: (warning|note): |OpenIGTLink: )")
_PY_WARNING = re.compile(r"^\S.*:\d+: \w*Warning: ")


# -- checking what a case did -----------------------------------------------------------------

def snapshot(d: Path) -> dict[str, tuple]:
    """Every entry under ``d``: regular files by content hash, symlinks by target, FIFOs and
    folders by kind (never opened)."""
    out = {}
    for root, dirs, files in os.walk(d):
        for name in dirs + files:
            p = Path(root) / name
            rel = str(p.relative_to(d))
            st = os.lstat(p)
            if stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(p), p.exists())
            elif stat.S_ISREG(st.st_mode):
                with open(p, "rb") as fh:
                    out[rel] = ("file", hashlib.sha1(fh.read()).hexdigest())
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = ("dir",)
            else:
                out[rel] = ("special", stat.S_IFMT(st.st_mode))
    return out


def _damage(case, d: Path, before: dict, after: dict, argv: list[str]) -> tuple[str, str] | None:
    overwrite = "--overwrite" in argv
    outputs = {os.path.normpath(o) for o in case.outputs}
    for rel, what in before.items():
        now = after.get(rel)
        if now == what:
            continue
        dangling = what[0] == "link" and not what[2]
        if rel in outputs and (overwrite or dangling):
            continue
        if what[0] == "dir" and now is None and rel in outputs:
            continue
        return "damage", f"{rel} {'vanished' if now is None else 'changed'}"
    for rel, what in after.items():
        if rel in before or rel in outputs or what[0] == "dir":
            continue
        return "litter", f"left {rel!r} behind"
    return None


def _finite_walk(obj, path="") -> str | None:
    """The path of the first non-finite number in a parsed JSON value, or None."""
    if isinstance(obj, float):
        return None if obj == obj and obj not in (float("inf"), float("-inf")) else path
    if isinstance(obj, dict):
        for k, v in obj.items():
            bad = _finite_walk(v, f"{path}.{k}")
            if bad:
                return bad
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            bad = _finite_walk(v, f"{path}[{i}]")
            if bad:
                return bad
    return None


def _option(argv, name):
    return argv[argv.index(name) + 1] if name in argv and argv.index(name) + 1 < len(argv) \
        else None


def _check_ok_outputs(case, argv: list[str], res: dict) -> tuple[str, str] | None:
    """What an exit-0 run reported and wrote: finite numbers, valid statuses, readable
    outputs."""
    text = res["stdout"]
    if re.search(r"\bNaN\b|-?\bInfinity\b", text):
        return "nan", "NaN or Infinity on stdout"
    if argv[0] == "track":
        out = _option(argv, "--json")
        if out is None:
            return None
        p = Path(out)
        if not p.is_file():
            return "bad-output", f"--json {out} was not written"
        try:
            data = json.loads(p.read_text())
        except (ValueError, UnicodeDecodeError) as exc:
            return "bad-output", f"--json does not parse: {exc}"
        bad = _finite_walk(data)
        if bad:
            return "nan", f"--json{bad} is not finite"
        frames = data.get("frames", [])
        for i, f in enumerate(frames):
            if f.get("status") not in ("searching", "tracking", "lost"):
                return "nan", f"frame {i}: status {f.get('status')!r}"
            tip = f.get("tip_mm")
            if f["status"] == "tracking" and not (
                    isinstance(tip, list) and tip and all(
                        isinstance(v, (int, float)) and not isinstance(v, bool) for v in tip)):
                return "nan", f"frame {i} is tracking without a finite tip ({tip!r:.60})"
        if data.get("summary", {}).get("frames") != len(frames):
            return "bad-output", "--json summary.frames differs from the frames written"
        plus = _option(argv, "--out-plus")
        if plus is not None:
            from needlenet.io import RecordingError, read_plus

            try:
                read_plus(plus)
            except (RecordingError, OSError) as exc:
                return "bad-output", f"--out-plus does not read back: {exc}"
    elif argv[0] == "synth" and "--list" not in argv and _option(argv, "--out"):
        out = _option(argv, "--out")
        from needlenet.io import RecordingError, load_recording

        try:
            load_recording(out)
        except (RecordingError, ValueError, OSError) as exc:
            return "bad-output", f"synth --out does not read back: {exc}"
    return None


def _error_shape(res: dict) -> tuple[str, str, int]:
    """(outcome, detail, python warning lines) of a run that exited non-zero."""
    lines = [ln for ln in res["stderr"].splitlines() if ln.strip()]
    kept, warns, skip = [], 0, False
    for ln in lines:
        if skip:
            skip = False
            if ln.startswith("  "):
                continue
        if _PY_WARNING.match(ln):
            warns += 1
            skip = True
            continue
        kept.append(ln)
    rc = res["rc"]
    last = kept[-1] if kept else ""
    if rc == 2 and kept and _ERROR_LINE.match(last) and all(_ALLOWED_BEFORE.match(ln)
                                                            for ln in kept[:-1]):
        return "clean-error", last, warns
    if rc == 2 and kept and kept[0].startswith("usage: ") and _USAGE_ERROR.match(last):
        return "clean-error", last, warns
    return "messy-error", f"exit {rc}: " + " | ".join(kept[-3:])[:400], warns


def classify(case, d: Path, argv: list[str], res: dict | None, before: dict,
             worker_status: str | None, baseline_rss_mb: float = 0.0) -> dict:
    """The outcome of one case and a one-line detail."""
    after = snapshot(d)
    out = {"id": case.id, "family": case.family, "what": case.what, "argv": argv,
           "expect": list(case.expect)}
    dmg = _damage(case, d, before, after, argv)
    py_warns = 0
    if res is None:
        outcome, detail = worker_status or "crash", "worker gave no answer"
    elif dmg and dmg[0] == "damage":
        outcome, detail = dmg
    elif res["exc"] == "timeout":
        outcome, detail = "hang", f"over the time limit; at: {_last_frame(res['tb'])}"
    elif res["exc"] == "MemoryError" or res["peak_rss_mb"] > MEM_EXTRA / 2**20:
        outcome, detail = "memory", (f"MemoryError at {_last_frame(res['tb'])}"
                                     if res["exc"] else f"peak RSS +{res['peak_rss_mb']:.0f} MB")
    elif res["exc"]:
        outcome, detail = "traceback", f"{res['exc']} at {_last_frame(res['tb'])}"
    elif res["rc"] == 0:
        bad = _check_ok_outputs(case, argv, res)
        outcome, detail = bad if bad else ("ok", "")
    else:
        outcome, detail, py_warns = _error_shape(res)
        if outcome == "clean-error" and _ALLOC_TEXT.search(detail):
            outcome = "memory"
    if outcome in ("ok", "clean-error") and dmg:
        outcome, detail = dmg
    if res is not None:
        py_warns += sum(1 for ln in res["stderr"].splitlines() if _PY_WARNING.match(ln)) \
            if outcome == "ok" else 0
        out.update(rc=res["rc"], wall_s=round(res["wall_s"], 3),
                   peak_rss_mb=round(res["peak_rss_mb"], 1), stderr=res["stderr"][-2000:],
                   noise=res["noise"][-1000:], tb=res["tb"])
    out.update(outcome=outcome, detail=detail, py_warnings=py_warns,
               passed=outcome in case.expect)
    return out


def _last_frame(tb: str | None) -> str:
    if not tb:
        return "?"
    frames = re.findall(r'File "([^"]+)", line (\d+), in (\S+)', tb)
    if not frames:
        return "?"
    f, line, fn = frames[-1]
    root = str(Path(__file__).resolve().parents[2]) + os.sep
    return f"{f.replace(root, '')}:{line} ({fn})"


# -- running many ------------------------------------------------------------------------------

def run_cases(cases, workdir: Path, base, time_limit: float = TIME_LIMIT_S,
              mem_extra: int = MEM_EXTRA, keep: bool = False, progress=None) -> dict:
    """Run ``cases`` (an iterable of :class:`~tests.fuzz.cases.Case`) in a worker; return
    the report: ``results`` (one dict per case), ``worker`` (its measured baseline) and
    ``wall_s``."""
    from .cases import Case

    workdir = Path(workdir)
    cases_dir = workdir / "cases"
    cases_dir.mkdir(parents=True, exist_ok=True)
    warm = Case(id="warmup", family="control", what="warm-up",
                argv=["track", "{d}/i.npz", "--quiet", "--json", "{d}/out.json",
                      "--overwrite"],
                files=base.input_files("i.npz"))
    warm_dir = warm.materialize(workdir / "warm")
    t0 = time.perf_counter()
    worker = None
    infos = []
    results = []
    try:
        for case in cases:
            if worker is None or worker.cases >= RECYCLE_EVERY:
                if worker is not None:
                    worker.close()
                worker = Worker(workdir, warm.command(warm_dir), warm_dir, time_limit,
                                mem_extra)
                infos.append({k: worker.info.get(k) for k in ("baseline_vmdata_mb",
                                                              "vmsize_mb", "rss_mb",
                                                              "limit_mb", "wall_s")})
            d = case.materialize(cases_dir)
            argv = case.command(d)
            before = snapshot(d)
            res = worker.run(argv, d)
            status = None
            if res is None:
                alive = worker.proc.poll() is None
                rc = worker.close(kill=True)
                noise = worker.noise_text()
                status = "hang" if alive else ("memory" if rc == -signal.SIGKILL else "crash")
                worker = None
            r = classify(case, d, argv, res, before, status)
            if res is None:
                how = "killed after the time limit" if status == "hang" else f"died ({rc})"
                r["detail"] = f"worker {how}: " + noise.strip().replace("\n", " | ")[-300:]
            results.append(r)
            if r["outcome"] in ("hang", "memory", "crash") and worker is not None:
                worker.close(kill=True)
                worker = None
            if not keep:
                shutil.rmtree(d, ignore_errors=True)
                if d.exists():
                    subprocess.run(["chmod", "-R", "u+rwx", str(d)], check=False)
                    shutil.rmtree(d, ignore_errors=True)
            if progress is not None:
                progress(r)
    finally:
        if worker is not None:
            worker.close()
    return {"results": results, "worker": infos, "wall_s": time.perf_counter() - t0}


def run_fuzz(n: int, seed: int = 0, workdir: Path | None = None, only=None, keep: bool = False,
             families=None, time_limit: float = TIME_LIMIT_S, mem_extra: int = MEM_EXTRA,
             progress=None) -> dict:
    """Make the valid inputs, generate ``n`` cases of ``seed`` (or the indices ``only``;
    ``families`` filters) and run them; the report of :func:`run_cases` plus the seed."""
    from .cases import Base, generate_cases

    own = workdir is None
    workdir = Path(tempfile.mkdtemp(prefix="needlenet-fuzz-")) if own else Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    try:
        t0 = time.perf_counter()
        base = Base(workdir / "base")
        t_base = time.perf_counter() - t0
        cases = generate_cases(n, seed, base, only)
        if families:
            cases = (c for c in cases if c.family in families)
        report = run_cases(cases, workdir, base, time_limit, mem_extra, keep, progress)
        report.update(seed=seed, n=n, base_s=t_base, total_s=time.perf_counter() - t0,
                      workdir=str(workdir))
        return report
    finally:
        if own and not keep:
            shutil.rmtree(workdir, ignore_errors=True)


def summary_table(report: dict) -> str:
    """Counts by outcome, then by family and outcome."""
    res = report["results"]
    by = Counter(r["outcome"] for r in res)
    cols = [o for o in OUTCOMES if by[o]]
    fam: dict[str, Counter] = defaultdict(Counter)
    for r in res:
        fam[r["family"]][r["outcome"]] += 1
    w = max([len(f) for f in fam] + [6])
    lines = [f"{len(res)} cases, seed {report.get('seed')}, {report['wall_s']:.1f} s "
             f"({sum(r.get('wall_s', 0) for r in res):.1f} s in cases); "
             f"{sum(not r['passed'] for r in res)} failed",
             "", "outcome       count", *[f"{o:<13} {by[o]:5d}" for o in cols], "",
             f"{'family':<{w}} " + " ".join(f"{c:>11}" for c in cols) + "   failed"]
    for f in sorted(fam):
        failed = sum(not r["passed"] for r in res if r["family"] == f)
        lines.append(f"{f:<{w}} " + " ".join(f"{fam[f][c]:>11}" for c in cols) +
                     f"   {failed:6d}")
    info = report.get("worker") or []
    if info:
        i = info[0]
        lines += ["", f"worker: VmData {i['baseline_vmdata_mb']:.0f} MB after warm-up, "
                      f"VmSize {i['vmsize_mb']:.0f} MB, RSS {i['rss_mb']:.0f} MB; data "
                      f"capped at {i['limit_mb']:.0f} MB; {len(info)} worker(s) started"]
    peak = max(res, key=lambda r: r.get("peak_rss_mb", 0), default=None)
    if peak is not None and "peak_rss_mb" in peak:
        lines.append(f"largest resident peak: +{peak['peak_rss_mb']:.0f} MB ({peak['id']}); "
                     f"slowest case: {max(r.get('wall_s', 0) for r in res):.2f} s")
    warns = sum(r.get("py_warnings", 0) for r in res)
    if warns:
        lines.append(f"Python warnings printed: {warns} lines in "
                     f"{sum(1 for r in res if r.get('py_warnings'))} cases")
    return "\n".join(lines)


def failures_text(report: dict, seed: int | None = None) -> str:
    """Every failed case: id, outcome, what it did, its detail and how to reproduce it."""
    seed = report.get("seed") if seed is None else seed
    out = []
    for r in report["results"]:
        if r["passed"]:
            continue
        idx = int(r["id"].split("-")[0])
        out.append(f"{r['id']}: {r['outcome']} (expected {'/'.join(r['expect'])}): {r['what']}"
                   f"\n    {r['detail']}\n    argv: {json.dumps(r['argv'])}\n"
                   f"    reproduce: python -m tests.fuzz.runner --seed {seed} --only {idx} "
                   "--keep /tmp/needlenet-fuzz")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.fuzz.runner", description=__doc__.split(
        "\n\n")[0])
    ap.add_argument("--cases", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", help="comma-separated case indices (reproduce them)")
    ap.add_argument("--families", help="comma-separated families to keep")
    ap.add_argument("--keep", metavar="DIR", help="work in DIR and keep every case's files")
    ap.add_argument("--report", metavar="FILE.json")
    ap.add_argument("--time-limit", type=float, default=TIME_LIMIT_S)
    ap.add_argument("--mem-extra-gb", type=float, default=MEM_EXTRA / 2**30)
    ap.add_argument("--verbose", action="store_true", help="one line per case")
    ap.add_argument("--worker", nargs=2, type=int, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker_main(*args.worker)
        return 0
    only = None if not args.only else [int(s) for s in args.only.split(",")]
    fams = None if not args.families else set(args.families.split(","))
    count = [0]

    def progress(r):
        count[0] += 1
        if args.verbose or not r["passed"]:
            print(f"[{count[0]}] {r['id']} {r['outcome']} {r.get('wall_s', 0):.2f}s "
                  f"{r['what'][:90]}" + (f"\n      {r['detail'][:200]}" if not r["passed"]
                                           else ""), flush=True)
        elif count[0] % 100 == 0:
            print(f"[{count[0]}] ...", flush=True)

    report = run_fuzz(args.cases, args.seed, args.keep, only, bool(args.keep), fams,
                      args.time_limit, int(args.mem_extra_gb * 2**30), progress)
    print()
    print(summary_table(report))
    fails = failures_text(report)
    if fails:
        print("\nfailures:\n" + fails)
    if args.keep and only:
        for r in report["results"]:
            print(f"\n{r['id']} ({r['outcome']}): cd {report['workdir']}/cases/{r['id']} && "
                  "needlenet " + " ".join(_quote(a) for a in r["argv"]))
    if args.report:
        Path(args.report).write_text(json.dumps(report, indent=1, default=str))
    return 1 if fails else 0


def _quote(a: str) -> str:
    import shlex

    return shlex.quote(a)


if __name__ == "__main__":
    sys.exit(main())
