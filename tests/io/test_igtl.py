"""OpenIGTLink streaming on loopback: what a pyigtl client receives, and the failure modes.
Every wait is bounded; the server and the client are always closed."""

import socket
import threading

import numpy as np
import pytest

from needlenet.io import IGTLStreamer, StreamError, needle_tip_matrix

pyigtl = pytest.importorskip("pyigtl")
TIMEOUT = 5.0


@pytest.fixture
def streamer():
    s = IGTLStreamer(0)  # port 0: the system picks a free one
    yield s
    s.close(flush_timeout_s=0.0)


@pytest.fixture
def client(streamer):
    c = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=streamer.port)
    try:
        assert streamer.wait_for_client(TIMEOUT), "the client did not connect"
        yield c
    finally:
        c.stop()


def test_frames_arrive_with_tip_transform_image_and_points(streamer, client):
    rng = np.random.default_rng(0)
    T, H, W = 4, 12, 17
    frames = rng.integers(0, 256, (T, H, W), dtype=np.uint8)
    spacing, origin = np.array([0.2, 0.1]), np.array([1.0, -0.8])
    tips = np.array([[0.5 + i, 6.0 + 0.5 * i] for i in range(T)])
    direction = np.array([0.6, 0.8])
    for i in range(T):
        status = "searching" if i == 0 else "tracking"
        assert streamer.send_frame(frames[i], spacing, tips[i], direction, tips[i] - 10 * direction,
                                   status, origin=origin, timestamp=100.0 + i)
        img = client.wait_for_message("Image_Reference", timeout=TIMEOUT)
        st = client.wait_for_message("NeedleStatus", timeout=TIMEOUT)
        assert img is not None and st is not None and st.string == status
        np.testing.assert_array_equal(img.image, frames[i][None])  # (k, j, i) = (1, depth, lat)
        m = img.ijk_to_world_matrix
        # pixel (i, j) -> (x0 + i dx, 0, z0 + j dz): i lateral, j depth
        np.testing.assert_allclose(m @ [3, 5, 0, 1], [-0.8 + 3 * 0.1, 0, 1.0 + 5 * 0.2, 1],
                                   atol=1e-5)
        if i == 0:
            continue  # searching: no transform, no points
        tr = client.wait_for_message("NeedleTipToReference", timeout=TIMEOUT)
        tip = client.wait_for_message("NeedleTip", timeout=TIMEOUT)
        entry = client.wait_for_message("NeedleEntry", timeout=TIMEOUT)
        assert tr is not None and tip is not None and entry is not None
        np.testing.assert_allclose(tr.matrix, needle_tip_matrix(tips[i], direction), atol=1e-6)
        np.testing.assert_allclose(tr.matrix[:3, 2], [0.6, 0, 0.8], atol=1e-6)
        np.testing.assert_allclose(tip.positions[0], [tips[i][0], 0, tips[i][1]], atol=1e-5)
        e = tips[i] - 10 * direction
        np.testing.assert_allclose(entry.positions[0], [e[0], 0, e[1]], atol=1e-5)
    assert streamer.frames_sent == T and streamer.frames_skipped == 0


def test_volume_and_probe_pose(streamer, client):
    vol = np.random.default_rng(1).integers(0, 256, (5, 3, 4), dtype=np.uint8)  # z, y, x
    pose = np.eye(4)
    pose[:3, 3] = [10.0, 20.0, 30.0]
    assert streamer.send_frame(vol, [0.5, 0.25, 0.125], [0.1, 0.2, 0.3], [0, 0, 1], None,
                               "tracking", probe_pose=pose)
    img = client.wait_for_message("Image_Reference", timeout=TIMEOUT)
    tr = client.wait_for_message("NeedleTipToReference", timeout=TIMEOUT)
    np.testing.assert_array_equal(img.image, vol.transpose(1, 0, 2))  # (k=y, j=z, i=x)
    # voxel [z=2, y=1, x=3] -> (3 * 0.125, 1 * 0.25, 2 * 0.5) + the probe's translation
    np.testing.assert_allclose(img.ijk_to_world_matrix @ [3, 2, 1, 1],
                               [10.375, 20.25, 31.0, 1], atol=1e-5)
    np.testing.assert_allclose(tr.matrix[:3, 3], [10.1, 20.2, 30.3], atol=1e-5)


def test_no_client_sends_nothing_and_does_not_block(streamer):
    img = np.zeros((8, 8), np.uint8)
    for _ in range(300):  # more than pyigtl's queue holds
        assert streamer.send_frame(img, [0.1, 0.1], [1.0, 1.0], [0, 1], None, "tracking") is False
    assert streamer.frames_skipped == 300 and streamer.frames_sent == 0
    assert not streamer._server.outgoing_messages  # nothing stale for a later client


def test_port_in_use_is_named():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        with pytest.raises(StreamError, match=f"OpenIGTLink port {port} on 127.0.0.1: "
                                              "address already in use"):
            IGTLStreamer(port)


def test_names_ports_and_threads_are_checked():
    with pytest.raises(StreamError, match="is 24 bytes; the protocol keeps 20"):
        IGTLStreamer(0, tip_name="NeedleTipToReference1234")
    with pytest.raises(StreamError, match="port 70000"):
        IGTLStreamer(70000)
    with pytest.raises(StreamError, match="host 'nosuchif0': not 127.0.0.1 nor a network"):
        IGTLStreamer(0, host="nosuchif0")
    errors = []

    def worker():
        try:
            IGTLStreamer(0)
        except StreamError as exc:
            errors.append(str(exc))

    t = threading.Thread(target=worker)
    t.start()
    t.join(TIMEOUT)
    assert errors and "main thread" in errors[0]


def test_closed_streamer_restores_signal_handlers():
    import signal

    before = signal.getsignal(signal.SIGINT)
    with IGTLStreamer(0) as s:
        assert signal.getsignal(signal.SIGINT) is not before  # pyigtl's own handler
    assert signal.getsignal(signal.SIGINT) is before
    with pytest.raises(StreamError, match="closed"):
        s.send_frame(np.zeros((4, 4), np.uint8), [1, 1])
