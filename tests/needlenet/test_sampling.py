"""remap_points (needlenet/_sampling.py): OpenCV's bilinear samples at any number of points;
OpenCV's remap refuses maps of 32,767 pixels or more on a side."""

import cv2
import numpy as np
import pytest

from needlenet._sampling import remap_points


def test_samples_are_opencvs_own_whatever_the_layout():
    rng = np.random.default_rng(3)
    image = rng.uniform(0, 255, (60, 80)).astype(np.float32)
    cols = rng.uniform(-5, 85, (7, 300)).astype(np.float32)
    rows = rng.uniform(-5, 65, (7, 300)).astype(np.float32)
    want = cv2.remap(image, cols.reshape(1, -1), rows.reshape(1, -1), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).reshape(7, 300)
    np.testing.assert_array_equal(remap_points(image, cols, rows, cv2.BORDER_REPLICATE), want)
    assert remap_points(image, np.zeros(0), np.zeros(0)).shape == (0,)


def test_more_points_than_opencv_takes_on_a_side():
    rng = np.random.default_rng(4)
    image = rng.integers(0, 256, (50, 50), dtype=np.uint8)
    n = 100_003  # over SHRT_MAX, not a multiple of the row width
    cols, rows = rng.uniform(0, 49, n), rng.uniform(0, 49, n)
    with pytest.raises(cv2.error):
        cv2.remap(image, cols.astype(np.float32).reshape(1, -1),
                  rows.astype(np.float32).reshape(1, -1), cv2.INTER_LINEAR)
    got = remap_points(image, cols, rows)
    parts = [cv2.remap(image, cols[a:a + 10_000].astype(np.float32).reshape(1, -1),
                       rows[a:a + 10_000].astype(np.float32).reshape(1, -1),
                       cv2.INTER_LINEAR).ravel() for a in range(0, n, 10_000)]
    np.testing.assert_array_equal(got, np.concatenate(parts))


def test_a_long_line_at_a_fine_step_is_tracked(tmp_path, capsys):
    """Pixels 50 times deeper than wide: the echo strips along a line hold more samples than
    OpenCV's remap took in one row (it was a traceback)."""
    import synth
    from needlenet.cli import main

    seq = synth.generate("inplane", seed=1, frames=3, width_mm=12.0, depth_mm=10.0,
                         start_length_mm=6.0, background="homogeneous")
    p = synth.save_sequence(seq, tmp_path / "s.npz")
    for kind in ("classical", "learned"):
        assert main(["track", str(p), "--spacing", "5,0.1", "--features", kind, "--quiet"]) == 0
