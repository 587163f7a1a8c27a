"""The tip read where echo was gained between frames (:mod:`needlenet.trackers._inplane_motion`)
and the `line` tracker's use of it where the map shows no needle line."""

from pathlib import Path

import cv2
import numpy as np
import pytest

import synth
from needlenet.features import Frame
from needlenet.trackers._inplane_motion import MotionMark, MotionTip, MotionTipParams

SPACING = 0.1
ENTRY = np.array([19.0, 2.0])  # (x, z) mm: the needle comes in at the right edge
DIRECTION = np.array([-np.cos(np.deg2rad(25.0)), np.sin(np.deg2rad(25.0))])


def _speckle(seed: int, shape=(300, 200)) -> np.ndarray:
    """Log-compressed fully developed speckle (Rayleigh amplitude, 50 dB), smoothed over a
    speckle cell, as 8-bit grey levels."""
    rng = np.random.default_rng(seed)
    iq = rng.normal(size=shape) + 1j * rng.normal(size=shape)
    env = cv2.GaussianBlur(np.abs(cv2.GaussianBlur(iq.real, (0, 0), 1.5)
                                  + 1j * cv2.GaussianBlur(iq.imag, (0, 0), 1.5)), (0, 0), 0.5)
    db = 20 * np.log10(env / env.max() + 1e-6)
    return np.clip((db + 50) / 50 * 255, 0, 255)


def _with_needle(image: np.ndarray, length_mm: float) -> np.ndarray:
    """``image`` with a bright needle echo (grey 250, 0.5 mm thick) from ``ENTRY`` along
    ``DIRECTION`` for ``length_mm``."""
    out = image.copy()
    a = ENTRY / SPACING
    b = (ENTRY + length_mm * DIRECTION) / SPACING
    cv2.line(out, tuple(int(round(v)) for v in a), tuple(int(round(v)) for v in b), 250, 5)
    return out


def _frame(image: np.ndarray, index: int) -> Frame:
    return Frame.from_image(np.clip(image, 0, 255).astype(np.uint8), SPACING, t=index / 20.0,
                            index=index)


def _peak(images):
    m = MotionTip()
    inner = np.ones(images[0].shape, bool)
    peak = None
    for i, im in enumerate(images):
        f = _frame(im, i)
        m.observe(f)
        peak = m.peak_on(f, inner, ENTRY, DIRECTION, 30.0)
    return peak


def test_the_tip_of_an_advancing_needle_is_where_echo_was_gained():
    bg = _speckle(0)
    peak = _peak([_with_needle(bg, 10.0), _with_needle(bg, 12.0)])
    tip = ENTRY + 12.0 * DIRECTION
    assert peak is not None
    assert np.linalg.norm(peak.point_mm - tip) < 0.6
    assert peak.z >= MotionTipParams().min_z
    assert peak.run_mm <= MotionTipParams().max_run_mm


def test_a_still_needle_a_needle_gone_and_the_first_frame_read_nothing():
    bg = _speckle(1)
    assert _peak([_with_needle(bg, 10.0)]) is None  # no frame before
    assert _peak([_with_needle(bg, 10.0), _with_needle(bg, 10.0)]) is None
    assert _peak([_with_needle(bg, 10.0), bg]) is None  # echo lost, none gained


def test_a_repeated_frame_keeps_the_change_read_before_it():
    """A screen capture faster than the scanner repeats frames: the tip read between the last
    two different frames is read again on the repeat."""
    bg = _speckle(5)
    first, second = _with_needle(bg, 10.0), _with_needle(bg, 12.0)
    a = _peak([first, second])
    b = _peak([first, second, second])
    assert a is not None and b is not None
    assert np.allclose(a.point_mm, b.point_mm)


def test_a_needle_that_leaves_the_plane_reads_nothing():
    """The shaft's echo lost along the line while echo is gained where its tip was (tissue its
    bevel's shadow hid): no tip advanced."""
    bg = _speckle(6)
    revealed = bg.copy()
    tip = (ENTRY + 12.5 * DIRECTION) / SPACING
    cv2.circle(revealed, tuple(int(round(v)) for v in tip), 6, 250, -1)
    assert _peak([_with_needle(bg, 10.0), revealed]) is None
    # the control: the same gain with the shaft still there is read
    assert _peak([_with_needle(bg, 10.0), _with_needle(revealed, 10.0)]) is not None


def test_a_moved_probe_reads_nothing():
    """The probe moved by 0.4 mm: the speckle and the needle's whole echo change, and no short
    run of gained echo stands out."""
    bg = _speckle(2, (320, 220))
    first = _with_needle(bg[10:310, 10:210], 10.0)
    moved = _with_needle(bg[14:314, 12:212], 10.0)
    assert _peak([first, moved]) is None


def test_a_tip_near_the_edge_of_the_view_is_not_read():
    bg = _speckle(3)
    m = MotionTip()
    inner = np.ones(bg.shape, bool)
    for i, length in enumerate((10.0, 12.0)):
        f = _frame(_with_needle(bg, length), i)
        m.observe(f)
    # the view ends 13 mm along the line: the tip at 12 mm is within edge_room_mm of it
    assert m.peak_on(f, inner, ENTRY, DIRECTION, 13.0) is None


def test_a_frame_of_another_size_starts_afresh():
    m = MotionTip()
    m.observe(_frame(_speckle(4), 0))
    f = _frame(_with_needle(_speckle(4, (200, 200)), 8.0), 1)
    m.observe(f)
    assert m.peak_on(f, np.ones((200, 200), bool), ENTRY, DIRECTION, 20.0) is None


def test_a_mark_is_taken_once_it_advances_along_its_line():
    mark = MotionMark()
    args = (4.0, 3.0, 1.0, 40.0, 0.075)  # window deg, mm, growth mm, speed mm/s, gap s
    tip = ENTRY + 8.0 * DIRECTION
    assert not mark.advanced(0.0, ENTRY, DIRECTION, tip, *args)  # first sighting
    assert not mark.advanced(0.05, ENTRY, DIRECTION, tip + 0.3 * DIRECTION, *args)  # still
    assert mark.advanced(0.10, ENTRY, DIRECTION, tip + 1.5 * DIRECTION, *args)
    mark.clear()
    mark.advanced(0.0, ENTRY, DIRECTION, tip, *args)
    assert not mark.advanced(0.05, ENTRY, DIRECTION, tip + 9.0 * DIRECTION, *args)  # too fast
    mark.clear()
    mark.advanced(0.0, ENTRY, DIRECTION, tip, *args)
    mark.clear()
    mark.advanced(0.0, ENTRY, DIRECTION, tip, *args)
    assert not mark.advanced(0.2, ENTRY, DIRECTION, tip + 1.5 * DIRECTION, *args)  # not the
    # frame before
    mark.clear()
    mark.advanced(0.0, ENTRY, DIRECTION, tip, *args)
    other = np.array([-DIRECTION[1], DIRECTION[0]])
    assert not mark.advanced(0.05, ENTRY, DIRECTION, tip + 1.5 * DIRECTION + 4.0 * other, *args)


def test_params_are_checked():
    with pytest.raises(ValueError, match="band_mm"):
        MotionTipParams(band_mm=0.0)
    with pytest.raises(ValueError, match="min_z"):
        MotionTipParams(min_z=-1.0)


def test_breathing_tissue_beside_an_interface_reads_no_tip():
    """synth's world 100 with no needle, a bright interface and breathing tissue (2 mm): along
    the interface's line no gain of echo is read as a tip on any frame."""
    seq = synth.generate("inplane", seed=100, frames=12, needle_free=True,
                         tissue_motion_mm=2.0, interface_offset_mm=2.5)
    m = MotionTip()
    grid = seq.grid()
    inner = np.ones(seq.images.shape[1:], bool)
    # every line through the frame at the needle's angles, from the right edge
    x1 = grid.origin_mm[1] + (seq.images.shape[2] - 1) * grid.spacing_mm[1]
    starts = [np.array([x1, z]) for z in np.arange(2.0, 30.0, 2.0)]
    reads = 0
    for i in range(seq.images.shape[0]):
        f = Frame(seq.images[i], grid, t=float(seq.timestamps_s[i]), index=i)
        m.observe(f)
        for a in (20.0, 35.0, 50.0):
            d = np.array([-np.cos(np.deg2rad(a)), np.sin(np.deg2rad(a))])
            for s in starts:
                reads += m.peak_on(f, inner, s, d, 30.0) is not None
    assert reads == 0


SEQ = (Path(__file__).resolve().parents[2] / "needlenet" / "data" / "validation"
       / "val_lin_right_side_20_interface.npz")


def test_a_needle_merged_with_an_interface_is_tracked_by_the_echo_it_gains():
    """PyMUST's ``val_lin_right_side_20_interface`` (18 G at 20 degrees under a bright
    interface 2.5 mm above it): the map merges the two into one line across the view, which
    shows no tip; the needle's advance shows where its tip is."""
    pytest.importorskip("onnxruntime")
    from needlenet.trackers import Status, make_tracker

    seq = synth.load_sequence(SEQ)
    est = make_tracker("inplane", "line", "learned", seed=0).run(seq)
    tracked = [i for i, e in enumerate(est) if e.status == Status.TRACKING]
    assert len(tracked) >= 6
    assert sum(est[i].details.tip_from_motion for i in tracked) >= 5
    err = [np.linalg.norm(est[i].tip_mm - seq.tip_mm[i]) for i in tracked]
    assert max(err) < 2.5
