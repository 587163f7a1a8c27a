"""A needle whose tip has left the view runs on across it: the line tracker reports it `lost`
and takes no other line for it while its line is seen running out (one needle is there)."""

import numpy as np
import pytest

import synth


def _track(seed: int, start_length_mm: float, exits: int, model: str | None = None):
    """A 40-frame synth insertion whose tip leaves the view on frame ``exits``, tracked with
    learned features (``model``, default the shipped one): (sequence, visible, tracking,
    estimates)."""
    pytest.importorskip("onnxruntime")
    from needlenet.trackers import Status, make_tracker

    seq = synth.generate("inplane", seed=seed, frames=40, start_length_mm=start_length_mm)
    visible = np.asarray(seq.visible, bool)
    assert visible[:exits].all() and not visible[exits:].any()
    est = make_tracker("inplane", "line", "learned", model, seed=0).run(seq)
    tracking = np.array([e.status == Status.TRACKING for e in est])
    return seq, visible, tracking, est


def test_needle_running_out_of_view_is_lost_and_no_tissue_line_is_taken_for_it():
    # 14 G from the top right at 45 degrees, leaving through the left edge. The track
    # forgotten after five frames of the needle running edge to edge, a 5 mm tissue line near
    # the entry was taken for a new needle (frames 32, 33 and 39).
    _, visible, tracking, est = _track(13, 35.0, 31)
    assert tracking[:20].all()
    assert not tracking[~visible].any()
    assert all(e.status.value == "lost" for e in est[31:])


def test_needle_fading_on_the_map_before_the_edge_is_lost_once_its_tip_leaves(
        base_inplane_model):
    # 14 G from the top right at 35 degrees. The shaft map's confident evidence ends 3 mm
    # before the left edge (the needle fades on the map at 26 mm depth) and its weaker
    # continuation runs on to the edge: the segment's end stood still there as a tip, 3-24 mm
    # behind the needle's, on every frame from 11 on.
    # (the maps of the model the rule was built on, which showed it)
    seq, visible, tracking, est = _track(21, 40.0, 12, base_inplane_model)
    assert tracking[:5].all()
    assert not tracking[~visible].any()
    err = [np.linalg.norm(e.tip_mm - t)
           for e, t in zip(est, seq.tip_mm, strict=True) if e.tip_mm is not None]
    assert max(err) < 1.0
