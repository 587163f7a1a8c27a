"""Live OpenIGTLink input (needlenet/io/_igtl_source.py, `track igtl://...`): frames as a PLUS
Server sends them, sent here by needlenet's own IGTLStreamer on loopback and received by
pyigtl's client. Every wait is bounded."""

import json
import threading

import numpy as np
import pytest

import synth
from needlenet.cli import main
from needlenet.io import IGTLStreamer, StreamError
from needlenet.io._igtl_source import frame_from_image_message, parse_igtl_url
from needlenet.trackers import make_tracker

pyigtl = pytest.importorskip("pyigtl")


@pytest.mark.parametrize("url,want", [
    ("igtl://127.0.0.1", ("127.0.0.1", 18944, "Image_Reference")),
    ("igtl://scanner:18950/Image_Probe", ("scanner", 18950, "Image_Probe")),
    ("igtl://localhost:1/", ("localhost", 1, "Image_Reference")),
])
def test_urls(url, want):
    assert parse_igtl_url(url) == want


@pytest.mark.parametrize("url", ["igtl://", "igtl://h:0", "igtl://h:99999", "http://h:1",
                                 "igtl://h:1/a/b"])
def test_bad_urls_name_the_form(url):
    with pytest.raises(StreamError, match=r"igtl://HOST\[:PORT\]\[/DEVICE\]|port"):
        parse_igtl_url(url)


def _message(image, matrix, system="ras", t=12.5):
    return pyigtl.ImageMessage(image, ijk_to_world_matrix=matrix, world_coordinate_system=system,
                               timestamp=t, device_name="Image_Reference")


def test_a_frame_takes_spacing_and_pose_from_the_matrix():
    """i lateral and j depth scaled and rotated by the matrix: the spacing is the columns'
    lengths (depth first), the pose a right-handed rotation whose x is i and z is j, in RAS
    (an LPS matrix's first two rows negated)."""
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (1, 30, 40), dtype=np.uint8)
    a = np.deg2rad(30.0)
    rot = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
    m = np.eye(4)
    m[:3, :3] = rot @ np.diag([0.15, 0.25, 1.0])
    m[:3, 3] = [4.0, -2.0, 7.0]
    for system, flip in (("ras", np.eye(3)), ("lps", np.diag([-1.0, -1.0, 1.0]))):
        f = frame_from_image_message(_message(img, m, system), 3)
        np.testing.assert_array_equal(f.image, img[0])
        assert f.grid.spacing_mm == (0.25, 0.15) and f.t == 12.5 and f.index == 3
        pose = f.probe_pose
        np.testing.assert_allclose(pose[:3, 0], flip @ rot[:, 0], atol=1e-6)  # x: i
        np.testing.assert_allclose(pose[:3, 2], flip @ rot[:, 1], atol=1e-6)  # z: j (depth)
        np.testing.assert_allclose(pose[:3, 3], flip @ [4.0, -2.0, 7.0], atol=1e-6)
        assert np.linalg.det(pose[:3, :3]) == pytest.approx(1.0)


def test_colour_and_16_bit_frames_become_gray():
    rgb = np.zeros((1, 20, 30, 3), np.uint8)
    rgb[..., :] = (200, 100, 50)
    f = frame_from_image_message(_message(rgb, np.diag([0.1, 0.1, 1, 1])), 0)
    assert f.image.dtype == np.uint8
    assert abs(int(f.image[0, 0]) - round(0.299 * 200 + 0.587 * 100 + 0.114 * 50)) <= 1
    wide = np.arange(600, dtype=np.uint16).reshape(1, 20, 30) * 50
    g = frame_from_image_message(_message(wide, np.diag([0.1, 0.1, 1, 1])), 0).image
    assert g.dtype == np.uint8 and g.min() == 0 and g.max() == 255


@pytest.mark.parametrize("image,matrix,msg", [
    (np.zeros((4, 20, 30), np.uint8), np.diag([0.1, 0.1, 1, 1]), "tracks 2D frames"),
    (np.zeros((1, 20, 30), np.uint8), np.diag([0.0, 0.1, 1, 1]), "pixels of"),
    (np.zeros((1, 1, 30), np.uint8), np.diag([0.1, 0.1, 1, 1]), "is no image"),
    (np.zeros((1, 20, 30, 2), np.uint8), np.diag([0.1, 0.1, 1, 1]), "2 components"),
])
def test_frames_that_are_not_2d_images_are_refused(image, matrix, msg):
    with pytest.raises(StreamError, match=msg):
        frame_from_image_message(_message(image, matrix), 0)


def test_a_stream_is_tracked_live_from_the_command_line(tmp_path, capsys):
    """A PLUS-like server (needlenet's streamer, on loopback) sends a synth insertion frame
    by frame; `track igtl://` tracks what arrives and stops when the stream pauses."""
    seq = synth.generate("inplane", seed=21, frames=8)
    # the frames come at a rate a warm tracker keeps up with: the default tracker's compiled
    # code is loaded (or, on a fresh clone, compiled: seconds) before the stream starts
    make_tracker("inplane").run(seq)
    server = IGTLStreamer(0)
    sent = threading.Event()

    def send():
        try:
            if not server.wait_for_client(20.0):
                return
            for i in range(seq.n_frames):
                server.send_frame(np.asarray(seq.images[i]), seq.spacing_mm, None, None, None,
                                  "searching", origin=seq.origin_mm,
                                  timestamp=float(seq.timestamps_s[i]))
                sent.wait(0.15)  # a frame rate a tracker keeps up with
        finally:
            sent.set()

    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    out = tmp_path / "live.json"
    try:
        rc = main(["track", f"igtl://127.0.0.1:{server.port}", "--json", str(out),
                   "--igtl-idle", "2", "--igtl-connect", "20", "--quiet"])
    finally:
        thread.join(30.0)
        server.close(flush_timeout_s=0.0)
    assert rc == 0
    frames = json.loads(out.read_text())["frames"]
    assert len(frames) >= seq.n_frames // 2
    times = np.asarray(seq.timestamps_s, float)
    origin = np.asarray(seq.origin_mm)[::-1]  # (x, z): the stream's pixel 0 is the origin
    for f in frames:
        k = int(np.argmin(np.abs(times - f["t"])))
        assert abs(times[k] - f["t"]) < 1e-6
        if f["status"] == "tracking":
            assert np.linalg.norm(np.asarray(f["tip_mm"]) + origin - seq.tip_mm[k]) < 1.0
    assert any(f["status"] == "tracking" for f in frames)


def test_no_stream_is_a_clear_error(capsys):
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    rc = main(["track", f"igtl://127.0.0.1:{port}", "--igtl-connect", "0.5", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "no IMAGE 'Image_Reference'" in err and err.count("\n") == 1


@pytest.mark.parametrize("extra,msg", [
    (["--overlay", "{d}/o.gif"], "record the OpenIGTLink stream"),
    (["--spacing", "0.1"], "--spacing is for recording files"),
    (["--tracker", "volume"], "OpenIGTLink input is 2D frames"),
])
def test_options_for_files_are_refused_for_a_stream(tmp_path, capsys, extra, msg):
    rc = main(["track", "igtl://127.0.0.1:1"] + [a.format(d=tmp_path) for a in extra])
    assert rc == 2 and msg in capsys.readouterr().err
