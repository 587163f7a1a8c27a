"""Gray marks drawn over a live recording (pixel-identical in every frame while the echo
changes) are found and filled in from the echo around them; recordings that are not live,
black margins and saturated echo are left as they are."""

import dataclasses

import cv2
import numpy as np

import synth
from needlenet.io import load_recording
from needlenet.io._still_marks import FRAMES, LIVE_SHARE, fill_still_marks, still_marks
from needlenet.trackers import make_tracker


def _live(seed: int, frames: int = 10, shape=(200, 240)) -> np.ndarray:
    """A still speckle pattern (log-compressed Rayleigh, mean about 70) under receiver noise of
    2 gray levels, new in every frame: a live recording of still tissue."""
    rng = np.random.default_rng(seed)
    env = np.abs(rng.normal(size=shape) + 1j * rng.normal(size=shape))
    env = cv2.GaussianBlur(env, (0, 0), 1.0)
    base = 70 + 4.0 * 20 * np.log10(env / env.mean() + 1e-6)
    noisy = base[None] + rng.normal(0.0, 2.0, (frames, *shape))
    return np.clip(np.rint(noisy), 1, 254).astype(np.uint8)


def _guide(frames: np.ndarray, value: int = 200, dashes: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """``frames`` with a dotted biopsy guide drawn in gray over every frame, and the mask of
    the pixels drawn."""
    h, w = frames.shape[1:]
    p0, p1 = np.array([0.85 * w, 0.0]), np.array([0.2 * w, 0.9 * h])
    drawn = np.zeros((h, w), np.uint8)
    for k in range(dashes):
        a = tuple(int(v) for v in p0 + (p1 - p0) * k / dashes)
        b = tuple(int(v) for v in p0 + (p1 - p0) * (k + 0.5) / dashes)
        cv2.line(drawn, a, b, 255, 2, cv2.LINE_AA)
    a = drawn.astype(np.float64) / 255.0  # the anti-aliased edge blends with the echo
    out = np.rint(frames * (1.0 - a) + value * a).astype(np.uint8)
    return out, drawn >= 128


def test_gray_guide_over_a_live_recording_is_found_and_filled():
    clean = _live(1)
    marked, drawn = _guide(clean)
    mark = still_marks(marked)
    assert mark is not None
    # the guide's opaque core, and nothing away from it; with the one-pixel rim filled too,
    # every pixel drawn at half cover or more (the rim blends the changing echo in)
    rim = cv2.dilate(mark.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert np.count_nonzero(rim & drawn) >= 0.98 * np.count_nonzero(drawn)
    assert not np.any(mark & ~drawn)
    meta: dict = {}
    filled = fill_still_marks(marked, meta)
    assert meta["still_marks_px"] == int(mark.sum()) and "biopsy guide" in meta["warnings"][0]
    # filled in, the guide reads as the tissue: within 10% of the frame's mean, not 200
    assert abs(float(filled[:, drawn].mean()) - float(clean.mean())) < 0.1 * clean.mean()
    assert marked[:, drawn].mean() > clean.mean() + 60
    # pixels away from the guide and its one-pixel rim are not touched
    far = ~cv2.dilate(drawn.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    np.testing.assert_array_equal(filled[:, far], marked[:, far])


def test_gray_panel_of_an_uncropped_capture_does_not_hide_a_guide():
    marked, drawn = _guide(_live(8))
    T, h, w = marked.shape
    capture = np.full((T, h + 60, w + 200), 48, np.uint8)  # a screen's gray panel
    capture[:, 30:30 + h, 100:100 + w] = marked
    mark = still_marks(capture)
    assert mark is not None
    inside = np.zeros(capture.shape[1:], bool)
    inside[30:30 + h, 100:100 + w] = drawn
    rim = cv2.dilate(mark.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert np.count_nonzero(rim & inside) >= 0.98 * np.count_nonzero(inside)
    # the panel itself is no mark: at most its one-pixel border along the image
    panel = np.ones(capture.shape[1:], bool)
    panel[29:31 + h, 99:101 + w] = False
    assert not np.any(mark & panel)


def test_thick_solid_guide_is_a_mark_too():
    clean = _live(9)
    marked = clean.copy()
    marked[:, 60:65, 20:120] = 180  # a solid line 5 pixels thick
    mark = still_marks(marked)
    assert mark is not None and mark[60:65, 20:120].all()


def test_scattered_still_echo_of_many_levels_is_no_mark():
    frames = _live(10)
    rng = np.random.default_rng(10)
    # a few still pixels of assorted bright levels, as a simulation without noise leaves on
    # an interface that every slice shows alike
    rows, cols = rng.integers(20, 180, 12), rng.integers(20, 220, 12)
    frames[:, rows, cols] = rng.integers(200, 255, 12).astype(np.uint8)
    frames[:, 100, 100:104] = np.array([230, 241, 236, 250], np.uint8)
    assert still_marks(frames) is None


def test_recording_that_is_not_live_is_left_alone():
    # a simulation of still tissue: frames identical but for the marks' absence of noise
    still = np.repeat(_live(2)[:1], 10, axis=0)
    marked, _ = _guide(still)
    assert still_marks(marked) is None
    meta: dict = {}
    assert fill_still_marks(marked, meta) is marked and meta == {}


def test_live_recording_without_marks_is_left_alone():
    frames = _live(3)
    assert still_marks(frames) is None


def test_black_margin_and_saturated_echo_are_not_marks():
    frames = _live(4)
    frames[:, :, :20] = 0  # a black capture margin
    frames[:, 100:104, 60:180] = 255  # a saturated shaft, clipped to white in every frame
    assert still_marks(frames) is None


def test_too_few_frames_or_too_many_still_pixels_find_nothing():
    marked, _ = _guide(_live(5, frames=FRAMES - 1))
    assert still_marks(marked) is None
    frames = _live(6)
    h = int(np.ceil(2 * LIVE_SHARE * frames.shape[1]))
    frames[:, :h] = frames[0, :h]  # a still block as big as a codec's copied region
    assert still_marks(frames) is None


def test_folder_of_frames_is_filled_as_it_is_read(tmp_path):
    marked, drawn = _guide(_live(7))
    for k, f in enumerate(marked):
        cv2.imwrite(str(tmp_path / f"f{k:02d}.png"), f)
    seq = load_recording(tmp_path, spacing_mm=0.1, fps=20.0)
    assert seq.meta["still_marks_px"] == int(still_marks(marked).sum())
    np.testing.assert_array_equal(np.asarray(seq.images), fill_still_marks(marked, {}))


def test_tracker_does_not_take_a_drawn_guide_for_a_needle(tmp_path):
    seq = synth.generate("inplane", seed=1, frames=10, needle_free=True)
    rng = np.random.default_rng(1)
    ims = np.asarray(seq.images, np.float32)
    live = np.clip(np.rint(ims + rng.normal(0.0, 2.0, ims.shape)), 1, 254).astype(np.uint8)
    marked, _ = _guide(live, value=230, dashes=40)
    path = tmp_path / "guide.npz"
    synth.save_sequence(dataclasses.replace(seq, images=marked), path)

    def tracking(s) -> int:
        est = make_tracker("inplane", "line", "learned", seed=0).run(s)
        return sum(e.status.value == "tracking" for e in est)

    # the same frames without the guide: no needle on any frame
    assert tracking(dataclasses.replace(seq, images=live)) == 0
    assert tracking(synth.load_sequence(path)) >= 5  # read as it was drawn: a needle
    assert tracking(load_recording(path)) == 0
