"""Stream tracking results live over OpenIGTLink (pyigtl), e.g. to 3D Slicer's OpenIGTLinkIF.

Per frame, to the one connected client:

- ``IMAGE`` ``Image_Reference``: the frame; its IJK-to-world matrix places pixel (i, j) at
  probe-frame (x, y, z) = (x0 + i * dx, 0, z0 + j * dz) mm (volumes: k along elevation), times
  ``probe_pose`` when one is given. The coordinate system field says RAS, so receivers apply no
  LPS flip and image and transforms share one frame;
- ``TRANSFORM`` ``NeedleTipToReference``: origin at the tip, +Z along the insertion direction
  (see :func:`needle_tip_matrix`), while the tracker is tracking;
- ``POINT`` ``NeedleTip`` and ``NeedleEntry``: the tip and the entry point (when known);
- ``STRING`` ``NeedleStatus``: ``searching``, ``tracking`` or ``lost``.

pyigtl's limits, handled here: a device name is cut at 20 bytes on the wire, so longer names
are refused; its server installs SIGINT/SIGTERM handlers and so must be created on the main
thread (and they are put back on :meth:`IGTLStreamer.close`); messages are queued and sent by
pyigtl's own thread, so :meth:`IGTLStreamer.send_frame` never waits, and when no client is
connected it sends nothing (pyigtl would otherwise queue stale frames for the next client).
"""

from __future__ import annotations

import errno
import signal
import struct
import threading
import time

import numpy as np

from ._errors import StreamError
from ._recording import needle_tip_matrix

__all__ = ["IGTLStreamer", "check_device_name", "MAX_DEVICE_NAME"]

MAX_DEVICE_NAME = 20  # bytes: the OpenIGTLink header's device name field


def check_device_name(name: str) -> str:
    """A device name that survives the 20-byte header field, or :class:`StreamError`."""
    if not isinstance(name, str) or not name:
        raise StreamError(f"OpenIGTLink device name {name!r}: must be a non-empty string")
    n = len(name.encode("utf-8"))
    if n > MAX_DEVICE_NAME:
        raise StreamError(f"OpenIGTLink device name {name!r} is {n} bytes; the protocol keeps "
                          f"{MAX_DEVICE_NAME}")
    return name


class IGTLStreamer:
    """An OpenIGTLink server that sends one tracked frame at a time.

    ``port`` 0 picks a free port (see :attr:`port`). ``host`` is ``"127.0.0.1"`` (loopback,
    the default) or, to serve other machines, a network interface name such as ``"eth0"``
    (pyigtl binds to that interface's address). Use as a context manager or call
    :meth:`close`.
    """

    def __init__(self, port: int, host: str = "127.0.0.1", *, image_name: str = "Image_Reference",
                 tip_name: str = "NeedleTipToReference", tip_point_name: str = "NeedleTip",
                 entry_point_name: str = "NeedleEntry", status_name: str = "NeedleStatus"):
        try:
            port = int(port)
        except (TypeError, ValueError):
            raise StreamError(f"OpenIGTLink port {port!r}: must be an integer") from None
        if not 0 <= port <= 65535:
            raise StreamError(f"OpenIGTLink port {port}: must be 0 to 65535")
        self.names = {k: check_device_name(v) for k, v in (
            ("image", image_name), ("tip", tip_name), ("tip_point", tip_point_name),
            ("entry_point", entry_point_name), ("status", status_name))}
        if threading.current_thread() is not threading.main_thread():
            raise StreamError("the OpenIGTLink server must be created on the main thread "
                              "(pyigtl installs signal handlers)")
        import pyigtl

        self._pyigtl = pyigtl
        local = host in ("127.0.0.1", "localhost")
        previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            # pyigtl looks a non-loopback interface up by name with fcntl, as bytes
            self._server = pyigtl.OpenIGTLinkServer(port=port, local_server=local,
                                                    iface=None if local else host.encode())
        except OSError as exc:
            why = "address already in use" if exc.errno == errno.EADDRINUSE else str(exc)
            raise StreamError(f"OpenIGTLink port {port} on {host}: {why}") from None
        except (struct.error, TypeError, ValueError):
            raise StreamError(f"OpenIGTLink host {host!r}: not 127.0.0.1 nor a network "
                              "interface name such as eth0") from None
        self._previous_handlers = previous
        self.host = self._server.server_address[0]
        self.port = int(self._server.server_address[1])
        self.frames_sent = 0
        self.frames_skipped = 0
        self._closed = False

    # -- state -----------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return (not self._closed) and bool(self._server.is_connected())

    def wait_for_client(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` seconds for a client; True when one is connected."""
        end = time.monotonic() + max(0.0, float(timeout_s))
        while not self.connected and time.monotonic() < end:
            time.sleep(0.02)
        return self.connected

    # -- messages ---------------------------------------------------------------------------
    def image_message(self, image, spacing, origin=None, probe_pose=None, timestamp=None):
        """An IMAGE message of a frame in array order ([depth, lateral] or [depth, elevation,
        lateral]) with ``spacing``/``origin`` in array order (mm)."""
        img = np.asarray(image)
        sp = np.asarray(spacing, float)
        nd = img.ndim
        org = np.zeros(nd) if origin is None else np.asarray(origin, float)
        if nd not in (2, 3) or sp.shape != (nd,) or org.shape != (nd,):
            raise ValueError(f"image {img.shape} needs {img.ndim} spacings and origins, got "
                             f"{sp.shape} and {org.shape}")
        m = np.eye(4)
        if nd == 2:
            vox = img[None]  # pyigtl's (k, j, i): i lateral, j depth, one slice
            m[:3, 0], m[:3, 1], m[:3, 2] = (sp[1], 0, 0), (0, 0, sp[0]), (0, -1, 0)
            m[:3, 3] = (org[1], 0.0, org[0])
        else:
            vox = img.transpose(1, 0, 2)  # [z, y, x] -> (k = y, j = z, i = x)
            m[:3, 0], m[:3, 1], m[:3, 2] = (sp[2], 0, 0), (0, 0, sp[0]), (0, sp[1], 0)
            m[:3, 3] = (org[2], org[1], org[0])
        if probe_pose is not None:
            m = np.asarray(probe_pose, float) @ m
        return self._pyigtl.ImageMessage(np.ascontiguousarray(vox), ijk_to_world_matrix=m,
                                         world_coordinate_system="ras", timestamp=timestamp,
                                         device_name=self.names["image"])

    def send_frame(self, image, spacing, tip=None, direction=None, entry=None,
                   status="tracking", *, origin=None, probe_pose=None,
                   timestamp: float | None = None) -> bool:
        """Queue one frame's messages; never waits. ``tip``, ``direction`` and ``entry`` are in
        point order ((x, z) or (x, y, z), mm, probe frame); ``status`` a tracker status (its
        value or the enum). Returns False (and sends nothing) when no client is connected."""
        if self._closed:
            raise StreamError(f"OpenIGTLink server on port {self.port} is closed")
        if not self._server.is_connected():
            self.frames_skipped += 1
            return False
        P = self._pyigtl
        status = getattr(status, "value", status)
        pose = None if probe_pose is None else np.asarray(probe_pose, float)
        msgs = [self.image_message(image, spacing, origin, pose, timestamp),
                P.StringMessage(str(status), timestamp=timestamp,
                                device_name=self.names["status"])]

        def to_ref(m):
            return m if pose is None else pose @ m

        tip_ok = tip is not None and np.all(np.isfinite(np.asarray(tip, float)))
        if status == "tracking" and tip_ok:
            tm = to_ref(needle_tip_matrix(tip, direction))
            msgs.append(P.TransformMessage(tm, timestamp=timestamp, device_name=self.names["tip"]))
            msgs.append(P.PointMessage(tm[:3, 3], names="tip", timestamp=timestamp,
                                       device_name=self.names["tip_point"]))
            if entry is not None and np.all(np.isfinite(np.asarray(entry, float))):
                em = to_ref(needle_tip_matrix(entry))
                msgs.append(P.PointMessage(em[:3, 3], names="entry", timestamp=timestamp,
                                           device_name=self.names["entry_point"]))
        for msg in msgs:
            self._server.send_message(msg, wait=False)
        self.frames_sent += 1
        return True

    # -- shutdown ---------------------------------------------------------------------------
    def close(self, flush_timeout_s: float = 1.0) -> None:
        """Send what is queued (up to ``flush_timeout_s`` while a client is connected), stop
        the server and put the previous SIGINT/SIGTERM handlers back."""
        if self._closed:
            return
        srv = self._server
        end = time.monotonic() + max(0.0, flush_timeout_s)
        while srv.is_connected() and time.monotonic() < end:
            with srv.lock_outgoing_messages:
                if not srv.outgoing_messages:
                    break
            time.sleep(0.01)
        self._closed = True
        try:
            srv.stop()
        finally:
            if threading.current_thread() is threading.main_thread():
                for sig, handler in self._previous_handlers.items():
                    if handler is not None:
                        signal.signal(sig, handler)

    def __enter__(self) -> IGTLStreamer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
