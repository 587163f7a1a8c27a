"""Coloured marks drawn over a gray B-mode image are filled in from the echo around them; gray
and tinted images are read as their luma, unchanged."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from needlenet.io import load_recording
from needlenet.io._colour_marks import MAX_SHARE, colour_marks, fill_colour_marks
from needlenet.io._frames import _gray
from needlenet.io._gray import to_gray_uint8

DATA = Path(__file__).resolve().parents[2] / "needlenet" / "data" / "validation"


def _speckle(seed: int, shape=(200, 240)) -> np.ndarray:
    """Log-compressed Rayleigh speckle, 8-bit gray (mean about 70)."""
    rng = np.random.default_rng(seed)
    env = np.abs(rng.normal(size=shape) + 1j * rng.normal(size=shape))
    env = cv2.GaussianBlur(env, (0, 0), 1.0)
    db = 20 * np.log10(env / env.mean() + 1e-6)
    return np.clip(70 + 4.0 * db, 0, 255).astype(np.uint8)


def _dashed_guide(bgr: np.ndarray, colour, p0, p1, dashes: int = 30) -> np.ndarray:
    """A scanner's dotted biopsy guide from ``p0`` to ``p1`` (pixels, x then y)."""
    out = bgr.copy()
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    for k in range(dashes):
        a = p0 + (p1 - p0) * k / dashes
        b = p0 + (p1 - p0) * (k + 0.5) / dashes
        cv2.line(out, tuple(int(v) for v in a), tuple(int(v) for v in b), colour, 2, cv2.LINE_AA)
    return out


def test_gray_frame_stored_as_colour_reads_as_its_luma():
    g = _speckle(1)
    bgr = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)
    np.testing.assert_array_equal(_gray(bgr), g)
    assert not colour_marks(bgr).any()


def test_green_guide_is_filled_with_the_tissue_around_it():
    g = _speckle(2)
    bgr = _dashed_guide(cv2.cvtColor(g, cv2.COLOR_GRAY2BGR), (0, 255, 0), (200, 0), (40, 190))
    drawn = np.any(bgr != cv2.cvtColor(g, cv2.COLOR_GRAY2BGR), axis=2)
    plain = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    filled = _gray(bgr)
    # converted to gray alone, the guide is a line far brighter than the tissue (green's luma
    # is 150); filled in, it reads as the tissue does
    assert plain[drawn].mean() > g.mean() + 20
    assert abs(float(filled[drawn].mean()) - float(g.mean())) < 0.15 * g.mean()
    np.testing.assert_array_equal(filled[~cv2.dilate(drawn.view(np.uint8), np.ones((9, 9)))
                                         .astype(bool)], g[~cv2.dilate(
                                             drawn.view(np.uint8), np.ones((9, 9))).astype(bool)])


def test_tinted_display_map_is_read_as_its_luma():
    g = _speckle(3).astype(np.float32)
    # a sepia map: every pixel coloured, none saturated
    sepia = np.stack([0.75 * g, 0.88 * g, g], axis=-1).astype(np.uint8)  # BGR
    assert not colour_marks(sepia).any()
    np.testing.assert_array_equal(_gray(sepia), cv2.cvtColor(sepia, cv2.COLOR_BGR2GRAY))


def test_frame_mostly_coloured_is_left_alone():
    g = _speckle(4)
    bgr = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)
    h = int(np.ceil(MAX_SHARE * g.shape[0])) + 10
    bgr[:h, :, 0] = 0  # a colour Doppler box over the top rows: saturated yellow-ish
    bgr[:h, :, 1:] = 200
    luma = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    assert colour_marks(bgr).mean() > MAX_SHARE
    np.testing.assert_array_equal(fill_colour_marks(luma, bgr), luma)


def test_rgb_arrays_and_bgr_images_are_filled_alike():
    g = _speckle(5)
    bgr = _dashed_guide(cv2.cvtColor(g, cv2.COLOR_GRAY2BGR), (0, 255, 255), (10, 10), (230, 150))
    rgb = bgr[..., ::-1]
    from_array, _, _ = to_gray_uint8(np.ascontiguousarray(rgb)[None], 3)
    diff = np.abs(from_array[0].astype(int) - _gray(bgr).astype(int))
    assert diff.max() <= 2  # the two luma roundings


def test_drawn_guide_over_a_needle_free_recording_is_not_a_needle(tmp_path):
    """The needle-free PyMUST validation sequence with a green dotted guide drawn from the
    probe face: converted to gray alone, the learned line tracker tracked the guide on every
    frame; with the marks filled in it sees no needle."""
    pytest.importorskip("onnxruntime")
    from needlenet.trackers import Status, make_tracker

    d = np.load(DATA / "val_lin_no_needle.npz")
    H, W = d["images"].shape[1:]
    for t, f in enumerate(d["images"]):
        bgr = _dashed_guide(cv2.cvtColor(f, cv2.COLOR_GRAY2BGR), (0, 255, 0),
                            (0.85 * W, 0), (0.25 * W, 0.8 * H), dashes=40)
        cv2.imwrite(str(tmp_path / f"f{t:03d}.png"), bgr)
    seq = load_recording(tmp_path, spacing_mm=0.1, fps=20.0)
    est = make_tracker("inplane", "line", "learned", seed=0).run(seq)
    assert not any(e.status == Status.TRACKING for e in est)
