"""NRRD through pynrrd, image folders and videos through OpenCV, sidecars, crop."""

import json

import cv2
import nrrd
import numpy as np
import pytest

from needlenet.io import RecordingError, load_recording


def _rng(seed):
    return np.random.default_rng(seed)


def test_slicer_style_volume_sequence(tmp_path):
    vol = _rng(0).integers(0, 256, (3, 6, 5, 9), dtype=np.uint8)  # (T, depth, elev, lateral)
    data = np.transpose(vol, (0, 3, 2, 1))  # NRRD axes: list, x (lateral), y, z (depth)
    hdr = {"type": "unsigned char", "dimension": 4, "space": "right-anterior-superior",
           "kinds": ["list", "domain", "domain", "domain"],
           "space directions": np.array([[np.nan] * 3, [0.2, 0, 0], [0, 0.5, 0], [0, 0, 0.3]]),
           "space origin": np.array([3.0, 2.0, 1.0]),
           "axis 0 index type": "numeric", "axis 0 index values": "0 0.25 0.5"}
    nrrd.write(str(tmp_path / "v.seq.nrrd"), data, hdr, index_order="F")
    seq = load_recording(tmp_path / "v.seq.nrrd")
    assert seq.modality == "volume"
    np.testing.assert_array_equal(seq.images, vol)
    np.testing.assert_allclose(seq.spacing_mm, [0.3, 0.5, 0.2])
    np.testing.assert_allclose(seq.origin_mm, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(seq.timestamps_s, [0.0, 0.25, 0.5])


def test_2d_sequence_with_spacings_and_a_trailing_list_axis(tmp_path):
    frames = _rng(1).integers(0, 256, (4, 7, 10), dtype=np.uint8)  # (T, depth, lateral)
    hdr = {"kinds": ["domain", "domain", "list"], "spacings": [0.1, 0.2, np.nan]}
    nrrd.write(str(tmp_path / "f.nrrd"), np.transpose(frames, (2, 1, 0)), hdr, index_order="F")
    seq = load_recording(tmp_path / "f.nrrd", modality="axial", fps=20)
    assert seq.modality == "axial"
    np.testing.assert_array_equal(seq.images, frames)
    np.testing.assert_allclose(seq.spacing_mm, [0.2, 0.1])
    np.testing.assert_allclose(seq.timestamps_s, np.arange(4) / 20)


def test_nrrd_without_spacing_or_times_is_refused(tmp_path):
    frames = _rng(2).integers(0, 256, (10, 7, 3), dtype=np.uint8)
    nrrd.write(str(tmp_path / "n.nrrd"), frames, {"kinds": ["domain", "domain", "list"]},
               index_order="F")
    with pytest.raises(RecordingError, match=r"n\.nrrd: no pixel spacing.*--spacing"):
        load_recording(tmp_path / "n.nrrd")
    with pytest.raises(RecordingError, match=r"n\.nrrd: no frame times.*--fps"):
        load_recording(tmp_path / "n.nrrd", spacing_mm=0.1)
    seq = load_recording(tmp_path / "n.nrrd", spacing_mm=[0.3, 0.1], fps=10)
    assert seq.images.shape == (3, 7, 10)
    np.testing.assert_allclose(seq.spacing_mm, [0.3, 0.1])


def test_truncated_nrrd_is_named(tmp_path):
    p = tmp_path / "t.nrrd"
    nrrd.write(str(p), _rng(3).integers(0, 256, (20, 20, 4), dtype=np.uint8),
               {"encoding": "raw", "kinds": ["domain", "domain", "list"]}, index_order="F")
    p.write_bytes(p.read_bytes()[:-100])
    with pytest.raises(RecordingError, match=r"t\.nrrd: truncated: sizes/type need 1600 bytes"):
        load_recording(p, spacing_mm=0.1, fps=10)


def _asymmetric(T=4, H=24, W=32):
    """Frames with a bright square in the top-left: any flip or transposition shows."""
    f = _rng(4).integers(0, 60, (T, H, W), dtype=np.uint8)
    f[:, 2:8, 3:9] = 230
    return f


def test_png_folder_with_sidecar_crop_and_colour(tmp_path):
    frames = _asymmetric()
    d = tmp_path / "shots"
    d.mkdir()
    for i, f in enumerate(frames):  # colour PNGs, numbered so that sorting by text would fail
        cv2.imwrite(str(d / f"frame{i * 5}.png"), cv2.cvtColor(f, cv2.COLOR_GRAY2BGR))
    (d / "frames.json").write_text(json.dumps({"spacing_mm": [0.2, 0.1], "fps": 25,
                                               "origin_mm": [1.0, -2.0]}))
    seq = load_recording(d)
    assert seq.modality == "inplane"
    np.testing.assert_array_equal(seq.images, frames)
    np.testing.assert_allclose(seq.spacing_mm, [0.2, 0.1])
    np.testing.assert_allclose(seq.timestamps_s, np.arange(4) / 25)
    cropped = load_recording(d, crop=(3, 2, 20, 10), spacing_mm=0.5)
    np.testing.assert_array_equal(cropped.images, frames[:, 2:12, 3:23])
    # the crop moves the origin to the kept rectangle's top-left pixel
    np.testing.assert_allclose(cropped.origin_mm, [1.0 + 2 * 0.5, -2.0 + 3 * 0.5])
    with pytest.raises(RecordingError, match=r"crop x,y,w,h = 20,2,20,10 does not fit in "
                                             r"frames of 32x24"):
        load_recording(d, crop=(20, 2, 20, 10))


def test_sidecar_errors_name_the_key(tmp_path):
    d = tmp_path / "f"
    d.mkdir()
    cv2.imwrite(str(d / "0.png"), _asymmetric(1)[0])
    (d / "frames.json").write_text(json.dumps({"spacing": 0.1}))
    with pytest.raises(RecordingError, match="frames.json: unknown key 'spacing'"):
        load_recording(d)
    (d / "frames.json").write_text(json.dumps({"spacing_mm": [0.1, 0.2, 0.3]}))
    with pytest.raises(RecordingError, match="key 'spacing_mm' must be 1 or 2"):
        load_recording(d)
    (d / "frames.json").unlink()
    with pytest.raises(RecordingError, match="no pixel spacing"):
        load_recording(d)


def test_video_frames_fps_and_sidecar(tmp_path):
    frames = _asymmetric(T=6, H=48, W=64)
    p = tmp_path / "clip.avi"
    w = cv2.VideoWriter(str(p), cv2.VideoWriter_fourcc(*"MJPG"), 12.0, (64, 48))
    assert w.isOpened()
    for f in frames:
        w.write(cv2.cvtColor(f, cv2.COLOR_GRAY2BGR))
    w.release()
    (tmp_path / "clip.json").write_text(json.dumps({"spacing_mm": 0.15, "modality": "axial"}))
    seq = load_recording(p)
    assert seq.images.shape == frames.shape and seq.modality == "axial"
    np.testing.assert_allclose(seq.timestamps_s, np.arange(6) / 12.0)
    # MJPG is lossy: the bright square is where it was, to within a few grey levels
    err = np.abs(seq.images.astype(int) - frames.astype(int))
    assert np.median(err) < 8 and seq.images[:, 4, 5].min() > 180
    assert seq.images[:, 4, 40].max() < 120


def test_unknown_suffix_and_missing_file(tmp_path):
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(RecordingError, match=r"x\.txt: unknown recording type '.txt'"):
        load_recording(tmp_path / "x.txt")
    with pytest.raises(FileNotFoundError, match="nope.mha"):
        load_recording(tmp_path / "nope.mha")
    bad = tmp_path / "bad.avi"
    bad.write_bytes(b"not a video at all" * 10)
    with pytest.raises(RecordingError, match="bad.avi"):
        load_recording(bad, spacing_mm=0.1, fps=10)
