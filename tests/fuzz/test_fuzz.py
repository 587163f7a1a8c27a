"""The fuzz suite of issue 21 in CI: a seeded sample of bad inputs through ``needlenet track``
and ``needlenet synth``, every case a clean one-line error or a clean run.

The sample is 510 cases (10 rounds of :data:`~tests.fuzz.cases.SCHEDULE`, so every family is
drawn at least 10 times), run in one worker process: measured on this 2-core machine while
other jobs (model training, other engineers' tests) shared it, 29 s including making the
valid inputs (2 s) and starting the worker (3 s); the issue allows two minutes.
``NEEDLENET_FUZZ_CASES=2000`` runs the full set the issue asks for (about 2 minutes here),
``NEEDLENET_FUZZ_SEED`` another seed; ``python -m tests.fuzz.runner`` does the same with a
summary table and reproducers.
"""

import hashlib
import json
import os

import pytest

from .cases import FAMILIES, SCHEDULE, Base, Case, generate_cases
from .runner import (
    _check_ok_outputs,
    _error_shape,
    classify,
    failures_text,
    run_cases,
    run_fuzz,
    snapshot,
    summary_table,
)

CASES = int(os.environ.get("NEEDLENET_FUZZ_CASES", "510"))
SEED = int(os.environ.get("NEEDLENET_FUZZ_SEED", "0"))


def test_fuzz_sample(tmp_path):
    report = run_fuzz(CASES, SEED, tmp_path / "fuzz")
    res = report["results"]
    assert len(res) == CASES
    if CASES >= len(SCHEDULE):
        assert {r["family"] for r in res} == set(FAMILIES)
    failed = [r for r in res if not r["passed"]]
    assert not failed, "\n" + summary_table(report) + "\n\nfailures:\n" + failures_text(report)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return Base(tmp_path_factory.mktemp("base"))


def _fingerprint(case: Case) -> tuple:
    return (case.id, case.what, tuple(case.argv), case.expect, case.outputs,
            tuple(sorted((k, hashlib.sha1(v).hexdigest()) for k, v in case.files.items())))


def test_the_same_seed_gives_the_same_cases(base):
    a = [_fingerprint(c) for c in generate_cases(len(SCHEDULE), 3, base)]
    assert a == [_fingerprint(c) for c in generate_cases(len(SCHEDULE), 3, base)]
    assert a[:10] == [_fingerprint(c) for c in generate_cases(10, 3, base)]  # prefixes agree
    assert a != [_fingerprint(c) for c in generate_cases(len(SCHEDULE), 4, base)]
    assert {f[0].split("-", 1)[1] for f in a} == set(FAMILIES)


def test_the_runner_sees_damage_and_litter(base, tmp_path):
    """A case that replaces a file it was not allowed to, and one whose output is not
    declared, are failures; a valid input is ok."""
    track = ["track", "{d}/i.npz", "--quiet", "--features", "classical"]
    cases = [Case("a", "t", "damage", track + ["--json", "{d}/mine.json", "--overwrite"],
                  {**base.input_files("i.npz"), "mine.json": b"precious"}),
             Case("b", "t", "litter", track + ["--json", "{d}/new.json"],
                  base.input_files("i.npz")),
             Case("c", "t", "fine", track + ["--json", "{d}/out.json"],
                  base.input_files("i.npz"), expect=("ok",), outputs=("out.json",))]
    res = run_cases(cases, tmp_path, base)["results"]
    assert [r["outcome"] for r in res] == ["damage", "litter", "ok"], res
    assert [r["passed"] for r in res] == [False, False, True]


def _res(**kw):
    return {"rc": 0, "exc": None, "tb": None, "wall_s": 0.1, "peak_rss_mb": 1.0,
            "stdout": "", "stderr": "", "noise": "", **kw}


def test_the_runner_classifies(tmp_path):
    case = Case("x", "t", "w", ["track", "f"])
    d = tmp_path / "x"
    d.mkdir()
    before = snapshot(d)

    def outcome(**kw):
        return classify(case, d, case.argv, _res(**kw), before, None)["outcome"]

    assert outcome(exc="timeout", rc=None) == "hang"
    assert outcome(exc="MemoryError", rc=None) == "memory"
    assert outcome(peak_rss_mb=3000.0) == "memory"
    assert outcome(exc="ValueError: x", rc=None) == "traceback"
    assert outcome(rc=2, stderr="needlenet: error: x.npz: key 'images': bad\n") == "clean-error"
    assert outcome(rc=2, stderr="needlenet: error: Unable to allocate 3 GiB\n") == "memory"
    assert outcome(rc=2, stderr="needlenet: warning: a\nneedlenet: error: b\n") == "clean-error"
    assert outcome(rc=2, stderr="needlenet: error: a\nb\n") == "messy-error"
    assert outcome(rc=1, stderr="needlenet: error: a\n") == "messy-error"
    assert outcome(rc=2, stderr="usage: needlenet track\nneedlenet track: error: argument "
                                "--fps: invalid float value: 'x'\n") == "clean-error"
    assert outcome(stdout='{"a": NaN}') == "nan"
    assert classify(case, d, case.argv, None, before, "crash")["outcome"] == "crash"
    kept, _, warns = _error_shape(_res(rc=2, stderr="x.py:3: RuntimeWarning: bad\n  y = 1\n"
                                                    "needlenet: error: z\n"))
    assert (kept, warns) == ("clean-error", 1)


@pytest.mark.parametrize("frames, verdict", [
    ([{"status": "tracking", "tip_mm": [1.0, 2.0]}], None),
    ([{"status": "tracking", "tip_mm": None}], "nan"),
    ([{"status": "tracking", "tip_mm": [None, 2.0]}], "nan"),
    ([{"status": "lost", "tip_mm": None}], None),
    ([{"status": "bogus", "tip_mm": None}], "nan"),
])
def test_a_tracking_frame_needs_a_finite_tip(tmp_path, frames, verdict):
    out = tmp_path / "r.json"
    out.write_text(json.dumps({"frames": frames, "summary": {"frames": len(frames)}}))
    got = _check_ok_outputs(None, ["track", "f", "--json", str(out)], _res())
    assert (got[0] if got else None) == verdict
