"""``tools/recording_conditions.py``: copies of a labelled set as other recordings show it
(receiver noise, a depth-dependent gain, a brighter display, coarser pixels, a drawn guide),
each doing what it says and nothing else."""

from pathlib import Path

import numpy as np
import pytest

import synth
from needlenet.io._still_marks import still_marks
from tests.tools import load_tool

ROOT = Path(__file__).resolve().parents[2]
SEQ = ROOT / "needlenet" / "data" / "validation" / "val_ph_right_side_40_faint.npz"


@pytest.fixture(scope="module")
def tool():
    return load_tool("recording_conditions")


@pytest.fixture(scope="module")
def seq():
    return synth.load_sequence(SEQ)


def test_noise_has_its_sigma_and_keeps_the_black_outside(tool, seq):
    ims = np.asarray(seq.images)
    out = tool.converted(seq, "noise", 5.0, np.random.default_rng(0)).images
    on = ims > 0
    assert np.array_equal(out > 0, on)  # the sector's outside stays black, nothing else
    d = out.astype(float) - ims
    mid = on & (ims > 20) & (ims < 235)  # away from clipping
    assert np.std(d[mid]) == pytest.approx(5.0, rel=0.05)
    assert abs(np.mean(d[mid])) < 0.1


def test_ramp_changes_the_grey_level_with_depth(tool, seq):
    ims = np.asarray(seq.images).astype(float)
    out = tool.converted(seq, "ramp", 40.0, None).images.astype(float)
    rows = np.arange(ims.shape[1])
    want = -20.0 + 40.0 * rows / (ims.shape[1] - 1)
    ok = (ims > 30) & (ims < 215)
    got = np.array([np.mean((out - ims)[:, r][ok[:, r]]) if ok[:, r].any() else np.nan
                    for r in rows])
    keep = np.isfinite(got)
    np.testing.assert_allclose(got[keep], want[keep], atol=0.6)


def test_gain_scales_the_grey_levels_and_clips_at_white(tool, seq):
    ims = np.asarray(seq.images).astype(float)
    out = tool.converted(seq, "gain", 1.25, None).images.astype(float)
    on = ims > 0
    assert np.array_equal(out > 0, on)  # the sector's outside stays black
    np.testing.assert_array_equal(out[on], np.minimum(np.rint(1.25 * ims[on]), 255))
    assert np.mean(out[on] == 255) > np.mean(ims[on] == 255)  # more of the needle is white


def test_scale_keeps_every_place_in_millimetres(tool, seq):
    out = tool.converted(seq, "scale", 2.0, None)
    h, w = np.asarray(seq.images).shape[1:]
    assert out.images.shape[1:] == (round(h / 2), round(w / 2))
    np.testing.assert_allclose(out.spacing_mm, np.asarray(seq.spacing_mm) * [h / round(h / 2),
                                                                          w / round(w / 2)])
    np.testing.assert_array_equal(out.tip_mm, seq.tip_mm)
    # the first output pixel covers the first two input pixels: its centre lies half-way
    np.testing.assert_allclose(out.origin_mm,
                               np.asarray(seq.origin_mm) + 0.5 * np.asarray(seq.spacing_mm)
                               * [h / round(h / 2) - 1, w / round(w / 2) - 1])


def test_guide_copy_is_live_and_its_guide_a_still_mark(tool, seq):
    out = tool.converted(seq, "guide", 200, np.random.default_rng(1)).images
    mark = still_marks(out)
    # the guide's core, at its gray, with a few nearly covered pixels of its rim
    assert mark is not None and np.mean(out[0][mark] == 200) > 0.8
    assert out[0][mark].min() > 150
    assert still_marks(tool.converted(seq, "noise", 2.0, np.random.default_rng(1)).images) \
        is None


def test_an_existing_folder_with_files_is_refused(tool, tmp_path, capsys):
    (tmp_path / "mine.txt").write_text("a user's file")
    with pytest.raises(SystemExit):
        tool.main([str(SEQ.parent), str(tmp_path), "noise", "2"])
    assert "holds files" in capsys.readouterr().err
    assert (tmp_path / "mine.txt").read_text() == "a user's file"
