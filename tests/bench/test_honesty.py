"""``needlenet bench honesty`` (issue 21's needle-free protocol, and recordings without a
needle from their start): the per-world figures from hand-made runs, the protocol's sequence,
and the demo tier end to end."""

import json
from types import SimpleNamespace

import numpy as np

from needlenet.bench._honesty import (
    FRAMES,
    GAP,
    REACQUIRE_FRAMES,
    protocol_sequence,
    world_metrics,
)
from needlenet.bench._runner import run_suite


def _run(tip, tracking, offsets):
    """Estimates at ``tip + offsets`` (mm along x) where ``tracking``."""
    return [SimpleNamespace(status="tracking" if on else "lost",
                            tip_mm=(t + np.array([d, 0.0])) if on else None)
            for t, on, d in zip(tip, tracking, offsets, strict=True)]


def _truth():
    tip = np.stack([np.linspace(10, 40, FRAMES), np.linspace(5, 30, FRAMES)], axis=1)
    tip[GAP[0]:GAP[1]] = np.nan
    return SimpleNamespace(tip_mm=tip)


def test_world_metrics_count_false_tracking_and_the_return():
    seq = _truth()
    tracking = np.ones(FRAMES, bool)
    tracking[GAP[0]:GAP[0] + 10] = False  # 20 of the 30 needle-free frames `tracking`
    offsets = np.zeros(FRAMES)
    offsets[GAP[1]:GAP[1] + 4] = 5.0  # 5 mm off for 4 frames after the return
    offsets[:40] = 3.0  # frames 0-39 off; 30-39 are 10 of the 25 frames "held" is read on
    m = world_metrics(_run(seq.tip_mm, tracking, offsets), seq)
    assert m["false_tracking"] == 20 and m["needle_free_frames"] == 30
    assert m["reacquire_frames"] == 4
    assert m["held_before"]  # 15 of frames 30-54 within 2 mm
    assert m["within_before"] == GAP[0] - 40
    assert m["within_after"] == FRAMES - GAP[1] - 4


def test_a_needle_never_seen_again_or_never_held():
    seq = _truth()
    tracking = np.zeros(FRAMES, bool)
    tracking[:20] = True
    m = world_metrics(_run(seq.tip_mm, tracking, np.zeros(FRAMES)), seq)
    assert m["reacquire_frames"] is None and not m["held_before"]
    assert m["false_tracking"] == 0 and m["within_after"] == 0


def test_protocol_sequence_holds_no_needle_in_the_gap():
    import synth

    seq = protocol_sequence(11)
    free = synth.generate("inplane", seed=11, frames=FRAMES, speed_mm_s=5.0, needle_free=True)
    full = synth.generate("inplane", seed=11, frames=FRAMES, speed_mm_s=5.0)
    a, b = GAP
    np.testing.assert_array_equal(seq.images[a:b], free.images[a:b])
    np.testing.assert_array_equal(seq.images[:a], full.images[:a])
    assert not seq.visible[a:b].any() and seq.visible[:a].all()
    assert np.isnan(seq.tip_mm[a:b]).all() and np.isfinite(seq.tip_mm[b:]).all()


def test_demo_tier(tmp_path):
    res = run_suite("honesty", tier="demo", json_out=tmp_path / "h.json", log=lambda m: None)
    rows = json.loads((tmp_path / "h.json").read_text())["rows"]
    assert {(r["method"], r["features"]) for r in rows} == {
        (m, k) for m in ("line", "kf+f", "df") for k in ("classical", "learned")}
    by = {(r["method"], r["features"]): r for r in rows}
    # the default tracker on world 11: no needle-free frame `tracking`, the needle back at once
    line = by[("line", "learned")]
    assert line["false_tracking"] == 0 and line["reacquired"] == 1
    assert line["reacquire_frames"][0] < REACQUIRE_FRAMES
    # DF on the learned maps: its axis on the needle's centre line, its tip at the tip map's
    # peak, so the returning needle's tip is within 2 mm on DF's first reported frame
    df = by[("df", "learned")]
    assert df["false_tracking"] == 0 and df["reacquire_frames"][0] <= 1
    assert "needle-free `tracking`" in res["markdown"]
    # world 100 without a needle from its first frame: nothing `tracking` on it
    assert line["recording_false_tracking"] == 0 and line["recording_frames"] == 30
    assert "needle-free recordings `tracking`" in res["markdown"]
    # and with its tissue breathing under a still probe
    assert line["breathing_false_tracking"] == 0
    assert "breathing" in res["markdown"]

