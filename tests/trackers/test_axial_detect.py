"""The axial detector takes a compact spot that stands out of the slice's other spots: a
needle cut across, not an interface cut across (a line) nor the best of many speckle spots."""

from pathlib import Path

import numpy as np
import pytest

import synth
from needlenet.trackers._cross_section import compact_spots, is_compact

VAL = Path(__file__).resolve().parents[2] / "needlenet" / "data" / "validation_axial"


def _gauss(shape, rc, sigma):
    r, c = np.mgrid[:shape[0], :shape[1]]
    return np.exp(-((r - rc[0]) ** 2 + (c - rc[1]) ** 2) / (2 * sigma ** 2))


def test_a_brighter_interface_is_no_spot_and_the_needle_is():
    shape, spacing = (120, 120), (0.2, 0.2)
    needle = _gauss(shape, (50, 60), 3.0)
    r = np.arange(shape[0])[:, None]
    interface = 1.6 * np.exp(-((r - 80) ** 2) / (2 * 3.0 ** 2)) * np.ones((1, shape[1]))
    S = (needle + interface).astype(np.float32)
    spots, z = compact_spots(S, 0.0, 0.01, spacing, 2.0, 0.5, 2.0)
    assert spots[0] == (50, 60)
    assert all(abs(s[0] - 80) > 5 for s in spots)  # no spot on the interface
    assert is_compact(S, (50.0, 60.0), 0.0, 0.01, spacing, 2.0, 0.5)
    assert not is_compact(S, (80.0, 30.0), 0.0, 0.01, spacing, 2.0, 0.5)


def test_spots_are_suppressed_within_the_separation():
    shape, spacing = (100, 100), (0.2, 0.2)
    S = (_gauss(shape, (40, 40), 2.0) + 0.9 * _gauss(shape, (40, 48), 2.0)  # 1.6 mm apart
         + 0.5 * _gauss(shape, (70, 70), 2.0)).astype(np.float32)
    spots, _ = compact_spots(S, 0.0, 0.01, spacing, 1.0, 0.5, 2.0)
    assert spots[0] == (40, 40)
    assert spots[1] == (70, 70)


@pytest.mark.parametrize("name, kind", [("axv_ph_no_needle", "classical"),
                                        ("axv_ph_17", "classical"),
                                        ("axv_ph_no_needle", "learned"),
                                        ("axv_ph_20_interface", "learned")])
def test_axial_reports_no_needle_where_there_is_none(name, kind):
    """PyMUST P4-2v validation slices. Classical: past the tip (and in the needle-free
    sequence) the best spot of the smoothed variance map scores 18-25, above the detection
    score the synth slices set, but is one of many alike (ratio 1.01-1.03 to the next); it was
    reported `tracking` on every such slice, and the needle-free sequence's interface on every
    slice. Learned: the shipped model marks the sector's edge, and a spot within a millimetre
    of it was tracked on 29 of 30 needle-free slices and on every slice of the interface
    sequence, 5.7 mm from its needle."""
    from needlenet.trackers import Status, make_tracker

    seq = synth.load_sequence(VAL / f"{name}.npz")
    visible = np.asarray(seq.visible, bool)
    est = make_tracker("axial", "carriere", kind, seed=0).run(seq)
    tracking = np.array([e.status == Status.TRACKING for e in est])
    # two slices past the tip may be coasted at the ROI (max_coast_frames), then lost
    assert tracking[~visible].sum() <= (2 if visible.any() else 0)
    err = [np.linalg.norm(e.tip_mm - t) for e, t in zip(est, seq.tip_mm, strict=True)
           if e.tip_mm is not None and np.all(np.isfinite(t))]
    assert all(v < 1.5 for v in err)
    if kind == "classical" and visible.any():
        assert tracking[visible].all()


def test_classical_axial_takes_the_needle_not_the_interface_below_it():
    from needlenet.trackers import make_tracker

    seq = synth.load_sequence(VAL / "axv_ph_20_interface.npz")
    visible = np.asarray(seq.visible, bool)
    est = make_tracker("axial", "carriere", "classical", seed=0).run(seq)
    err = [np.linalg.norm(e.tip_mm - t) for e, t, v in zip(est, seq.tip_mm, visible, strict=True)
           if v and e.tip_mm is not None]
    assert len(err) == visible.sum()
    assert np.median(err) < 0.5  # the interface lies about 2.5 mm below the needle
