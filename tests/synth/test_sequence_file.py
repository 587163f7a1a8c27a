"""The sequence file: round trip, validation, bad files named by key."""

import json
import zipfile

import numpy as np
import pytest

import synth


def _seq(T=3, modality="inplane"):
    nd = 3 if modality == "volume" else 2
    shape = (T, 8, 9, 10) if nd == 3 else (T, 16, 20)
    rng = np.random.default_rng(0)
    return synth.Sequence(
        images=rng.integers(0, 255, shape, dtype=np.uint8), spacing_mm=np.full(nd, 0.2),
        origin_mm=np.zeros(nd), modality=modality, timestamps_s=np.arange(T) * 0.05,
        dynamic_range_db=60.0, meta={"scenario": "test", "seed": 1},
        tip_mm=rng.normal(size=(T, nd)), entry_mm=rng.normal(size=(T, nd)),
        direction=rng.normal(size=(T, nd)), visible=np.ones(T, bool),
        probe_pose=np.repeat(np.eye(4)[None], T, 0))


@pytest.mark.parametrize("modality", ["inplane", "axial", "volume"])
def test_round_trip(tmp_path, modality):
    s = _seq(modality=modality)
    path = synth.save_sequence(s, tmp_path / "s.npz")
    r = synth.load_sequence(path)
    assert r.modality == modality and r.meta == s.meta
    for k in ("images", "spacing_mm", "origin_mm", "timestamps_s", "tip_mm", "probe_pose"):
        np.testing.assert_array_equal(getattr(r, k), getattr(s, k))
    assert r.images.dtype == np.uint8


def test_images_stored_labels_deflated(tmp_path):
    # speckle does not compress: the images member is stored, the rest deflated; np.load and
    # the reader both read it back
    s = _seq()
    path = synth.save_sequence(s, tmp_path / "s.npz")
    with zipfile.ZipFile(path) as zf:
        assert zf.getinfo("images.npy").compress_type == zipfile.ZIP_STORED
        assert zf.getinfo("tip_mm.npy").compress_type == zipfile.ZIP_DEFLATED
    with np.load(path) as z:
        np.testing.assert_array_equal(z["images"], s.images)
    np.testing.assert_array_equal(synth.load_sequence(path).images, s.images)
    assert path.read_bytes() == synth.save_sequence(s, tmp_path / "t.npz").read_bytes()


def test_refuses_to_overwrite(tmp_path):
    path = tmp_path / "s.npz"
    synth.save_sequence(_seq(), path)
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="exists"):
        synth.save_sequence(_seq(T=5), path)
    assert path.read_bytes() == before
    synth.save_sequence(_seq(T=5), path, overwrite=True)
    assert synth.load_sequence(path).n_frames == 5


def _write(path, arrays):
    np.savez(path, **arrays)
    return path


def _arrays(s):
    d = {k: v for k, v in s.as_dict().items()}
    d["meta"] = np.array(json.dumps(d["meta"]))
    d["modality"] = np.array(d["modality"])
    return d


@pytest.mark.parametrize("key", ["images", "spacing_mm", "modality", "timestamps_s", "meta"])
def test_missing_key_is_named(tmp_path, key):
    d = _arrays(_seq())
    del d[key]
    path = _write(tmp_path / "bad.npz", d)
    with pytest.raises(synth.SequenceFileError, match=f"key '{key}'.*missing"):
        synth.load_sequence(path)


@pytest.mark.parametrize("key,value,msg", [
    ("images", np.zeros((3, 16, 20), np.float32), "uint8"),
    ("spacing_mm", np.array([0.2, -0.1]), "positive"),
    ("spacing_mm", np.array([0.2]), "2 finite"),
    ("timestamps_s", np.array([0.0, 0.1]), "3 finite"),
    ("tip_mm", np.zeros((3, 3)), "shape"),
    ("modality", np.array("volume"), "does not match"),
    ("modality", np.array("sagittal"), "one of"),
    ("visible", np.ones(3, np.int64), "bool"),
])
def test_wrong_key_is_named(tmp_path, key, value, msg):
    d = _arrays(_seq())
    d[key] = value
    path = _write(tmp_path / "bad.npz", d)
    with pytest.raises(synth.SequenceFileError, match=f"key '{key}'.*{msg}"):
        synth.load_sequence(path)


def test_corrupt_and_truncated_files(tmp_path):
    path = tmp_path / "c.npz"
    path.write_bytes(b"not a zip file at all")
    with pytest.raises(synth.SequenceFileError, match="not a readable"):
        synth.load_sequence(path)
    good = synth.save_sequence(_seq(), tmp_path / "g.npz")
    data = good.read_bytes()
    trunc = tmp_path / "t.npz"
    trunc.write_bytes(data[: len(data) // 2])
    with pytest.raises(synth.SequenceFileError):
        synth.load_sequence(trunc)
    with pytest.raises(FileNotFoundError, match="no such"):
        synth.load_sequence(tmp_path / "missing.npz")
    assert zipfile.is_zipfile(good)


def test_pickled_objects_are_not_loaded(tmp_path):
    d = _arrays(_seq())
    d["meta"] = np.array([{"a": 1}], dtype=object)
    path = tmp_path / "p.npz"
    np.savez(path, **d)
    with pytest.raises(synth.SequenceFileError):
        synth.load_sequence(path)
