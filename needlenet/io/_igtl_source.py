"""Frames received live over OpenIGTLink: the images a PLUS Server (or a scanner's own
OpenIGTLink server) streams, tracked as they arrive.

A PLUS Server sends each ultrasound frame as an ``IMAGE`` message (``Image_Reference`` by
default): pixels in (k, j, i) order with k = 1 for a 2D frame, j along depth and i along the
transducer, and the IJK-to-world matrix that scales and places them. Read here:

- the spacing from the matrix's columns: depth ``|M[:, 1]|``, lateral ``|M[:, 0]|`` mm;
- the probe pose from the same columns normalised (probe x along i, z along j, y the plane's
  normal; in RAS, the frame results are sent in) and the matrix's translation, so a tracked
  probe's motion reaches the trackers (:attr:`~needlenet.features.Frame.probe_pose`) and
  results streamed back with ``--igtl`` land where the image is;
- the time from the message's timestamp;
- gray from colour (RGB components: luma, coloured marks filled in, as for videos), and other
  pixel types scaled to 0..255 frame by frame (each frame's own range: the learned model's
  input does not move with gain).

pyigtl's client keeps the latest message of each device: when tracking is slower than the
stream, frames in between are skipped and the tracker works on the newest one. The stream
ends when no new frame comes for ``idle_s`` seconds (or none within ``connect_s`` of the
start). Volumes (k > 1) are refused: PLUS sends them in its own axis order, and the volume
trackers read recorded files.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator

import numpy as np

from ._errors import StreamError

__all__ = ["IGTLSource", "parse_igtl_url", "DEFAULT_IMAGE_DEVICE", "DEFAULT_IGTL_PORT"]

DEFAULT_IMAGE_DEVICE = "Image_Reference"  # PLUS Server's default image stream
DEFAULT_IGTL_PORT = 18944  # OpenIGTLink's registered port, PLUS Server's default
_URL = re.compile(r"igtl://(?P<host>[^:/\s]+)(?::(?P<port>\d{1,5}))?(?:/(?P<device>[^/\s]+))?/?")


def parse_igtl_url(text: str) -> tuple[str, int, str]:
    """``igtl://HOST[:PORT][/DEVICE]`` -> (host, port, device); a StreamError naming the
    form expected otherwise."""
    m = _URL.fullmatch(str(text).strip())
    if m is None:
        raise StreamError(f"{text!r}: an OpenIGTLink source is igtl://HOST[:PORT][/DEVICE], "
                          f"e.g. igtl://127.0.0.1:{DEFAULT_IGTL_PORT}/{DEFAULT_IMAGE_DEVICE}")
    port = int(m["port"]) if m["port"] else DEFAULT_IGTL_PORT
    if not 1 <= port <= 65535:
        raise StreamError(f"{text!r}: port {port} is not 1 to 65535")
    return m["host"], port, m["device"] or DEFAULT_IMAGE_DEVICE


class IGTLSource:
    """An OpenIGTLink client receiving the ``device``'s IMAGE messages as frames (see the
    module's doc). Use as a context manager, or call :meth:`close`."""

    def __init__(self, host: str, port: int, device: str = DEFAULT_IMAGE_DEVICE, *,
                 connect_s: float = 30.0, idle_s: float = 5.0):
        import pyigtl

        for name, v in (("connect_s", connect_s), ("idle_s", idle_s)):
            if not (np.isfinite(v) and 0.0 < v <= 3600.0):
                raise StreamError(f"{name} must be in (0, 3600] seconds, got {v}")
        self.host, self.port, self.device = host, int(port), device
        self.connect_s, self.idle_s = float(connect_s), float(idle_s)
        self.frames_received = 0
        self._client = pyigtl.OpenIGTLinkClient(host=host, port=self.port)

    def __enter__(self) -> IGTLSource:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._client is not None:
            self._client.stop()
            self._client = None

    def frames(self) -> Iterator:
        """The frames as they arrive (:class:`~needlenet.features.Frame`, ``index`` counting
        the frames received), until the stream pauses for ``idle_s``."""
        start = time.monotonic()
        while self._client is not None:
            wait = self.connect_s - (time.monotonic() - start) if not self.frames_received \
                else self.idle_s
            msg = self._client.wait_for_message(self.device, timeout=max(wait, 0.0))
            if msg is None:
                if not self.frames_received:
                    raise StreamError(
                        f"no IMAGE {self.device!r} from {self.host}:{self.port} within "
                        f"{self.connect_s:g} s (is the server running and sending that "
                        "device? PLUS Server's default is Image_Reference)")
                return
            if getattr(msg, "message_type", "IMAGE") != "IMAGE":
                raise StreamError(f"{self.host}:{self.port}: {self.device!r} is a "
                                  f"{msg.message_type} stream, not IMAGE")
            yield frame_from_image_message(msg, self.frames_received, self.device)
            self.frames_received += 1


def frame_from_image_message(msg, index: int, device: str = DEFAULT_IMAGE_DEVICE):
    """A :class:`~needlenet.features.Frame` from a pyigtl ``ImageMessage`` (see the
    module's doc); a StreamError for one that is not a 2D image with a usable matrix."""
    from ..features import Frame
    from ._frames import _gray
    from ._gray import to_gray_uint8

    where = f"OpenIGTLink {device!r} frame {index}"
    im = np.asarray(msg.image)
    if im.ndim == 4 and im.shape[0] == 1:  # (1, j, i, components)
        c = im.shape[3]
        if c == 1:
            im = im[0, :, :, 0]
        elif c in (3, 4) and im.dtype == np.uint8:
            im = _gray(np.ascontiguousarray(im[0, :, :, 2::-1]))  # RGB -> BGR, alpha dropped
        else:
            raise StreamError(f"{where}: {c} components of {im.dtype}; needlenet reads gray "
                              "or 8-bit RGB images")
    elif im.ndim == 3 and im.shape[0] == 1:
        im = im[0]
    elif im.ndim == 2:
        pass
    else:
        raise StreamError(f"{where}: an image of shape {im.shape} (k, j, i); needlenet tracks "
                          "2D frames over OpenIGTLink (k = 1); record volumes and track the file")
    if im.shape[0] < 2 or im.shape[1] < 2:
        raise StreamError(f"{where}: {im.shape[1]}x{im.shape[0]} pixels is no image")
    if im.dtype != np.uint8:
        im = to_gray_uint8(im[None], 1)[0][0]
    # a frame of its own in one layout, as a recording's frames are: the trackers' compiled
    # code then runs on it as it is (a view into the message's buffer is read-only and
    # strided, each a version to compile while the stream runs)
    im = np.require(im, np.uint8, ["C_CONTIGUOUS", "WRITEABLE", "OWNDATA"])
    m = np.asarray(msg.ijk_to_world_matrix, float)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise StreamError(f"{where}: its IJK-to-world matrix is not 4 x 4 finite numbers")
    if str(getattr(msg, "world_coordinate_system", "lps")).lower() == "lps":
        m = np.diag([-1.0, -1.0, 1.0, 1.0]) @ m  # to RAS, the frame results are sent in
    di, dj = (float(np.linalg.norm(m[:3, k])) for k in (0, 1))
    if not (di > 0 and dj > 0):
        raise StreamError(f"{where}: its IJK-to-world matrix gives pixels of {dj:g} x {di:g} "
                          "mm (depth x lateral)")
    ui, uj = m[:3, 0] / di, m[:3, 1] / dj
    un = np.cross(uj, ui)  # the plane's normal: probe y (elevation), x y z right-handed
    if np.linalg.norm(un) < 1e-6:
        raise StreamError(f"{where}: its IJK-to-world matrix's i and j axes are parallel")
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = ui, un / np.linalg.norm(un), uj
    pose[:3, 3] = m[:3, 3]
    t = float(getattr(msg, "timestamp", 0.0) or 0.0)
    spacing = tuple(float(f"{v:.7g}") for v in (dj, di))  # the wire's float32, no further
    return Frame.from_image(np.ascontiguousarray(im), spacing, t=t, index=index,
                            probe_pose=pose)
