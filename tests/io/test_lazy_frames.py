"""Recordings read frame by frame: a lazily read PLUS, NRRD, image folder or video gives the
same frames and the same tracking as the eager read, reads a frame only when it is asked for,
and names the file and the frame of a damaged frame found late."""

import dataclasses
import re

import numpy as np
import pytest

import synth
from needlenet.cli import main
from needlenet.io import RecordingError, load_recording, save_plus_sequence
from needlenet.io._lazy import FrameStack
from needlenet.trackers import make_tracker

cv2 = pytest.importorskip("cv2")
nrrd = pytest.importorskip("nrrd")


@pytest.fixture(scope="module")
def seq():
    return synth.generate("inplane", seed=22, frames=6, width_mm=16.0, depth_mm=20.0,
                          angle_deg=35.0, start_length_mm=12.0, background="homogeneous")


def _tips(s):
    est = make_tracker("inplane", "line", "classical", seed=0).run(s)
    return [e.status.value for e in est], np.array(
        [np.full(2, np.nan) if e.tip_mm is None else e.tip_mm for e in est])


def _same_tracking(a, b):
    sa, ta = _tips(a)
    sb, tb = _tips(b)
    assert sa == sb
    np.testing.assert_array_equal(ta, tb)


def _write_nrrd(path, images, encoding):
    """(T, H, W) frames as a NRRD sequence, the list axis slowest (header fields in the
    file's axis order: lateral, depth, frames)."""
    nrrd.write(str(path), np.ascontiguousarray(images), {
        "kinds": ["domain", "domain", "list"], "encoding": encoding,
        "space dimension": 2, "space directions": [[0.1, 0.0], [0.0, 0.1], [np.nan, np.nan]],
        "axis 2 index values": " ".join(str(0.05 * i) for i in range(len(images)))},
        index_order="C")


# -- memory-mapped: uncompressed PLUS and raw NRRD ----------------------------------------------

def test_plus_is_read_frame_by_frame_and_tracks_as_the_array(tmp_path, seq):
    """Uncompressed: through a memory map; compressed: inflated in order as read."""
    save_plus_sequence(seq, tmp_path / "raw.seq.mha", compress=False)
    save_plus_sequence(seq, tmp_path / "z.seq.mha", compress=True)
    mapped, inflated = load_recording(tmp_path / "raw.seq.mha"), \
        load_recording(tmp_path / "z.seq.mha")
    assert isinstance(mapped.images.source, np.ndarray)  # the raw frames, memory-mapped
    for got in (mapped, inflated):
        assert isinstance(got.images, FrameStack)
        assert got.images.shape == seq.images.shape
        assert got.images.dtype == np.uint8 and got.images.ndim == 3
        for i in (0, 1, 5, 2, 0):  # forwards, then back
            np.testing.assert_array_equal(got.images[i], seq.images[i])
        np.testing.assert_array_equal(got.images, seq.images)
        _same_tracking(got, seq)


def _plus_z(seq, tmp_path):
    return save_plus_sequence(seq, tmp_path / "z.seq.mha", compress=True)[0]


def _nrrd_gzip(seq, tmp_path):
    path = tmp_path / "g.seq.nrrd"
    _write_nrrd(path, seq.images, "gzip")
    return path


@pytest.mark.parametrize("write, cut", [(_plus_z, 200), (_nrrd_gzip, 300)])
def test_a_compressed_recording_cut_after_opening_names_the_frame(tmp_path, seq, write, cut):
    path = write(seq, tmp_path)
    got = load_recording(path)
    data = path.read_bytes()
    path.write_bytes(data[:len(data) - cut])
    np.testing.assert_array_equal(got.images[0], seq.images[0])
    with pytest.raises(RecordingError, match=re.escape(path.name) + r": frame 5: the "
                                             r"compressed pixel data ends before it"):
        got.images[5]


def test_a_mapped_frame_is_read_when_asked_for(tmp_path, seq):
    """The file's bytes of frame 4, changed after opening, are what frame 4 reads: nothing
    was read ahead of time (frame 0, read before, keeps what it read)."""
    path = save_plus_sequence(seq, tmp_path / "raw.seq.mha", compress=False)[0]
    got = load_recording(path)
    f0 = got.images[0]
    T, H, W = seq.images.shape
    with open(path, "r+b") as fh:
        fh.seek(path.stat().st_size - (T - 4) * H * W)
        fh.write(bytes(H * W))
    np.testing.assert_array_equal(f0, seq.images[0])
    assert not got.images[4].any()
    np.testing.assert_array_equal(got.images[3], seq.images[3])
    f0[:] = 7  # a frame read is the caller's own copy
    np.testing.assert_array_equal(got.images[0], seq.images[0])


@pytest.mark.parametrize("orientation", ["UN", "MN", "UF"])
def test_mapped_plus_applies_the_orientation_per_frame(tmp_path, seq, orientation):
    path = save_plus_sequence(seq, tmp_path / "raw.seq.mha", compress=False)[0]
    data = path.read_bytes().replace(b"UltrasoundImageOrientation = MF\n",
                                     f"UltrasoundImageOrientation = {orientation}\n".encode())
    (tmp_path / "o.seq.mha").write_bytes(data)
    got = load_recording(tmp_path / "o.seq.mha")
    want = seq.images[..., ::-1] if orientation[0] == "U" else seq.images
    want = want[:, ::-1] if orientation[1] == "N" else want
    assert isinstance(got.images, FrameStack)
    np.testing.assert_array_equal(got.images[2], want[2])
    np.testing.assert_array_equal(got.images, want)


def test_raw_and_gzip_nrrd_are_read_frame_by_frame_and_track_as_the_whole_read(tmp_path, seq):
    """raw: memory-mapped; gzip: inflated in order; bzip2: read whole, as before."""
    for enc in ("raw", "gzip", "bzip2"):
        _write_nrrd(tmp_path / f"{enc}.seq.nrrd", seq.images, enc)
    mapped, inflated, whole = (load_recording(tmp_path / f"{enc}.seq.nrrd")
                               for enc in ("raw", "gzip", "bzip2"))
    assert isinstance(whole.images, np.ndarray)
    for got in (mapped, inflated):
        assert isinstance(got.images, FrameStack)
        for i in (0, 5, 1):
            np.testing.assert_array_equal(got.images[i], seq.images[i])
        np.testing.assert_array_equal(got.images, whole.images)
        np.testing.assert_array_equal(got.spacing_mm, whole.spacing_mm)
        np.testing.assert_array_equal(got.timestamps_s, whole.timestamps_s)
        _same_tracking(got, whole)




def test_nrrd_with_interleaved_frames_is_read_whole(tmp_path, seq):
    """The list axis fastest: every frame touches the whole file, so it is read at once."""
    nrrd.write(str(tmp_path / "i.nrrd"), seq.images, {"kinds": ["list", "domain", "domain"],
                                                      "encoding": "raw"}, index_order="F")
    got = load_recording(tmp_path / "i.nrrd", spacing_mm=0.1, fps=20)
    assert isinstance(got.images, np.ndarray)
    np.testing.assert_array_equal(got.images, seq.images.transpose(0, 2, 1))


# -- the frame stack ------------------------------------------------------------------------------

def test_selections_and_crops_of_a_stack_read_nothing_until_indexed(seq):
    reads = []

    def read(i):
        reads.append(i)
        return seq.images[i].copy()

    stack = FrameStack(read, seq.n_frames, seq.images.shape[1:])
    sub = stack[[0, 3, 5]][1:, 2:12, 3:23]
    assert sub.shape == (2, 10, 20) and reads == []
    np.testing.assert_array_equal(sub[1], seq.images[5, 2:12, 3:23])
    assert reads == [5]
    mask = np.array([True, False, False, True, False, True])
    np.testing.assert_array_equal(stack[mask], seq.images[mask])
    np.testing.assert_array_equal(stack[-1], seq.images[-1])
    with pytest.raises(IndexError):
        stack[seq.n_frames]
    assert (stack == seq.images).all() and stack.max() == seq.images.max()
    np.testing.assert_array_equal(stack.astype(int), seq.images.astype(int))


# -- image folders and videos --------------------------------------------------------------------

def _folder(tmp_path, seq):
    d = tmp_path / "frames"
    d.mkdir()
    for i, im in enumerate(seq.images):
        cv2.imwrite(str(d / f"f{i}.png"), im)
    return d


def test_a_folder_decodes_only_the_frames_read(tmp_path, seq, monkeypatch):
    d = _folder(tmp_path, seq)
    decoded = []
    imread = cv2.imread
    monkeypatch.setattr(cv2, "imread", lambda f, *a: decoded.append(f) or imread(f, *a))
    got = load_recording(d, spacing_mm=0.1, fps=20)
    assert isinstance(got.images, FrameStack)
    assert [p.rsplit("/", 1)[1] for p in decoded] == ["f0.png"]  # its size and type
    np.testing.assert_array_equal(got.images[3], seq.images[3])
    assert [p.rsplit("/", 1)[1] for p in decoded] == ["f0.png", "f3.png"]
    monkeypatch.undo()
    eager = dataclasses.replace(got, images=np.asarray(got.images))
    np.testing.assert_array_equal(eager.images, seq.images)
    _same_tracking(got, eager)


def test_a_damaged_frame_found_late_names_the_file_and_the_frame(tmp_path, seq, capsys):
    d = _folder(tmp_path, seq)
    got = load_recording(d, spacing_mm=0.1, fps=20)
    (d / "f4.png").write_bytes((d / "f4.png").read_bytes()[:60])  # damaged after opening
    np.testing.assert_array_equal(got.images[0], seq.images[0])
    with pytest.raises(RecordingError, match=r"f4\.png: not a readable image \(frame 4\)"):
        got.images[4]
    rc = main(["track", str(d), "--spacing", "0.1", "--fps", "20", "--features", "classical",
               "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.strip().splitlines()[-1].startswith("needlenet: error: ")
    assert "f4.png: not a readable image (frame 4)" in err and "Traceback" not in err


def test_a_folder_frame_of_another_size_is_named(tmp_path, seq):
    d = _folder(tmp_path, seq)
    got = load_recording(d, spacing_mm=0.1, fps=20)
    cv2.imwrite(str(d / "f2.png"), seq.images[2][:, :-4])
    with pytest.raises(RecordingError, match=r"f2\.png: \d+x\d+ pixels \(frame 2\), but "
                                             r"f0\.png has"):
        got.images[2]


def test_a_video_is_decoded_on_demand_in_any_order(tmp_path, seq):
    path = tmp_path / "v.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 20,
                        seq.images.shape[:0:-1], False)
    for im in seq.images:
        w.write(im)
    w.release()
    got = load_recording(path, spacing_mm=0.1)
    assert isinstance(got.images, FrameStack) and got.n_frames == seq.n_frames
    forwards = np.asarray(got.images)
    backwards = np.stack([got.images[i] for i in range(seq.n_frames - 1, -1, -1)])[::-1]
    np.testing.assert_array_equal(forwards, backwards)
    np.testing.assert_array_equal(got.images[2], forwards[2])
    assert np.abs(forwards.astype(int) - seq.images.astype(int)).mean() < 3.0  # MJPG


def test_an_overlay_reads_only_the_frames_it_shows(tmp_path, seq):
    from needlenet.io import write_overlay

    reads = []

    def read(i):
        reads.append(i)
        return seq.images[i].copy()

    lazy = dataclasses.replace(seq, images=FrameStack(read, seq.n_frames, seq.images.shape[1:]))
    est = make_tracker("inplane", "line", "classical", seed=0).run(seq)
    write_overlay(tmp_path / "o.gif", lazy, est, max_frames=3)
    assert reads == [0, 2, 4]
    assert (tmp_path / "o.gif").stat().st_size > 0


@pytest.mark.parametrize("name, compress", [("o.seq.mha", False), ("o.seq.mha", True),
                                            ("o.mhd", True)])
def test_a_stack_is_written_to_plus_frame_by_frame(tmp_path, seq, name, compress):
    """--out-plus of a long recording: the same file as from the array (uncompressed, byte
    for byte), and the same frames read back."""
    reads = []

    def read(i):
        reads.append(i)
        return seq.images[i].copy()

    lazy = dataclasses.replace(seq, images=FrameStack(read, seq.n_frames, seq.images.shape[1:]))
    (tmp_path / "lazy").mkdir()
    out = save_plus_sequence(lazy, tmp_path / "lazy" / name, compress=compress)
    ref = save_plus_sequence(seq, tmp_path / name, compress=compress)
    assert sorted(reads) == list(range(seq.n_frames))
    if not compress:
        assert out[0].read_bytes() == ref[0].read_bytes()
    np.testing.assert_array_equal(load_recording(out[0]).images, seq.images)


def test_a_volume_stack_is_written_in_the_file_order(tmp_path):
    vol = synth.generate("volume", seed=3, frames=2, output_size=24)
    lazy = dataclasses.replace(vol, images=FrameStack(lambda i: vol.images[i].copy(),
                                                      vol.n_frames, vol.images.shape[1:]))
    out = save_plus_sequence(lazy, tmp_path / "v.seq.mha")
    np.testing.assert_array_equal(load_recording(out[0]).images, vol.images)
