"""The model-choice tool (``tools/choose_model.py``): its score and its post-processed copies."""

from pathlib import Path

import numpy as np
import pytest

import synth
from tests.tools import load_tool

ROOT = Path(__file__).resolve().parents[2]


def _tool():
    return load_tool("choose_model")


def test_the_volume_score_counts_good_wrong_and_needle_free_volumes():
    pytest.importorskip("onnxruntime")
    from needlenet.bench import _external

    rows = _external.run(directory=ROOT / "needlenet" / "data" / "validation_volume",
                         features=("learned",), log=lambda *a: None)["rows"]
    assert {r["features"] for r in rows} == {"learned"}
    pooled = next(r for r in rows if r["sequence"] == "pooled")
    per = [r for r in rows if r["sequence"] != "pooled"]
    needle = sum(r["needle_frames"] for r in per if r.get("needle_frames"))
    good = sum(r["within_3mm_frames"] for r in per)
    wrong = sum(r["wrong_frames"] for r in per)
    expected = (good - wrong) / needle - pooled["false_tracking_fraction"]
    score, false = _tool().score_set(ROOT / "needlenet" / "data" / "validation_volume", None)
    assert score == pytest.approx(expected)
    assert false == pooled["false_tracking_fraction"]
    assert needle == 18 and -1.0 <= score <= 1.0


def _one_sequence_set(tmp_path, seed: int):
    """A set (folder) holding one small seeded in-plane sequence ``a.npz``: (folder, sequence)."""
    src = tmp_path / "src"
    src.mkdir()
    seq = synth.generate("inplane", seed=seed, frames=2, width_mm=12, depth_mm=12)
    synth.save_sequence(seq, src / "a.npz")
    return src, seq


def test_post_processed_copies_are_written_once(tmp_path):
    src, seq = _one_sequence_set(tmp_path, 3)
    tool = _tool()
    dirs = tool.postprocessed_copies(src, tmp_path / "work")
    assert [d.name for d in dirs] == list(tool.COPIES)
    stamps = [(d / "a.npz").stat().st_mtime_ns for d in dirs]
    for d in dirs:
        copy = synth.load_sequence(d / "a.npz")
        assert copy.images.shape == seq.images.shape and copy.images.dtype == np.uint8
        assert np.array_equal(copy.tip_mm, seq.tip_mm)
        assert np.mean(copy.images != seq.images) > 0.05
    tool.postprocessed_copies(src, tmp_path / "work")
    assert [(d / "a.npz").stat().st_mtime_ns for d in dirs] == stamps


def test_recording_condition_copies_are_written_once_as_the_tool_writes_them(tmp_path):
    src, _ = _one_sequence_set(tmp_path, 4)
    tool = _tool()
    dirs = tool.condition_copies(src, tmp_path / "work")
    assert [d.name for d in dirs] == [name for name, _, _ in tool.CONDITIONS]
    rc = load_tool("recording_conditions")
    for d, (_, op, value) in zip(dirs, tool.CONDITIONS, strict=True):
        out = tmp_path / f"by_tool_{d.name}"
        assert rc.main([str(src), str(out), op, str(value)]) == 0
        a, b = synth.load_sequence(d / "a.npz"), synth.load_sequence(out / "a.npz")
        np.testing.assert_array_equal(a.images, b.images)
        np.testing.assert_allclose(a.spacing_mm, b.spacing_mm)
    stamps = [(d / "a.npz").stat().st_mtime_ns for d in dirs]
    tool.condition_copies(src, tmp_path / "work")
    assert [(d / "a.npz").stat().st_mtime_ns for d in dirs] == stamps
