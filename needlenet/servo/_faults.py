"""Faults injected into a servo loop's measurement to exercise its watchdogs (``needlenet servo
--fault``): shared by Ye's loop (:func:`~needlenet.servo.run_ye`) and Chatelain's
(:func:`~needlenet.servo.run_chatelain`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

__all__ = ["FAULTS", "Fault"]

FAULTS = ("frozen-feed", "stuck-detector", "needle-lost", "never-found")


@dataclass(frozen=True)
class Fault:
    """A fault in the measurement from frame ``frame`` on: ``frozen-feed`` (the feed repeats
    the frame before: the same measurement again), ``stuck-detector`` (the detector reports
    the needle at its last detection whatever the image shows), ``needle-lost`` (no needle in
    the image) or ``never-found`` (none from the first frame; ``frame`` is ignored).
    ``frame=None``: the loop's own choice, the middle of the run (Ye) or of the insertion
    (Chatelain), when the needle is tracked."""

    kind: str
    frame: int | None = None

    def __post_init__(self) -> None:
        if self.kind not in FAULTS:
            raise ValueError(f"fault must be one of {', '.join(FAULTS)}, got {self.kind!r}")
        if self.frame is not None and self.frame < 0:
            raise ValueError(f"fault frame must be >= 0, got {self.frame}")

    def at(self, default_frame: int) -> Fault:
        """This fault with ``frame`` set (``default_frame`` where it was None)."""
        return self if self.frame is not None else replace(self, frame=int(default_frame))

    @property
    def start(self) -> int:
        return 0 if self.kind == "never-found" else int(self.frame or 0)

    def wrap(self, measure: Callable):
        """``measure`` (Ye's loop: frame, probe position -> :class:`Measurement`) with the
        fault from :attr:`start` on."""
        from ._ye import Measurement
        last: list = [None, None]  # the last measurement, the last detection's z

        def faulty(k: int, probe_xyz: np.ndarray):
            if k < self.start:
                m = measure(k, probe_xyz)
                last[0] = m
                if m.detected and m.z is not None:
                    last[1] = np.asarray(m.z, float).copy()
                return m
            if self.kind in ("needle-lost", "never-found"):
                return Measurement(False)
            if self.kind == "frozen-feed":  # the same frame again, its time not advancing
                m = last[0] if last[0] is not None else Measurement(False)
                return m._replace(stale=True)
            if last[1] is None:  # stuck before any detection: reports nothing
                return Measurement(False)
            z = last[1].copy()
            z[0] = probe_xyz[0]  # z_x is the probe's position (section 4.2); y, z stuck
            return Measurement(True, z)

        return faulty
