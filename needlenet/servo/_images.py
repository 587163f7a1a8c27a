"""Ye 2025's loop closed through images: the scanner images the world from the probe's current
pose every 25 Hz frame and a feature source finds the needle's cross-section in the image.

The world is ``synth``'s ``servo`` scenario (Ye's tip path of section 4.1, a transverse
plane probe): x_p of the image = world +Y, its elevation = world -X, depth = world +Z. The
probe's pose is the controller's (X and Y of the mass-damper axes, Z fixed), never a recorded
one. Measurement, as section 4.2: when the detector finds the needle in the image at (x, z)
(image mm), z = (z_x, Y_probe + x, Z_probe + z), with z_x taken "directly from the position
of the ultrasound probe"; otherwise the EKF only predicts.

Elevation thickness. Ye's ideal detection sees the needle exactly when the plane is behind the
tip. A real image has an elevation beam of finite thickness, so the needle's echo (the bevel
and the last millimetre of shaft) is seen until the plane is ``reach`` mm *ahead* of the tip
(about the needle radius plus two elevation beam sigmas: ~1-1.5 mm for the servo scenario's
probe); Ye's gain K_e then holds the plane at that boundary, ahead of the tip, and z_x = probe
X carries the same bias. The paper is silent (its images are ideal); we keep Ye's control law
and remove the bias from the measurement: z_x = probe X - reach, with ``reach`` calibrated for
each detector once, before the loop, on a calibration world (another seed; the plane swept
across a known tip, reach = where the detection rate falls below one half), as one would
calibrate on a phantom. ``reach_mm=0`` gives Ye's uncorrected z_x.

Detector (:class:`CrossSectionDetector`): the detection step of Carriere's axial tracker on the
shaft map of any feature source (the variance image of Carriere eq. (1) for classical
features, the axial ONNX model's shaft probability for learned ones): the map smoothed at the
needle's radius, its maximum accepted when its robust score (max - median) / MAD reaches
``detect_score`` (and for learned maps a probability of at least ``min_peak``), refined to
sub-pixel, and for classical maps moved one radius below the echo's upper edge (the tracker's
``detect_anchor``).

World set-up. Imaging a plane that only translates in its own plane and in elevation costs a
slice of a cached 3D field of the tissue echo (``Scanner.prepare``); the fields along the
nominal path are built once before the loop (``setup_s``, not part of any cycle's latency) and
kept (the scanner itself keeps 8). A probe moving along X images new tissue: the speckle
decorrelates physically.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from ._ye import Measurement, YeServoConfig, ye_insertion_velocity, ye_tip_path

__all__ = ["CrossSectionDetector", "ServoImaging", "ServoWorld", "calibrate_reach",
           "make_detector", "servo_world"]

# probe frame -> world: x_p = +Y, y_p = -X, z_p = +Z (synth's ServoScenario)
_R_PROBE = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class ServoImaging:
    """The servo world's scanner. Defaults keep a frame small (160 x 96 at 0.3 mm, the
    axial model's spacing) and cover the tip's path: it starts 10 mm deep and sinks by
    ~33 mm over Ye's 2000 samples (Z is not servoed), so the image is 48 mm deep."""

    spacing_mm: float = 0.3
    width_mm: float = 28.8
    depth_mm: float = 48.0
    tip_depth_mm: float = 10.0
    scatterers_per_cell: float = 10.0
    gauge: int = 18
    background: str = "inhomogeneous"
    chunk_mm: float = 10.0  # elevation length of one prepared field
    lateral_pad_mm: float = 4.0  # lateral deviation from the nominal path a field allows


class _FieldCache(list):
    """The scanner's list of cached fields without its 8-field limit (``Scanner`` trims it
    with ``del fields[8:]`` after an on-demand build): the prepared fields along the path
    must survive. Trimming keeps at most ``limit`` fields instead."""

    limit = 64

    def __delitem__(self, key):
        if isinstance(key, slice) and key.stop is None and key.step is None:
            key = slice(max(int(key.start or 0), self.limit), None)
        super().__delitem__(key)


class ServoWorld:
    """The ``servo`` scenario's world and a scanner imaging it from any probe pose."""

    def __init__(self, seed: int, n_samples: int, imaging: ServoImaging | None = None,
                 frame_rate_hz: float = 25.0):
        from synth import scenario_params

        self.imaging = ServoImaging() if imaging is None else imaging
        im = self.imaging
        t0 = time.perf_counter()
        p = scenario_params("servo", n_samples=int(n_samples), frame_rate_hz=frame_rate_hz,
                            spacing_mm=im.spacing_mm, width_mm=im.width_mm,
                            depth_mm=im.depth_mm, tip_depth_mm=im.tip_depth_mm,
                            scatterers_per_cell=im.scatterers_per_cell, gauge=im.gauge,
                            background=im.background)
        self.params = p
        self.scanner, _ = p.build(p.draw(np.random.default_rng(seed)))
        self.scanner._fields = _FieldCache(self.scanner._fields)
        self.world = self.scanner.world
        self.grid = self.scanner.probe.grid
        self.radius_mm = self.world.needle.radius_mm
        self.step_mm = 0.5 * float(min(min(self.grid.spacing_mm), self.radius_mm))
        v = ye_insertion_velocity(int(n_samples), frame_rate_hz)
        self.s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) / frame_rate_hz)])
        self.tip, _ = ye_tip_path(v, frame_rate_hz, p.radius_of_curvature_mm)
        self.probe_z = -float(im.tip_depth_mm)
        self.rng = np.random.default_rng([seed, 7])
        self.build_s = time.perf_counter() - t0
        self.setup_s = 0.0

    def pose(self, probe_xyz) -> np.ndarray:
        pose = np.eye(4)
        pose[:3, :3] = _R_PROBE
        pose[:3, 3] = probe_xyz
        return pose

    def prepare(self, x_range=None) -> float:
        """Build the tissue fields along the nominal path (probe on the tip) once; returns
        the seconds spent."""
        from synth import invert_rigid

        t0 = time.perf_counter()
        im = self.imaging
        x = self.tip[:, 0] if x_range is None else np.asarray(x_range, float)
        y = np.interp(x, self.tip[:, 0], self.tip[:, 1])
        lo, hi = float(x.min()) - 2.0, float(x.max()) + 2.0
        edges = np.arange(lo, hi + im.chunk_mm, im.chunk_mm)
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            sel = (x >= a - 1.0) & (x <= b + 1.0)
            ys = y[sel] if np.any(sel) else np.interp([a, b], x, y)
            poses = np.stack([self.pose([xx, yy, self.probe_z])
                              for xx in (a - 0.5, b + 0.5)
                              for yy in (ys.min() - im.lateral_pad_mm,
                                         ys.max() + im.lateral_pad_mm)])
            # the same inverse as :meth:`image` (the cache keys are the transforms' bytes)
            self.scanner.prepare(np.stack([invert_rigid(q) for q in poses]))
        dt = time.perf_counter() - t0
        self.setup_s += dt
        return dt

    def image(self, k: int, probe_xyz, s_tip: float | None = None) -> np.ndarray:
        """The 8-bit image of frame k (tip at arc length ``s[k]``) from ``probe_xyz``."""
        from synth import apply_transform, invert_rigid

        pose = self.pose(probe_xyz)
        inv = invert_rigid(pose)
        s_tip = self.s[k] if s_tip is None else s_tip
        pts, tan, _ = self.world.needle_world(s_tip, np.eye(4), self.step_mm)
        pts = apply_transform(inv, pts)
        near = np.abs(pts[:, 1]) < 4.0  # beyond ~6 elevation sigmas the needle adds nothing
        frame = self.scanner.render(inv, pts[near], tan[near] @ inv[:3, :3].T, self.rng,
                                    self.step_mm)
        return frame.image

    def crossing(self, k: int, probe_x: float) -> np.ndarray | None:
        """Where the shaft crosses the plane X = probe_x (world), or None (plane ahead)."""
        s = np.linspace(max(self.s[k] - 20.0, 0.0), self.s[k], 401)
        pts = self.world.needle_path.point_at(s)
        dx = pts[:, 0] - probe_x
        idx = np.flatnonzero(np.sign(dx[:-1]) != np.sign(dx[1:]))
        if len(idx) == 0:
            return None
        j = idx[-1]
        f = dx[j] / (dx[j] - dx[j + 1])
        return pts[j] + f * (pts[j + 1] - pts[j])


class CrossSectionDetector:
    """The needle's cross-section in an axial image from a feature source's shaft map (see
    the module docstring). ``detect(image, grid)`` -> (found, (x, z) mm, score)."""

    def __init__(self, source, radius_mm: float = 0.635, detect_score: float | None = None,
                 min_peak: float | None = None):
        from ..trackers._axial import AxialParams

        self.source = source
        self.learned = getattr(source, "kind", "classical") == "learned"
        ap = AxialParams()
        self.radius_mm = float(radius_mm)
        self.detect_score = ap.detect_score if detect_score is None else float(detect_score)
        self.min_peak = (0.3 if self.learned else 0.0) if min_peak is None else float(min_peak)
        self.score_floor = ap.score_floor
        self.name = getattr(source, "name", type(source).__name__)

    def detect(self, image: np.ndarray, grid) -> tuple[bool, np.ndarray | None, float]:
        from ..features._base import Frame, FrameError, check_frame
        from ..trackers._axial import _below_top_edge, _subpixel

        frame = Frame(image, grid)
        try:
            check_frame(frame)
        except FrameError:  # nothing can be measured (e.g. a constant frame): not detected
            return False, None, 0.0
        F = np.ascontiguousarray(self.source.likelihood(frame).shaft, np.float32)
        sp = float(np.mean(grid.spacing_mm))
        S = cv2.GaussianBlur(F, (0, 0), self.radius_mm / sp)
        sub = S[::3, ::3]
        med = float(np.median(sub))
        mad = max(1.4826 * float(np.median(np.abs(sub - med))), self.score_floor)
        idx = np.unravel_index(int(np.argmax(S)), S.shape)
        score = (float(S[idx]) - med) / mad
        if score < self.detect_score or float(S[idx]) < self.min_peak:
            return False, None, score
        rc = np.asarray(idx, float) + _subpixel(S, idx)
        if not self.learned:  # Carriere's tracker: one radius below the echo's upper edge
            try:
                rc = _below_top_edge(F, rc, float(F.mean()),
                                     self.radius_mm / grid.spacing_mm[0])
            except ZeroDivisionError:  # a flat column at the edge (the helper's corner case)
                pass
        return True, grid.index_to_points(rc), score


def make_detector(features: str, model=None, radius_mm: float = 0.635, threads: int = 1):
    """A :class:`CrossSectionDetector` with ``features`` "learned" (the shipped axial ONNX
    model, or ``model``) or "classical" (Carriere's variance image)."""
    if features == "learned":
        from ..features import learned_features

        return CrossSectionDetector(learned_features("axial", model, threads=threads),
                                    radius_mm)
    if features == "classical":
        from ..features._variance import VarianceFeatures

        return CrossSectionDetector(VarianceFeatures(), radius_mm)
    raise ValueError(f"features must be 'learned' or 'classical' for images, got {features!r}")


def image_measurement(world: ServoWorld, detector: CrossSectionDetector, reach_mm: float,
                      gate_mm: float | None = None):
    """The ``measure`` callback of :func:`run_ye` for frames imaged from the probe's pose."""
    grid = world.grid

    def measure(k: int, probe_xyz: np.ndarray) -> Measurement:
        t0 = time.perf_counter()
        img = world.image(k, probe_xyz)
        t1 = time.perf_counter()
        found, xz, _ = detector.detect(img, grid)
        if not found:
            return Measurement(False, None, t1 - t0)
        # section 4.2: z_x from the probe's position (less the plane's reach, see above);
        # z_y, z_z: the detection, probe frame -> world
        z = np.array([probe_xyz[0] - reach_mm, probe_xyz[1] + xz[0], probe_xyz[2] + xz[1]])
        return Measurement(True, z, t1 - t0)

    return measure


_REACH_CACHE: dict = {}


def calibrate_reach(detector: CrossSectionDetector, imaging: ServoImaging | None = None,
                    seed: int = 1_000_003, arc_mm=(30.0, 60.0, 90.0),
                    offsets_mm=None) -> float:
    """How far ahead of the tip (mm) the detector still finds the needle: the plane is swept
    across the tip of a calibration world (seed distinct from any run) at a few arc lengths;
    a detection counts when it lies within 2 mm of the tip; reach = the offset where the
    detection rate first falls below one half (linear interpolation). Cached per detector
    and imaging."""
    imaging = ServoImaging() if imaging is None else imaging
    key = (detector.name, getattr(detector.source, "path", None), imaging, seed, tuple(arc_mm))
    if key in _REACH_CACHE:
        return _REACH_CACHE[key]
    d = np.arange(-1.0, 3.01, 0.1) if offsets_mm is None else np.asarray(offsets_mm, float)
    n = 2000
    w = ServoWorld(seed, n, imaging)
    rate = np.zeros(len(d))
    for s_tip in arc_mm:
        k = int(np.searchsorted(w.s, s_tip))
        tip = w.tip[k]
        w.prepare(np.array([tip[0] + d.min(), tip[0] + d.max()]))
        probe_y = tip[1]
        for i, di in enumerate(d):
            probe = np.array([tip[0] + di, probe_y, w.probe_z])
            found, xz, _ = detector.detect(w.image(k, probe), w.grid)
            if found:
                yz = np.array([probe[1] + xz[0], probe[2] + xz[1]])
                found = bool(np.linalg.norm(yz - tip[1:]) < 2.0)
            rate[i] += found / len(arc_mm)
    below = np.flatnonzero((rate < 0.5) & (d > d[np.argmax(rate)]))
    if len(below) == 0:
        reach = float(d[-1])
    else:
        j = int(below[0])
        if j == 0:
            reach = float(d[0])
        else:
            f = (rate[j - 1] - 0.5) / max(rate[j - 1] - rate[j], 1e-9)
            reach = float(d[j - 1] + f * (d[j] - d[j - 1]))
    _REACH_CACHE[key] = reach
    return reach


def servo_world(seed: int, n_samples: int, imaging: ServoImaging | None = None,
                config: YeServoConfig | None = None) -> ServoWorld:
    """A prepared :class:`ServoWorld` for ``n_samples`` frames of Ye's profile."""
    cfg = YeServoConfig() if config is None else config
    w = ServoWorld(seed, n_samples, imaging, cfg.frame_rate_hz)
    w.prepare()
    return w
