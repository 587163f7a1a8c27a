"""The external in-plane set (PyMUST) and ``needlenet bench external``."""

from __future__ import annotations

import numpy as np
import pytest

import synth
from needlenet.bench import _external as ext
from needlenet.bench import run_suite


@pytest.fixture(scope="module")
def committed():
    return ext.external_sequences()


def test_the_committed_set_loads_and_covers_the_protocol(committed):
    assert len(committed) >= 10
    needle = [s for _, s in committed if s.meta["needle"]]
    free = [s for _, s in committed if not s.meta["needle"]]
    assert len(needle) >= 8 and len(free) >= 2
    assert {s.meta["source"] for _, s in committed} == {"pymust"}
    assert {s.meta["probe"] for _, s in committed} == {"L11-5v", "P4-2v"}
    assert {s.meta["side"] for s in needle} == {"left", "right"}
    angles = [s.meta["angle_deg"] for s in needle]
    assert min(angles) <= 15 and max(angles) >= 60
    assert all(10 <= a <= 70 for a in angles)
    for _, s in committed:
        assert s.modality == "inplane" and s.images.dtype == np.uint8
        assert 8 <= s.n_frames <= 16
        assert 0.1 <= s.spacing_mm[0] <= 0.15


def test_the_validation_set_is_apart_from_the_test_set(committed):
    from importlib import resources

    from needlenet.bench.external.specs import SPECS, VALIDATION_SPECS

    val = ext.external_sequences(resources.files("needlenet").joinpath("data", "validation"))
    assert [n for n, _ in val] == sorted(s.name for s in VALIDATION_SPECS)
    assert not {s.seed for s in VALIDATION_SPECS} & {s.seed for s in SPECS}
    assert not {n for n, _ in val} & {n for n, _ in committed}
    for name, seq in val:
        spec = next(s for s in VALIDATION_SPECS if s.name == name)
        assert seq.meta["seed"] == spec.seed and seq.meta["source"] == "pymust"
        assert seq.modality == "inplane" and seq.n_frames == spec.n_frames
    assert {s.meta["probe"] for _, s in val} == {"L11-5v", "L12-3v", "P4-2v"}


def test_labels_lie_inside_the_image_and_needle_free_frames_have_none(committed):
    for name, s in committed:
        needle, free = ext.frame_classes(s)
        if not s.meta["needle"]:
            assert free.all() and not s.visible.any(), name
            assert np.isnan(s.tip_mm).all(), name
            continue
        assert needle.all() and not free.any(), name
        (H, W) = s.images.shape[1:]
        lo = np.array([s.origin_mm[1], s.origin_mm[0]])
        hi = lo + np.array([(W - 1) * s.spacing_mm[1], (H - 1) * s.spacing_mm[0]])
        tips = s.tip_mm[s.visible]
        assert np.all((tips >= lo) & (tips <= hi)), name
        # the tip lands on an imaged pixel (sector probes: inside the fan, not the black margin)
        j = np.round((tips[:, 0] - lo[0]) / s.spacing_mm[1]).astype(int)
        i = np.round((tips[:, 1] - lo[1]) / s.spacing_mm[0]).astype(int)
        assert np.all(s.images.max(axis=0)[i, j] > 0), name
        # the needle advances along its own direction, 1-2 mm per frame
        step = np.linalg.norm(np.diff(s.tip_mm, axis=0), axis=1)
        assert np.all((step >= 1.0 - 1e-9) & (step <= 2.0 + 1e-9)), name
        np.testing.assert_allclose(np.linalg.norm(s.direction, axis=1), 1.0, atol=1e-9)


def test_sequence_metrics_on_hand_made_estimates():
    # 5 needle frames (errors 0, 1, 2 and 4 mm where tracking; frame 3 not tracked) and
    # 4 needle-free frames, one of them reported tracking
    true = np.array([[0, 10], [1, 10], [2, 10], [3, 10], [4, 10]] + [[np.nan, np.nan]] * 4,
                    float)
    est = np.array([[0, 10], [1, 11], [4, 10], [9, 9], [4, 14], [5, 5], [np.nan, np.nan],
                    [np.nan, np.nan], [np.nan, np.nan]], float)
    tracking = np.array([1, 1, 1, 0, 1, 1, 0, 0, 0], bool)
    needle = np.arange(9) < 5
    m = ext.sequence_metrics(tracking, est, true, needle, ~needle)
    assert m["tip_errors_mm"] == [0.0, 1.0, 2.0, 4.0]
    assert m["tip_error_median_mm"] == pytest.approx(1.5)
    # numpy's linear percentile: 2 + 0.85 * (4 - 2)
    assert m["tip_error_p95_mm"] == pytest.approx(3.7)
    assert m["tracked_fraction"] == pytest.approx(4 / 5)
    assert m["false_tracking_fraction"] == pytest.approx(1 / 4)
    # the model-choice score: 3 of 5 needle frames within 3 mm, less 1 of 4 needle-free
    assert m["within_3mm_frames"] == 3 and m["score"] == pytest.approx(3 / 5 - 1 / 4)
    # a confident wrong answer: 1 of 5 needle frames tracked more than 3 mm off (4 mm)
    assert m["wrong_frames"] == 1 and m["wrong_fraction"] == pytest.approx(1 / 5)
    # a sequence without needle frames has no tip statistics
    m2 = ext.sequence_metrics(np.zeros(3, bool), np.full((3, 2), np.nan),
                              np.full((3, 2), np.nan), np.zeros(3, bool), np.ones(3, bool))
    assert m2["tip_error_median_mm"] is None and m2["tracked_fraction"] is None
    assert m2["false_tracking_fraction"] == 0.0
    p = ext.pooled_metrics([m, m2])
    assert p["tip_error_median_mm"] == pytest.approx(1.5)
    assert p["tracked_fraction"] == pytest.approx(4 / 5)
    assert p["false_tracking_fraction"] == pytest.approx(1 / 7)
    assert (p["needle_frames"], p["needle_free_frames"]) == (5, 7)
    assert p["score"] == pytest.approx(3 / 5 - 1 / 7)
    assert p["wrong_fraction"] == pytest.approx(1 / 5) and m2["wrong_fraction"] is None


@pytest.mark.parametrize("dim", [2, 3])
def test_the_reported_region_covers_95_percent_of_errors_drawn_from_it(dim):
    """covered_fraction against scipy's chi-square distribution: errors drawn from the reported
    covariance fall inside its 95% region on 95% of frames; a covariance reported four times
    too small (half the spread) covers far fewer."""
    from scipy.stats import chi2

    rng = np.random.default_rng(7)
    n = 4000
    A = rng.normal(size=(n, dim, dim))
    cov = A @ np.transpose(A, (0, 2, 1)) + 0.1 * np.eye(dim)  # positive definite
    y = np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(n, dim)))
    true = rng.uniform(-20, 20, size=(n, dim))
    needle, tracking = np.ones(n, bool), np.ones(n, bool)
    m = ext.sequence_metrics(tracking, true + y, true, needle, np.zeros(n, bool), cov)
    d2 = np.einsum("ni,ni->n", y, np.linalg.solve(cov, y[..., None])[..., 0])
    assert m["covered_frames"] == int(np.count_nonzero(chi2.cdf(d2, dim) <= 0.95))
    assert m["covariance_frames"] == n
    assert 0.93 <= m["covered_fraction"] <= 0.97
    small = ext.sequence_metrics(tracking, true + y, true, needle, np.zeros(n, bool), cov / 4)
    assert small["covered_fraction"] < 0.6


def test_coverage_counts_tracked_needle_frames_with_a_usable_covariance_and_pools():
    true = np.zeros((5, 2))
    est = np.array([[0.5, 0.0], [3.0, 0.0], [0.1, 0.0], [0.0, 0.0], [np.nan, np.nan]])
    cov = np.stack([np.eye(2), np.eye(2), np.full((2, 2), np.nan), -np.eye(2), np.eye(2)])
    tracking = np.array([True, True, True, True, True])
    m = ext.sequence_metrics(tracking, est, true, np.ones(5, bool), np.zeros(5, bool), cov)
    # frame 2 gives no covariance, frame 3 no positive definite one, frame 4 no tip: of the
    # two left, 0.5 mm lies inside the unit covariance's 95% region (2.45), 3 mm does not
    assert (m["covariance_frames"], m["covered_frames"]) == (2, 1)
    assert m["covered_fraction"] == pytest.approx(0.5)
    without = ext.sequence_metrics(tracking, est, true, np.ones(5, bool), np.zeros(5, bool))
    assert without["covered_fraction"] is None and without["covariance_frames"] == 0
    p = ext.pooled_metrics([m, m, without])
    assert (p["covariance_frames"], p["covered_frames"]) == (4, 2)


def test_a_tracking_report_without_a_tip_is_not_a_tracked_frame():
    true = np.array([[0.0, 10.0], [1.0, 10.0]])
    est = np.array([[0.0, 10.0], [np.nan, np.nan]])
    m = ext.sequence_metrics(np.ones(2, bool), est, true, np.ones(2, bool), np.zeros(2, bool))
    assert m["tracked_fraction"] == 0.5 and m["tip_errors_mm"] == [0.0]


def test_the_suite_runs_on_a_short_sequence(committed, tmp_path):
    name, seq = next((n, s) for n, s in committed if s.meta["needle"])
    short = synth.Sequence(**{**seq.as_dict(), **{
        k: getattr(seq, k)[:4] for k in ("images", "timestamps_s", "tip_mm", "entry_mm",
                                         "direction", "visible", "centerline_mm",
                                         "contrast_ratio")}})
    synth.save_sequence(short, tmp_path / f"{name}.npz")
    rows = []
    out = ext.run(tier="quick", seed=0, log=lambda m: None, rows=rows, directory=tmp_path)
    kinds = {r["features"] for r in rows}
    assert "classical" in kinds
    assert [r["sequence"] for r in rows if r["features"] == "classical"] == [name, "pooled"]
    keys = {"sequence", "features", "method", "probe", "tip_error_median_mm", "tip_error_p95_mm",
            "tracked_fraction", "false_tracking_fraction", "needle_frames",
            "needle_free_frames"}
    for r in rows:
        assert keys <= set(r)
        assert r["needle_frames"] == 4 and r["needle_free_frames"] == 0
        assert 0.0 <= r["tracked_fraction"] <= 1.0
    assert "| **pooled** |" in ext.markdown({"rows": rows}, {"cpu": "x", "cores": 2})
    assert out["data"] == str(tmp_path)
    # one feature kind only, as the model-choice tool asks: the same rows for that kind
    only = []
    ext.run(tier="quick", seed=0, log=lambda m: None, rows=only, directory=tmp_path,
            features=("classical",))
    assert {r["features"] for r in only} == {"classical"}
    def untimed(rs):
        return [{k: v for k, v in r.items() if not k.startswith("latency")} for r in rs]

    assert untimed(only) == untimed([r for r in rows if r["features"] == "classical"])


def test_frame_records_give_each_frames_class_status_error_and_reason():
    from needlenet.trackers._base import NeedleEstimate, Status

    seq = synth.generate("inplane", seed=4, frames=3, width_mm=20, depth_mm=25)
    seq.visible = np.array([True, True, False])
    tip = np.asarray(seq.tip_mm, float)
    est = [NeedleEstimate(t=0.0, status=Status.TRACKING, tip_mm=tip[0] + [3.0, 4.0]),
           NeedleEstimate(t=0.05, status=Status.LOST, reason="no needle: a reason"),
           NeedleEstimate(t=0.1, status=Status.TRACKING, tip_mm=tip[2])]
    tip_est = np.array([tip[0] + [3.0, 4.0], [np.nan, np.nan], tip[2]])
    recs = ext.frame_records(est, seq, tip_est)
    assert [(r["frame"], r["class"], r["status"]) for r in recs] == [
        (0, "needle", "tracking"), (1, "needle", "lost"), (2, "-", "tracking")]
    assert recs[0]["tip_error_mm"] == pytest.approx(5.0) and recs[0]["reason"] == ""
    assert recs[1]["tip_error_mm"] is None and recs[1]["reason"] == "no needle: a reason"
    assert recs[2]["tip_error_mm"] == pytest.approx(0.0)


def test_the_report_lists_every_frame(tmp_path, capsys):
    import csv

    from needlenet.cli import main

    data = tmp_path / "set"
    data.mkdir()
    synth.save_sequence(synth.generate("inplane", seed=4, frames=3, width_mm=20, depth_mm=25),
                        data / "mine.npz")
    free = synth.generate("inplane", seed=5, frames=2, width_mm=20, depth_mm=25,
                          needle_free=True)
    free.meta["needle"] = False
    synth.save_sequence(free, data / "none.npz")
    report = tmp_path / "report"
    assert main(["bench", "external", "--data", str(data), "--report", str(report)]) == 0
    capsys.readouterr()
    with open(report / "frames.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert "frames.csv" in (report / "report.md").read_text()
    kinds = sorted({r["features"] for r in rows})
    assert len(rows) == 5 * len(kinds)
    for r in rows:
        assert r["class"] == ("needle-free" if r["sequence"] == "none" else "needle")
        assert r["status"] in ("tracking", "lost", "searching")
        # a frame without a tip says why
        assert (r["tip_error_mm"] == "") == (r["status"] != "tracking") or r["class"] != "needle"
        assert (r["reason"] != "") == (r["status"] != "tracking")


def test_the_suite_is_registered():
    with pytest.raises(ValueError, match="unknown suite"):
        run_suite("externals")
    from needlenet.bench import HEADLINE, SUITES

    assert "external" in SUITES and HEADLINE["external"] == "tip_error_p95_mm"


def test_a_users_set_and_model_run_through_the_cli(tmp_path, capsys):
    from importlib import resources

    from needlenet.cli import main

    seq = synth.generate("inplane", seed=4, frames=3, width_mm=20, depth_mm=25)
    synth.save_sequence(seq, tmp_path / "mine.npz")
    model = str(resources.files("needlenet").joinpath("models", "inplane.onnx"))
    out = tmp_path / "rows.json"
    assert main(["bench", "external", "--data", str(tmp_path), "--model", model,
                 "--json", str(out)]) == 0
    import json

    rows = json.loads(out.read_text())["rows"]
    learned = [r for r in rows if r["features"] == "learned"]
    assert [r["sequence"] for r in learned] == ["mine", "pooled"]
    assert all(r["model"] == model for r in learned)
    assert all(r["model"] is None for r in rows if r["features"] == "classical")
    capsys.readouterr()


def test_labelled_plus_recordings_are_a_set_too(tmp_path, capsys):
    """A PLUS sequence whose NeedleTipToReference transforms are the labels (a tracked
    needle's recording) is measured as the same sequence file is; one without them is a
    clean error (its frames would count as needle-free)."""
    import json

    from needlenet.cli import main
    from needlenet.io import save_plus_sequence

    seq = synth.generate("inplane", seed=4, frames=4, width_mm=20, depth_mm=25)
    (tmp_path / "npz").mkdir()
    (tmp_path / "plus").mkdir()
    synth.save_sequence(seq, tmp_path / "npz" / "mine.npz")
    save_plus_sequence(seq, tmp_path / "plus" / "mine.seq.mha")
    rows = {}
    for kind in ("npz", "plus"):
        out = tmp_path / f"{kind}.json"
        assert main(["bench", "external", "--data", str(tmp_path / kind), "--json",
                     str(out)]) == 0
        rows[kind] = [r for r in json.loads(out.read_text())["rows"] if r["sequence"] == "mine"]
    keys = ("features", "tip_error_median_mm", "tracked_fraction", "needle_frames")
    assert [[r[k] for k in keys] for r in rows["plus"]] == \
        [[r[k] for k in keys] for r in rows["npz"]]
    bare = synth.Sequence(**{**seq.as_dict(), "tip_mm": None, "visible": None,
                             "direction": None, "entry_mm": None, "centerline_mm": None})
    save_plus_sequence(bare, tmp_path / "plus" / "unlabelled.seq.mha")
    capsys.readouterr()
    assert main(["bench", "external", "--data", str(tmp_path / "plus")]) == 2
    assert "unlabelled.seq.mha: no NeedleTipToReference transforms" in capsys.readouterr().err


@pytest.mark.parametrize("argv,message", [
    (["bench", "latency", "--data", "."], "--data and --model belong to the external suite"),
    (["bench", "external", "--data", "/nonexistent-dir"], "not a directory"),
    (["bench", "external", "--model", "README.md"], "cannot be loaded by onnxruntime"),
])
def test_bad_external_options_are_refused_before_work(argv, message, capsys):
    from needlenet.cli import main

    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_a_set_of_mixed_modalities_is_refused(tmp_path):
    seq = synth.generate("axial", seed=1, insertion_mm=12.0)
    synth.save_sequence(seq, tmp_path / "ax.npz")
    inplane = synth.generate("inplane", seed=4, frames=2, width_mm=20, depth_mm=25)
    synth.save_sequence(inplane, tmp_path / "a_in.npz")
    with pytest.raises(ValueError, match="ax holds a 'axial' sequence"):
        ext.run(tier="quick", log=lambda m: None, directory=tmp_path)
