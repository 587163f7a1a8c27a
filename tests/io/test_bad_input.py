"""Bad recordings give one RecordingError naming the file and the field, checked before any
allocation; damaged pixels are handled per pixel and reported, never rescale a recording."""

import json
import re
import zipfile
import zlib

import numpy as np
import pytest

import synth
from needlenet.io import RecordingError, load_recording, save_plus_sequence
from needlenet.io._limits import memory_budget_bytes


@pytest.fixture(scope="module")
def seq():
    return synth.generate("inplane", seed=4, frames=4, width_mm=16.0, depth_mm=20.0,
                          angle_deg=35.0, start_length_mm=12.0, background="homogeneous")


@pytest.fixture
def npz(tmp_path, seq):
    return synth.save_sequence(seq, tmp_path / "s.npz")


@pytest.fixture
def plus(tmp_path, seq):
    """(header text, pixel bytes) of an uncompressed PLUS file of ``seq``, and a writer."""
    p = save_plus_sequence(seq, tmp_path / "s.seq.mha", compress=False)[0]
    raw = p.read_bytes()
    j = raw.index(b"\n", raw.index(b"ElementDataFile")) + 1

    def write(header: str, body: bytes = raw[j:], name: str = "e.seq.mha"):
        out = tmp_path / name
        out.write_bytes(header.encode() + body)
        return out

    return raw[:j].decode(), raw[j:], write


def _rewrite_member(src, dst, key, data: bytes):
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for name in zin.namelist():
            zout.writestr(name, data if name == f"{key}.npy" else zin.read(name))
    return dst


def _npy_header(shape, descr="|u1") -> bytes:
    h = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}".encode()
    h += b" " * (63 - len(h) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(h).to_bytes(2, "little") + h


def test_npz_array_header_that_does_not_parse_is_named(tmp_path, npz):
    bad = _rewrite_member(npz, tmp_path / "b.npz", "images",
                          b"\x93NUMPY\x01\x00\x30\x00{'descr': '|u1', 'shape': (((( }\n")
    with pytest.raises(RecordingError, match=r"b\.npz: key 'images': has a damaged array header"):
        load_recording(bad)


def test_npz_header_claiming_more_than_the_file_holds_allocates_nothing(tmp_path, npz):
    bad = _rewrite_member(npz, tmp_path / "h.npz", "images",
                          _npy_header((10**6, 10**6, 1000)) + bytes(100))
    with pytest.raises(RecordingError, match=r"key 'images': its header describes .* but the "
                                             r"file holds 100 bytes"):
        load_recording(bad)


def test_npz_corrupt_compressed_stream_is_named(tmp_path, seq):
    path = synth.save_sequence(seq, tmp_path / "c.npz")
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        info = z.getinfo("images.npy")
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    for k in range(8):  # bytes inside the deflate stream of the images
        data[start + 200 + 37 * k] ^= 0x5A
    path.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match=r"c\.npz: key 'images'"):
        load_recording(path)


@pytest.mark.parametrize("meta, field", [({"draw": 5}, "'draw' must be a JSON object"),
                                         ({"params": {"speed_mm_s": "fast"}},
                                          r"params\.speed_mm_s = 'fast' must be a number"),
                                         ({"params": {"rotation_depth_mm": float("nan")}},
                                          r"params\.rotation_depth_mm = nan")])
def test_malformed_meta_the_trackers_read_is_named(tmp_path, seq, meta, field):
    path = synth.save_sequence(synth.Sequence(**{**seq.as_dict(), "meta": meta}),
                               tmp_path / "m.npz")
    with pytest.raises(RecordingError, match=rf"m\.npz: meta field {field}"):
        load_recording(path)


@pytest.mark.parametrize("dims", ["9223372036854775807 1 1", "3037000500 3037000500 1"])
def test_plus_dimsize_beyond_memory_is_refused_before_reading(plus, dims):
    header, body, write = plus
    bad = write(re.sub(r"DimSize = [\d ]+", f"DimSize = {dims}", header))
    with pytest.raises(RecordingError, match=r"DimSize/ElementType describes .* GiB .* more "
                                             r"than this machine can hold"):
        load_recording(bad)
    assert memory_budget_bytes() > 2**28


def test_plus_negative_compressed_size_is_named(plus):
    header, body, write = plus
    h = header.replace("CompressedData = False", "CompressedData = True")
    h = h.replace("DimSize", "CompressedDataSize = -100\nDimSize")
    with pytest.raises(RecordingError, match=r"CompressedDataSize = -100 must be positive"):
        load_recording(write(h, zlib.compress(body)))


def test_plus_size_beyond_what_zlib_can_inflate_is_refused(plus):
    header, body, write = plus
    h = header.replace("CompressedData = False", "CompressedData = True")
    h = re.sub(r"DimSize = (\d+) (\d+) (\d+)", r"DimSize = \1 \2 300000", h)
    with pytest.raises(RecordingError, match=r"more than zlib can inflate"):
        load_recording(write(h, zlib.compress(body)))


@pytest.mark.parametrize("value", ["1e-06 1e-06 1", "100 100 1"])
def test_spacing_outside_physical_range_is_named(plus, value):
    header, body, write = plus
    bad = write(re.sub(r"ElementSpacing = [^\n]+", f"ElementSpacing = {value}", header))
    with pytest.raises(RecordingError, match=r"ElementSpacing = .* mm per pixel is outside "
                                             r"0\.005-5\.0 mm"):
        load_recording(bad)


def test_spacing_argument_outside_range_names_the_option(npz):
    with pytest.raises(RecordingError, match=r"--spacing = \[1e-06, 1e-06\]"):
        load_recording(npz, spacing_mm=1e-6)


@pytest.mark.parametrize("fps", [1e300, 1e-300, float("nan")])
def test_frame_rate_outside_range_is_named(npz, fps):
    with pytest.raises(RecordingError, match=r"fps \(--fps\) = .* frames/s is outside"):
        load_recording(npz, fps=fps)


def test_float_pixels_with_nan_or_a_hot_pixel_do_not_rescale_the_recording(plus, seq):
    header, body, write = plus
    clean = np.frombuffer(body, np.uint8).astype(np.float32)
    h = header.replace("MET_UCHAR", "MET_FLOAT")
    for bad_value, note in ((np.nan, "not finite numbers; they are shown black"),
                            (1e6, "far outside the recording's intensity range")):
        img = clean.copy()
        img[1234] = bad_value
        got = load_recording(write(h, img.tobytes(), f"f{bad_value}.seq.mha"))
        assert any(note in w for w in got.meta["warnings"])
        lo, hi = clean.min(), clean.max()  # the clean recording's own scaling
        same = got.images.reshape(-1) == np.rint((clean - lo) * (255.0 / (hi - lo))).astype(
            np.uint8)
        same[1234] = True
        assert same.all(), (got.meta.get("intensity_range"), lo, hi, same.mean())


def test_plus_invalid_frames_are_skipped_and_reported(plus, seq):
    header, body, write = plus
    h = header
    for k in (1, 2):
        h = h.replace(f"Seq_Frame{k:04d}_ImageStatus = OK",
                      f"Seq_Frame{k:04d}_ImageStatus = INVALID")
    got = load_recording(write(h))
    assert got.n_frames == seq.n_frames - 2
    np.testing.assert_array_equal(got.images, seq.images[[0, 3]])
    np.testing.assert_allclose(got.tip_mm, seq.tip_mm[[0, 3]])
    assert any("skipped 2 of 4 frames marked ImageStatus = INVALID (frames 1, 2)" in w
               for w in got.meta["warnings"])


def test_nrrd_detached_device_bogus_type_and_empty_file_are_named(tmp_path):
    head = ("NRRD0004\ntype: {t}\ndimension: 3\nsizes: 32 40 3\nspacings: 0.1 0.1 NaN\n"
            "kinds: space space list\nencoding: raw\ndata file: {f}\n")
    (tmp_path / "z.nhdr").write_text(head.format(t="uint8", f="/dev/zero"))
    with pytest.raises(RecordingError, match=r"z\.nhdr: field data file = '/dev/zero' is not a "
                                             r"regular file"):
        load_recording(tmp_path / "z.nhdr")
    (tmp_path / "d.raw").write_bytes(bytes(32 * 40 * 3))
    (tmp_path / "t.nhdr").write_text(head.format(t="bogus", f="d.raw"))
    with pytest.raises(RecordingError, match=r"t\.nhdr: field type = 'bogus'"):
        load_recording(tmp_path / "t.nhdr")
    (tmp_path / "e.nrrd").write_bytes(b"")
    with pytest.raises(RecordingError, match=r"e\.nrrd: not a readable NRRD header"):
        load_recording(tmp_path / "e.nrrd")


def test_truncated_video_reports_the_frames_decoded(tmp_path, seq):
    cv2 = pytest.importorskip("cv2")
    path = tmp_path / "v.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 20,
                        seq.images.shape[:0:-1], False)
    for im in np.concatenate([seq.images] * 3):
        w.write(im)
    w.release()
    data = path.read_bytes()
    (tmp_path / "t.avi").write_bytes(data[:len(data) // 2])
    got = load_recording(tmp_path / "t.avi", spacing_mm=0.1)
    assert got.n_frames < 12
    assert any(f"decoded {got.n_frames} of the 12 frames" in w for w in got.meta["warnings"])
    assert "warnings" not in load_recording(path, spacing_mm=0.1).meta


def test_meta_round_trip_unchanged(tmp_path, seq):
    """A clean file reads without warnings (nothing invented)."""
    path = synth.save_sequence(seq, tmp_path / "ok.npz")
    got = load_recording(path)
    assert "warnings" not in got.meta
    assert json.loads(json.dumps(got.meta)) == got.meta


# -- found by the fuzz suite (tests/fuzz) --------------------------------------------------------

@pytest.fixture
def deadline():
    """Fail instead of hanging: the bugs below made readers wait for ever."""
    import signal

    def boom(*_):
        raise TimeoutError("the reader hung")

    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(20)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


@pytest.mark.parametrize("name", ["x.npz", "x.seq.mha", "x.nrrd", "x.avi"])
def test_a_fifo_is_refused_not_read_for_ever(tmp_path, deadline, name):
    import os

    os.mkfifo(tmp_path / name)
    with pytest.raises(RecordingError, match=r"not a regular file or a folder"):
        load_recording(tmp_path / name, spacing_mm=0.1, fps=20)


def _png(w, h, rows=b"") -> bytes:
    """A PNG whose header says ``w`` x ``h`` gray pixels, with ``rows`` as its data."""
    def chunk(kind, payload):
        return len(payload).to_bytes(4, "big") + kind + payload + \
            (zlib.crc32(kind + payload) & 0xFFFFFFFF).to_bytes(4, "big")

    ihdr = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + \
        chunk(b"IDAT", zlib.compress(rows or b"\0" * (w + 1))) + chunk(b"IEND", b"")


def test_png_frames_a_fifo_among_them_or_a_header_claiming_gigapixels(tmp_path, seq, deadline):
    import os

    cv2 = pytest.importorskip("cv2")
    d = tmp_path / "f"
    d.mkdir()
    for i, im in enumerate(seq.images):
        cv2.imwrite(str(d / f"{i}.png"), im)
    os.mkfifo(d / "9.png")
    with pytest.raises(RecordingError, match=r"9\.png: not a regular file"):
        load_recording(d, spacing_mm=0.1, fps=20)
    (d / "9.png").unlink()
    (d / "9.png").write_bytes(_png(30000, 30000))  # OpenCV allocated 900 MB for it
    with pytest.raises(RecordingError, match=r"9\.png: its header's image size describes "
                                             r"frames of \(30000, 30000\)"):
        load_recording(d, spacing_mm=0.1, fps=20)
    (d / "9.png").write_bytes(_png(50000, 50000))  # OpenCV raised cv2.error
    with pytest.raises(RecordingError, match=r"9\.png"):
        load_recording(d, spacing_mm=0.1, fps=20)


def test_a_sidecar_origin_far_away_or_nested_for_ever_is_named(tmp_path, seq):
    cv2 = pytest.importorskip("cv2")
    d = tmp_path / "f"
    d.mkdir()
    for i, im in enumerate(seq.images):
        cv2.imwrite(str(d / f"{i}.png"), im)
    (d / "frames.json").write_text(json.dumps({"spacing_mm": 0.1, "fps": 20,
                                               "origin_mm": [1e308, 1e308]}))
    with pytest.raises(RecordingError, match=r"the sidecar's origin_mm = \[1e\+308, 1e\+308\] "
                                             r"mm is not finite or lies more than"):
        load_recording(d)
    (d / "frames.json").write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(RecordingError, match=r"frames\.json: not a readable JSON sidecar "
                                             r"\(RecursionError"):
        load_recording(d)


@pytest.mark.parametrize("matrix, message", [
    ("0 " * 15 + "1", r"the rotation part is singular"),
    ("1e300 0 0 0 0 1e300 0 0 0 0 1e300 0 0 0 0 1", r"the rotation part is singular or "
                                                    r"scales by 1e\+300"),
    ("1 0 0 1e9 0 1 0 0 0 0 1 0 0 0 0 1", r"translation \[1000000000\.0, 0\.0, 0\.0\] mm"),
    ("1 0 0 0 0 1 0 0 0 0 1 0 0 0 1 1", r"the last row"),
])
def test_plus_transforms_that_are_no_pose_are_named(plus, matrix, message):
    """A singular ProbeToReferenceTransform was a LinAlgError; one of 1e300 a ValueError
    deep in the metrics."""
    header, body, write = plus
    h = re.sub(r"Seq_Frame0002_ProbeToReferenceTransform = [^\n]+",
               f"Seq_Frame0002_ProbeToReferenceTransform = {matrix}", header)
    with pytest.raises(RecordingError, match=r"Seq_Frame0002_ProbeToReferenceTransform: "
                                             rf"{message}"):
        load_recording(write(h))


def test_plus_frame_times_with_a_pause_of_days_are_named(plus):
    """``--realtime`` slept for the pause (OverflowError for 1e300 s)."""
    header, body, write = plus
    h = re.sub(r"Seq_Frame0003_Timestamp = [^\n]+", "Seq_Frame0003_Timestamp = 1e300", header)
    with pytest.raises(RecordingError, match=r"frame 3 comes 1e\+300 s after frame 2, more "
                                             r"than 3600 s"):
        load_recording(write(h))


@pytest.mark.parametrize("edit, message", [
    (lambda a: a.update(direction=np.zeros_like(a["direction"])),
     r"key 'direction': frame 0: a vector of length 0"),
    (lambda a: a.update(direction=np.full_like(a["direction"], 1e300)),
     r"key 'direction': frame 0: a vector of length inf"),
    (lambda a: a.update(tip_mm=np.full_like(a["tip_mm"], 1e300)),
     r"tip_mm of frame 0 lies more than 100000 mm from the probe"),
    (lambda a: a.pop("direction"), r"key 'direction': is required when tip_mm is given"),
    (lambda a: a.update(probe_pose=np.array(a["probe_pose"]).astype("U5")),
     r"key 'probe_pose': must hold real numbers, got dtype <U5"),
    (lambda a: a.update(timestamps_s=np.zeros(4, "V4")),
     r"key 'timestamps_s': must hold real numbers"),
    (lambda a: a.update(tip_mm=np.full_like(a["tip_mm"], np.inf)),
     r"key 'tip_mm': must be finite, or NaN where unknown"),
    (lambda a: a.update(spacing_mm=np.array([[0.1], [0.1]])),
     r"key 'spacing_mm': must be 2 finite numbers, got \[\[0\.1\], \[0\.1\]\]$"),
    (lambda a: a.update(meta=np.array('{"a": ' + "[" * 100000 + "]" * 100000 + "}")),
     r"scalar keys modality/dynamic_range_db/meta: maximum recursion depth"),
])
def test_npz_labels_and_arrays_the_metrics_cannot_use_are_named(tmp_path, npz, edit, message):
    """Each of these was a traceback in the metrics, numpy or json (or a message on two
    lines)."""
    with np.load(npz) as z:
        arrays = {k: z[k] for k in z.files}
    edit(arrays)
    np.savez(tmp_path / "e.npz", **arrays)
    with pytest.raises(RecordingError, match=message):
        load_recording(tmp_path / "e.npz")


def test_nrrd_line_skip_space_origin_and_gzip_that_inflates_too_far(tmp_path, deadline):
    head = ("NRRD0004\ntype: uint8\ndimension: 3\nspace dimension: 2\nsizes: 32 40 3\n"
            "space directions: (0.1,0) (0,0.1) none\nkinds: domain domain list\n"
            "encoding: {enc}\n{extra}\n")
    data = bytes(32 * 40 * 3)
    cases = [("raw", "line skip: 1000000000\n", data, r"line skip = 1000000000 must be 0 to"),
             ("raw", "space origin: (0,0,0)\n", data,
              r"field space origin has 3 values for 2-dimensional space directions"),
             ("gzip", "", gzip_bytes(bytes(50 << 20)),
              r"the gzip data inflates to more than the 3840 bytes"),
             ("raw", "", data[:100], r"truncated: sizes/type need 3840 bytes")]
    for k, (enc, extra, body, message) in enumerate(cases):
        p = tmp_path / f"{k}.nrrd"
        p.write_bytes(head.format(enc=enc, extra=extra).encode() + body)
        with pytest.raises(RecordingError, match=message):
            load_recording(p, fps=20)
    p = tmp_path / "magic.nrrd"
    p.write_bytes(b"NRRD\n" + head.format(enc="raw", extra="").encode()[9:] + data)
    with pytest.raises(RecordingError) as exc:
        load_recording(p, fps=20)
    assert "\n" not in str(exc.value)  # pynrrd quotes the line with its line break


def gzip_bytes(data: bytes) -> bytes:
    import gzip

    return gzip.compress(data, mtime=0)
