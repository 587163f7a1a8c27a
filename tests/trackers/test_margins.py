"""The imaged region of a frame: a blank area is margin only where it runs along the border for
MARGIN_ALONG_MM, and the whole frame is read only when the border's blank pixels reach that
length in all (the same region as reading it every time)."""

import cv2
import numpy as np
import pytest

import synth
from needlenet.features import Frame
from needlenet.trackers import _margins as m


def _read_everything(frame: Frame) -> np.ndarray:
    """The region with every blank test that touches the border read over the whole frame."""
    im = np.asarray(frame.image)
    blank = np.zeros(im.shape, bool)
    for level, k in m._boxes(frame):
        full = m._blank(im, level, k)
        if full[0].any() or full[-1].any() or full[:, 0].any() or full[:, -1].any():
            blank |= full
    if not blank.any():
        return np.ones(im.shape, bool)
    _, labels = cv2.connectedComponents(blank.astype(np.uint8), connectivity=4)
    return ~np.isin(labels, m._margins(labels, frame.grid.spacing_mm))


def _speckle(rng, shape):
    return rng.gamma(2.0, 40.0, shape).clip(1, 255).astype(np.uint8)


@pytest.mark.parametrize("seed", range(12))
def test_the_region_is_the_one_read_over_the_whole_frame(seed):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(120, 400, 2)
    sp = float(rng.choice([0.05, 0.1, 0.2]))
    image = _speckle(rng, (h, w))
    for _ in range(int(rng.integers(1, 4))):  # black notches at the border, 1-12 mm along it
        n = max(int(rng.uniform(1.0, 12.0) / sp), 1)
        d = int(rng.integers(2, 40))
        side = int(rng.integers(4))
        at = int(rng.integers(0, max(h, w)))
        if side == 0:
            image[:d, at:at + n] = 0
        elif side == 1:
            image[-d:, at:at + n] = 0
        elif side == 2:
            image[at:at + n, :d] = 0
        else:
            image[at:at + n, -d:] = 0
    if seed % 3 == 0:  # a lossy capture: the black a few grey levels up
        image = cv2.imdecode(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 40])[1], 0)
    frame = Frame(image, synth.Grid((h, w), (sp, sp), (0.0, 0.0)))
    np.testing.assert_array_equal(m.imaged_region(frame), _read_everything(frame))


@pytest.mark.parametrize("along_mm, margin", [(4.0, False), (6.0, True)])
def test_a_black_notch_at_the_border_is_margin_once_it_runs_along_it_far_enough(along_mm, margin):
    rng = np.random.default_rng(3)
    image = _speckle(rng, (200, 300))
    n = int(round(along_mm / 0.1))
    image[:30, 100:100 + n] = 0  # 3 mm deep, along the top border
    region = m.imaged_region(Frame(image, synth.Grid(image.shape, (0.1, 0.1), (0.0, 0.0))))
    assert (not region[10, 100 + n // 2]) == margin
    assert region[100:, :].all()


def _border_rows_by_cv2(im, level, k):
    """The border's blank pixels read off OpenCV's box filter of each border strip."""
    kx, kz = min(k[0], im.shape[1]), min(k[1], im.shape[0])
    return (m._blank(im[:kz], level, k)[0], m._blank(im[-kz:], level, k)[-1],
            m._blank(im[:, :kx], level, k)[:, 0], m._blank(im[:, -kx:], level, k)[:, -1])


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64])
def test_the_border_test_counts_as_opencvs_box_filter(dtype):
    """The compiled border count gives the blank pixels OpenCV's box filter gives, on frames
    from 1 pixel to larger than the box, boxes wider or taller than the frame (reflected more
    than once), black levels 0 and 12, and boxes whose size is or is not a multiple of 5."""
    rng = np.random.default_rng(int(np.dtype(dtype).num))
    for _ in range(400):
        h, w = rng.integers(1, 90, 2)
        im = rng.gamma(0.5, 20.0, (h, w)).clip(0, 255)
        im[rng.random((h, w)) < rng.random()] = 0
        im = im.astype(dtype)
        level = float(rng.choice([0.0, 12.0]))
        k = (int(rng.integers(1, 30)) | 1, int(rng.integers(1, 30)) | 1)
        for a, b in zip(m._border_blank(im, level, k), _border_rows_by_cv2(im, level, k),
                        strict=True):
            np.testing.assert_array_equal(a, b)
