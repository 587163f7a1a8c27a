"""Where the image changes between frames: an advancing needle's tip on a line the map cannot end.

A needle being inserted moves and the tissue beside it, under a still probe, does not (much):
between two frames echo appears where the bevel now is, and the shaft behind it stays. Tissue
lines, interfaces and a needle that has stopped do not change; a needle that leaves the plane
or is drawn back loses echo. Where a needle's shaft map runs on along a bright interface
beside it (the two merge into one line that crosses the view and shows no tip), the echo
gained on that line tells where the needle's tip is. The needle's motion is a cue of its own
in the literature where the B-mode image alone does not show the needle (Beigi et al.,
Ultrasonics 2017: time-domain features of the needle's motion; Ayvali and Desai, Ann. Biomed.
Eng. 2015: optical flow).

:class:`MotionTip` keeps the frame before and reads on a line the grey levels gained since
then, smoothed over ``smooth_mm`` (about a speckle cell, so that single pixels' noise makes no
peak), at each point along the line their maximum over ``band_mm`` either side of it. The
tip is the strongest gain on the line, taken only where it stands out of the change of the
whole imaged region (``min_z`` robust standard deviations above the median of the region's
absolute change, smoothed alike; its median absolute deviation, at least one grey level, the
step of 8-bit images), and where the run about it is short (``max_run_mm``: the bevel's new
place with its point spread, a few millimetres at an insertion's speed), and only while the
shaft behind the run stays: where the line behind it lost echo (the median along it of the
loss, smoothed alike, reaching the same ``min_z``), a needle left the plane (tissue its
shadow hid gains echo) or the probe moved, and no tip advanced. A probe moved by
hand, or breathing, changes the whole frame: the median and spread rise with it and no short
run stands out; along an interface that moves across itself the gain runs the whole line.
Then nothing is read.

:class:`MotionMark` keeps the tip read so on the frame before: a tip read on a line without
a track (or outside the tip filter's gate) is taken only once it has been seen advancing
along the line on consecutive frames (``growing.growth_mm`` further than on the frame before,
no faster than the tracker's speed prior allows).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._sampling import remap_points
from ..features import Frame

__all__ = ["MotionTipParams", "MotionPeak", "MotionTip", "MotionMark"]

_STAT_SAMPLES = 20_000  # pixels (strided) the region's median and spread are read from: their
# standard errors are about 1% of the spread


@dataclass(frozen=True)
class MotionTipParams:
    """``smooth_mm``: the Gaussian's standard deviation over the change image (0.3 mm: about
    half a speckle cell of the probes needlenet meets). ``band_mm``: how far either side of
    the line the change is read (3 mm: a needle's map merged with an interface beside it lies
    up to that far from the merged line). ``step_mm``: the sampling step along and across.
    ``min_z``: how far, in robust standard deviations of the region's change, the tip's gain
    must stand out of the region's median (10: three times the strongest gain that speckle
    moving with breathing tissue shows on a line, 3.4 on synth's tissue moving 2 mm; an
    advancing needle's tip stands out 20-100).
    ``max_run_mm``: the longest run about the peak where the change is at least half the
    peak's (6 mm: a tip advancing a few millimetres between frames, plus the point spread
    at either end). ``edge_room_mm``: a tip read this close to the edge of the view, along
    the line, is not read (the needle may run on out of view there)."""

    smooth_mm: float = 0.3
    band_mm: float = 3.0
    step_mm: float = 0.2
    min_z: float = 10.0
    max_run_mm: float = 6.0
    edge_room_mm: float = 3.0

    def __post_init__(self) -> None:
        for name in ("smooth_mm", "band_mm", "step_mm", "max_run_mm"):
            if not 0.0 < getattr(self, name) <= 100.0:
                raise ValueError(f"{name} must lie in (0, 100] mm, got {getattr(self, name)}")
        if not 0.0 <= self.edge_room_mm <= 100.0:
            raise ValueError(f"edge_room_mm must lie in [0, 100] mm, got {self.edge_room_mm}")
        if not self.min_z > 0:
            raise ValueError(f"min_z must be positive, got {self.min_z}")


@dataclass(frozen=True)
class MotionPeak:
    """The strongest gain of echo on a line: ``point_mm`` (x, z) where it lies (across the
    line, the shallowest gain of half the peak's there), ``along_mm`` its
    distance from the line's start along it, ``z`` how far it stands out (robust SDs) and
    ``run_mm`` the length of the changed run about it."""

    point_mm: np.ndarray
    along_mm: float
    z: float
    run_mm: float


class MotionTip:
    """The change between this frame and the one before, read along lines (module doc)."""

    def __init__(self, params: MotionTipParams | None = None):
        self.params = MotionTipParams() if params is None else params
        self.reset()

    def reset(self) -> None:
        self._prev: np.ndarray | None = None
        self._cur: np.ndarray | None = None
        self._change: tuple | None = None  # this frame's, see _region_change

    def observe(self, frame: Frame) -> None:
        """This frame becomes the one the next frame is compared with; call once per frame,
        before reading it. A frame identical to the one before (a screen capture faster
        than the scanner repeats frames) changes nothing: the change read is the last one."""
        image = np.asarray(frame.image)
        if self._cur is not None and image.shape == self._cur.shape and \
                np.array_equal(image, self._cur):
            return
        self._prev = self._cur
        self._cur = np.array(image, copy=True)  # a reader may reuse its buffer
        self._change = None
        if self._prev is not None and self._prev.shape != self._cur.shape:
            self._prev = None

    def _region_change(self, frame: Frame, inner: np.ndarray) -> tuple | None:
        """(the smoothed gain and loss, the median and robust spread of the smoothed absolute
        change over ``inner``, the factors (rows, columns) from the frame's pixels to the
        gain's), computed once per frame on pixels no finer than half ``smooth_mm``."""
        if self._prev is None:
            return None
        if self._change is None:
            p = self.params
            cur, prev, keep = self._cur, self._prev, inner.view(np.uint8)
            if cur.dtype not in (np.uint8, np.float32):
                cur, prev = cur.astype(np.float32), prev.astype(np.float32)
            h, w = cur.shape
            fz, fx = (min(1.0, s / (0.5 * p.smooth_mm)) for s in frame.grid.spacing_mm)
            size = (max(1, int(round(w * fx))), max(1, int(round(h * fz))))
            if size != (w, h):  # 8-bit frames averaged in 8 bits: within half a grey level
                cur, prev = (cv2.resize(a, size, interpolation=cv2.INTER_AREA)
                             for a in (cur, prev))
                keep = cv2.resize(keep, size, interpolation=cv2.INTER_NEAREST)
            cur, prev = cur.astype(np.float32), prev.astype(np.float32)
            factors = (size[1] / h, size[0] / w)
            sz, sx = (p.smooth_mm / (sp / f) for sp, f in zip(frame.grid.spacing_mm, factors,
                                                           strict=True))
            signed = cur - prev
            gained = cv2.GaussianBlur(np.maximum(signed, 0.0), (0, 0), sigmaX=sx, sigmaY=sz)
            lost = cv2.GaussianBlur(np.maximum(-signed, 0.0), (0, 0), sigmaX=sx, sigmaY=sz)
            vals = (gained + lost)[keep > 0]  # the smoothed absolute change
            vals = vals[::max(1, vals.size // _STAT_SAMPLES)]
            if vals.size == 0:
                self._change = (gained, lost, 0.0, np.inf, factors)
            else:
                med = float(np.median(vals))
                scale = max(1.4826 * float(np.median(np.abs(vals - med))), 1.0)
                self._change = (gained, lost, med, scale, factors)
        return self._change

    def peak_on(self, frame: Frame, inner: np.ndarray, start_mm: np.ndarray,
                direction: np.ndarray, room_mm: float) -> MotionPeak | None:
        """The tip's change on the line from ``start_mm`` along the unit ``direction`` to the
        edge of the view, ``room_mm`` further on; None where no short run of change stands
        out there (or there is no frame before, or the peak lies within ``edge_room_mm`` of
        the edge)."""
        change = self._region_change(frame, inner)
        if change is None or not room_mm > 0:
            return None
        gained, lost, med, scale, (fr, fc) = change
        p = self.params
        s = np.arange(0.0, room_mm + 1e-9, p.step_mm)
        c = np.arange(-p.band_mm, p.band_mm + 1e-9, p.step_mm)
        u = np.asarray(direction, float)
        n = np.array([-u[1], u[0]])
        pts = start_mm[None, None] + s[:, None, None] * u + c[None, :, None] * n
        idx = frame.grid.points_to_index(pts.reshape(-1, 2))  # pixel centres kept
        cols, rows = (idx[:, 1] + 0.5) * fc - 0.5, (idx[:, 0] + 0.5) * fr - 0.5
        v = remap_points(gained, cols, rows).reshape(len(s), len(c))
        i, j = np.unravel_index(int(np.argmax(v)), v.shape)
        peak = float(v[i, j])
        z = (peak - med) / scale
        if not z >= p.min_z or s[i] > room_mm - p.edge_room_mm:  # NaN too
            return None
        hot = v.max(axis=1) >= med + 0.5 * (peak - med)
        cold_before = np.flatnonzero(~hot[:i])
        cold_after = np.flatnonzero(~hot[i + 1:])
        a = cold_before[-1] + 1 if cold_before.size else 0
        b = i + cold_after[0] if cold_after.size else len(s) - 1
        run = (b - a + 1) * p.step_mm
        if run > p.max_run_mm:
            return None
        # the shaft behind the tip stays: where it lost its echo along the line (a needle that
        # leaves the plane, or a probe moved), no tip advanced
        if a > 0:
            n_behind = a * len(c)  # the samples before the run, row-major
            behind = remap_points(lost, cols[:n_behind], rows[:n_behind]).reshape(a, len(c))
            if np.median(behind.max(axis=1)) >= med + p.min_z * scale:
                return None
        # the shallowest gain at half the peak's across the line there: the needle's own
        # echo comes first, its reverberations follow deeper
        deeper = n[1] >= 0
        half = np.flatnonzero(v[i] >= med + 0.5 * (peak - med))
        k = half[0] if deeper else half[-1]
        return MotionPeak(pts[i, k].copy(), float(s[i]), float(z), float(run))


class MotionMark:
    """The tip read from the gain of echo on a line on the frame before (module doc)."""

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self._last: tuple | None = None  # (t, entry, direction, tip)

    def advanced(self, t: float, entry_mm: np.ndarray, direction: np.ndarray,
                 tip_mm: np.ndarray, window_deg: float, window_mm: float, growth_mm: float,
                 max_speed_mm_s: float, max_gap_s: float) -> bool:
        """Whether ``tip_mm``, read now (time ``t``) on the line entering at ``entry_mm``
        along the unit ``direction`` (entry to tip), lies ``growth_mm`` or more further along
        the same line than the tip read on the frame before (at most ``max_gap_s`` before;
        directions within ``window_deg``, entries and the tip's distance from the line before
        within ``window_mm``), no faster than ``max_speed_mm_s``; the tip read now is kept
        for the next frame."""
        last, self._last = self._last, (t, entry_mm.copy(), direction.copy(), tip_mm.copy())
        if last is None:
            return False
        t0, e0, d0, p0 = last
        step = tip_mm - p0
        across = abs(float(step[0] * d0[1] - step[1] * d0[0]))
        if not 0.0 < t - t0 <= max_gap_s or \
                float(d0 @ direction) < np.cos(np.deg2rad(window_deg)) or \
                float(np.linalg.norm(entry_mm - e0)) > window_mm or across > window_mm:
            return False
        grown = float(step @ d0)
        return growth_mm <= grown <= max_speed_mm_s * (t - t0) + window_mm
