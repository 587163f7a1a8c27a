"""Ye 2025's loop closed through images: the scanner images the world from the probe's current
pose every 25 Hz frame and a feature source finds the needle's cross-section in the image.

The world is ``synth``'s ``servo`` scenario (Ye's tip path of section 4.1, a transverse
plane probe): x_p of the image = world +Y, its elevation = world -X, depth = world +Z. The
probe's pose is the controller's (X and Y of the mass-damper axes, Z fixed), never a recorded
one. Measurement, as section 4.2: when the detector finds the needle in the image at (x, z)
(image mm), z = (z_x, Y_probe + x, Z_probe + z), with z_x taken "directly from the position
of the ultrasound probe"; otherwise the EKF only predicts.

Elevation thickness, and what "detected" means. Ye's controller (eq. (13)) assumes the
needle is detected exactly when the plane is behind the tip (section 3.1: "when the needle is
not detected ... the scanning plane is ahead of the needle tip"). A real image has an
elevation beam of finite thickness (-6 dB full width ~1.1-1.4 mm for the servo scenario's
probe), and the scanner's specular shaft echo keeps full strength while the plane is within
a needle radius of the shaft: a detector that accepts any needle-like echo still finds the
needle ~1.5 mm *ahead* of the tip, so K_e parks the plane there, outside the slice. The shipped
learned shaft map does not help: it saturates (smoothed peak 0.50-0.56) from 1 mm behind the
tip to 0.6 mm ahead of it, so no threshold on its peak or its robust score separates the
two (measured on the calibration worlds: the boundary such a threshold gives wanders by more
than +-1 mm between arcs). What does change where the plane leaves the shaft is the echo's
amplitude: the shaft samples inside the elevation beam add coherently, and with the plane at
the tip only the half behind it is left (-6 dB, ~22 grey levels of the 70 dB log
compression; ~12-25 grey levels per mm there). So the detector localises the needle with
its feature map (learned or classical) and *accepts* it only when the echo's grey level there
reaches ``echo_threshold``. The level is absolute, not relative to the tissue: the needle's
specular echo does not scale with the tissue's echogenicity (the median of the image varies by
+-8 grey levels between worlds of the inhomogeneous background; the echo does not), while the
scanner's gain, TGC and compression are the calibration's. :func:`calibrate_detector` sets the
threshold once, before any loop, on calibration worlds whose seeds are disjoint from every
run's: the plane is swept across a known tip at arc lengths spanning the path's depths, the
echo level with the plane ``target_mm`` (default 0: at the tip) from the tip is read
off each sweep, and the threshold is interpolated in depth between the arcs (the elevation
beam, hence the echo, changes with the distance to the elevation focus: ~158 grey levels at
10 mm, ~175 at 15-34 mm). Detection then stops where the plane passes the tip (calibrated
reach ~0), Ye's gain law holds the plane just behind the tip with the tip inside the slice,
and z_x is the probe's X as section 4.2 says (no correction afterwards).

In-plane. ``in_plane`` is physical: the tip lies inside the imaged slice, |p_x - p_ux| <= the
half-width of the -6 dB elevation beam of the scanner's pulse-echo PSF at the tip's depth
(:func:`slice_half_width_mm`, from ``ImagingParams.psf_fwhm_mm``). ``behind`` (the probe
behind the tip, Ye's lead-lag) is reported separately.

Learned maps of the needle's wall. A model whose ONNX metadata says ``target_reference =
"wall"`` marks the wall facing the probe; the needle's centre lies one radius deeper (+z, as in
the axial tracker's ``_detect``), so the detection is moved by the needle's radius (the
world's needle, or ``radius_mm``). ``"centerline"`` maps are used as they are.

World set-up. Imaging a plane that only translates in its own plane and in elevation costs a
slice of a cached 3D field of the tissue echo (``Scanner.prepare``); the fields along the
nominal path are built once before the loop (``setup_s``, not part of any cycle's latency) and
kept (the scanner's ``field_cache_size`` is raised to 64 fields). A probe moving along X
images new tissue: the speckle decorrelates physically.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from ._ye import Measurement, YeServoConfig, ye_insertion_velocity, ye_tip_path

__all__ = ["CALIBRATION_SEEDS", "CrossSectionDetector", "DetectorCalibration", "EchoThreshold",
           "ServoImaging", "ServoWorld", "calibrate_detector", "calibrate_reach", "in_slice",
           "make_detector", "servo_world", "slice_half_width_mm"]

# seeds of the worlds :func:`calibrate_detector` calibrates on (runs must use other seeds)
CALIBRATION_SEEDS = (1_000_003, 1_000_004)

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
    # the straight shaft behind the entry point (in the insertion device's guide and, in
    # Ye's water-bath phantom, in the water): synth's world holds the needle from its entry
    # on, but a probe at the entry must see a shaft crossing its plane, not a needle end
    shaft_behind_entry_mm: float = 20.0
    chunk_mm: float = 10.0  # elevation length of one prepared field
    lateral_pad_mm: float = 4.0  # lateral deviation from the nominal path a field allows


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
        # the prepared fields along the whole path must survive on-demand builds
        self.scanner.field_cache_size = 64
        self.world = self.scanner.world
        self.grid = self.scanner.probe.grid
        self.radius_mm = self.world.needle.radius_mm
        self.step_mm = 0.5 * float(min(min(self.grid.spacing_mm), self.radius_mm))
        v = ye_insertion_velocity(int(n_samples), frame_rate_hz)
        self.s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) / frame_rate_hz)])
        self.tip, _ = ye_tip_path(v, frame_rate_hz, p.radius_of_curvature_mm)
        self.probe_z = -float(im.tip_depth_mm)
        self.rng = np.random.default_rng([seed, 7])
        from synth import apply_transform

        path, T = self.world.needle_path, self.world.needle_to_world(np.eye(4))
        u = T[:3, :3] @ path.tangent_at(0.0)
        u /= np.linalg.norm(u)
        back = np.arange(float(im.shaft_behind_entry_mm), 0.0, -self.step_mm)
        self._behind_pts = apply_transform(T, path.point_at(0.0)[None])[0] - back[:, None] * u
        self._behind_tan = np.repeat(u[None], len(back), 0)
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
            # the same transform as :meth:`image` (the scanner keys its fields by it)
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
        pts = apply_transform(inv, np.concatenate([self._behind_pts, pts]))
        tan = np.concatenate([self._behind_tan, tan])
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


def slice_half_width_mm(depth_mm, params=None) -> np.ndarray:
    """Half the -6 dB elevation width (mm) of the scanner's pulse-echo PSF at ``depth_mm``
    (below the probe's face): the half-thickness of the imaged slice. ``params``: the
    scanner's ``ImagingParams`` (default: the servo scenario's)."""
    if params is None:
        params = _servo_imaging_params()
    d = np.asarray(depth_mm, float)
    if not np.all(np.isfinite(d)):
        raise ValueError("slice_half_width_mm: depths must be finite")
    return 0.5 * _FWHM * params.sigma_elevation_mm(np.abs(d))


def in_slice(tip: np.ndarray, probe: np.ndarray, params=None) -> np.ndarray:
    """(n,) bool: the tip (n, 3) world mm lies inside the slice imaged from ``probe`` (n, 3):
    |p_x - p_ux| <= :func:`slice_half_width_mm` at the tip's depth p_z - p_uz."""
    tip, probe = np.asarray(tip, float), np.asarray(probe, float)
    half = slice_half_width_mm(tip[:, 2] - probe[:, 2], params)
    return np.abs(tip[:, 0] - probe[:, 0]) <= half


_FWHM = 2.0 * np.sqrt(2.0 * np.log(2.0))


def _servo_imaging_params():
    from synth import scenario_params

    return scenario_params("servo").imaging()


class CrossSectionDetector:
    """The needle's cross-section in an axial image from a feature source's shaft map (see
    the module docstring). ``detect(image, grid)`` -> (found, (x, z) mm, score).

    Localisation: the detection step of Carriere's axial tracker on the shaft map (the
    variance image of Carriere eq. (1) for classical features, the axial ONNX model's shaft
    probability for learned ones): the map smoothed at the needle's radius, its maximum
    accepted when its robust score (max - median) / MAD reaches ``detect_score`` (and for
    learned maps a probability of at least ``min_peak``), refined to sub-pixel; for
    classical maps moved one radius below the echo's upper edge (the tracker's
    ``detect_anchor``), for learned maps of the wall (``target_reference == "wall"``) one
    radius deeper. Acceptance: the echo's grey level there (:meth:`echo_level`) must reach
    ``echo_threshold`` at the detection's depth (None: no such test, any needle-like echo
    counts). After each call ``last`` holds the score, the level and the peak's (row, col).
    """

    def __init__(self, source, radius_mm: float = 0.635, detect_score: float | None = None,
                 min_peak: float | None = None, echo_threshold: float | None = None):
        from ..trackers import AxialParams

        if not np.isfinite(radius_mm) or radius_mm <= 0:
            raise ValueError(f"radius_mm must be positive, got {radius_mm}")
        self.source = source
        self.learned = getattr(source, "kind", "classical") == "learned"
        ap = AxialParams()
        self.radius_mm = float(radius_mm)
        self.detect_score = ap.detect_score if detect_score is None else float(detect_score)
        self.min_peak = (0.3 if self.learned else 0.0) if min_peak is None else float(min_peak)
        self.echo_threshold = echo_threshold
        self.score_floor = ap.score_floor
        self.name = getattr(source, "name", type(source).__name__)
        self.last: dict = {}

    @property
    def echo_threshold(self):
        """The acceptance level: None, a grey level, or an :class:`EchoThreshold` (a level
        that depends on depth)."""
        return self._echo_threshold

    @echo_threshold.setter
    def echo_threshold(self, value) -> None:
        if value is not None and not isinstance(value, EchoThreshold):
            if not np.isfinite(value):
                raise ValueError(f"echo_threshold must be finite, an EchoThreshold or None, "
                                 f"got {value}")
            value = float(value)
        self._echo_threshold = value

    @property
    def target_reference(self) -> str:
        """Where the map marks the needle: "centerline", or "wall" (the wall facing the
        probe) for a learned model that says so in its metadata."""
        if not self.learned:
            return "centerline"
        ref = getattr(self.source, "target_reference", "centerline")
        if ref not in ("centerline", "wall"):
            raise ValueError(f"{self.name}: target_reference must be 'centerline' or 'wall', "
                             f"got {ref!r}")
        return ref

    def echo_level(self, image: np.ndarray, rc, spacing_mm) -> float:
        """The echo's grey level: the maximum of the image, smoothed at half a needle radius,
        within two radii of ``rc`` (row, col)."""
        img = np.asarray(image)
        sp = np.asarray(spacing_mm, float)
        half = np.maximum(np.ceil(2.0 * self.radius_mm / sp).astype(int), 1)
        sig = np.maximum(0.5 * self.radius_mm / sp, 0.5)
        pad = np.ceil(3.0 * sig).astype(int)
        r, c = int(round(float(rc[0]))), int(round(float(rc[1])))
        lo = np.maximum(np.array([r, c]) - half - pad, 0)
        hi = np.minimum(np.array([r, c]) + half + pad + 1, img.shape[:2])
        crop = np.ascontiguousarray(img[lo[0]:hi[0], lo[1]:hi[1]], np.float32)
        sm = cv2.GaussianBlur(crop, (0, 0), sigmaX=float(sig[1]), sigmaY=float(sig[0]),
                              borderType=cv2.BORDER_REFLECT)
        w0 = np.maximum(np.array([r, c]) - half, 0) - lo
        w1 = np.minimum(np.array([r, c]) + half + 1, img.shape[:2]) - lo
        return float(sm[w0[0]:w1[0], w0[1]:w1[1]].max())

    def threshold_at(self, depth_mm: float) -> float | None:
        """The acceptance level at a depth (mm below the probe); None when uncalibrated."""
        t = self.echo_threshold
        if t is None:
            return None
        if isinstance(t, EchoThreshold):
            return t(depth_mm)
        return float(t)

    def _peak(self, image: np.ndarray, grid):
        """(score, peak value, (row, col), F, S) of the smoothed shaft map, or None when the
        frame cannot be measured (e.g. constant)."""
        from ..features import Frame, FrameError, check_frame

        frame = Frame(image, grid)
        try:
            check_frame(frame)
        except FrameError:
            return None
        F = np.ascontiguousarray(self.source.likelihood(frame).shaft, np.float32)
        sp = float(np.mean(grid.spacing_mm))
        S = cv2.GaussianBlur(F, (0, 0), self.radius_mm / sp)
        sub = S[::3, ::3]
        med = float(np.median(sub))
        mad = max(1.4826 * float(np.median(np.abs(sub - med))), self.score_floor)
        idx = np.unravel_index(int(np.argmax(S)), S.shape)
        return (float(S[idx]) - med) / mad, float(S[idx]), idx, F, S

    def detect(self, image: np.ndarray, grid) -> tuple[bool, np.ndarray | None, float]:
        from ..trackers import below_top_edge, local_peak, subpixel_peak

        self.last = {"score": 0.0, "level": float("nan"), "peak_rc": None,
                     "shaft_seen": False}
        pk = self._peak(image, grid)
        if pk is None:  # nothing can be measured (e.g. a constant frame): not detected
            return False, None, 0.0
        score, peak, idx, F, S = pk
        self.last.update(score=score, peak_rc=idx)
        if score < self.detect_score or peak < self.min_peak:
            return False, None, score
        level = self.echo_level(image, idx, grid.spacing_mm)
        self.last["level"] = level
        if self.echo_threshold is not None:
            depth = float(grid.index_to_points(np.asarray(idx, float))[1])
            if level < self.threshold_at(depth):
                # the shaft without the tip's echo: ahead of the tip, or far behind it
                self.last["shaft_seen"] = True
                return False, None, score
        rc = np.asarray(idx, float) + subpixel_peak(S, idx)
        radius_rows = self.radius_mm / float(grid.spacing_mm[0])
        if not self.learned:  # Carriere's tracker: one radius below the echo's upper edge
            rc = below_top_edge(F, rc, float(F.mean()), radius_rows)
        else:
            # the map's own mode within a radius of the smoothed map's peak
            rc = local_peak(F, idx, np.ceil(self.radius_mm / np.asarray(grid.spacing_mm)))
            if self.target_reference == "wall":
                # the map marks the wall facing the probe: the centre lies a radius deeper
                # (+z; the needle crosses the slice nearly at right angles)
                rc = rc + np.array([radius_rows, 0.0])
        return True, grid.index_to_points(rc), score


def make_detector(features: str, model=None, radius_mm: float = 0.635, threads: int = 1,
                  echo_threshold: float | None = None):
    """A :class:`CrossSectionDetector` with ``features`` "learned" (the shipped axial ONNX
    model, or ``model``) or "classical" (Carriere's variance image); uncalibrated unless
    ``echo_threshold`` is given (see :func:`calibrate_detector`)."""
    if features == "learned":
        from ..features import learned_features

        return CrossSectionDetector(learned_features("axial", model, threads=threads),
                                    radius_mm, echo_threshold=echo_threshold)
    if features == "classical":
        from ..features import VarianceFeatures

        return CrossSectionDetector(VarianceFeatures(), radius_mm,
                                    echo_threshold=echo_threshold)
    raise ValueError(f"features must be 'learned' or 'classical' for images, got {features!r}")


def image_measurement(world: ServoWorld, detector: CrossSectionDetector):
    """The ``measure`` callback of :func:`run_ye` for frames imaged from the probe's pose."""
    grid = world.grid
    previous: list = [None]

    def measure(k: int, probe_xyz: np.ndarray) -> Measurement:
        t0 = time.perf_counter()
        img = world.image(k, probe_xyz)
        t1 = time.perf_counter()
        if previous[0] is not None and np.array_equal(img, previous[0]):
            # a live scanner's frames differ (speckle, noise): this one is the feed repeating
            return Measurement(False, None, t1 - t0, stale=True)
        previous[0] = img
        found, xz, _ = detector.detect(img, grid)
        if not found:
            # a needle echo rejected only by the level test: the shaft, ahead or far behind
            return Measurement(False, None, t1 - t0, shaft_seen=detector.last["shaft_seen"])
        # section 4.2: z_x "taken directly from the position of the ultrasound probe";
        # z_y, z_z: the detection, probe frame -> world
        z = np.array([probe_xyz[0], probe_xyz[1] + xz[0], probe_xyz[2] + xz[1]])
        return Measurement(True, z, t1 - t0)

    return measure


@dataclass(frozen=True)
class EchoThreshold:
    """An acceptance level that depends on depth: grey ``levels`` at ``depths_mm`` (below the
    probe, increasing), linearly interpolated and held constant beyond the ends."""

    depths_mm: tuple
    levels: tuple

    def __call__(self, depth_mm: float) -> float:
        return float(np.interp(depth_mm, self.depths_mm, self.levels))


@dataclass(frozen=True)
class DetectorCalibration:
    """The result of :func:`calibrate_detector`: ``echo_threshold`` (an
    :class:`EchoThreshold`), the ``target_mm`` it was set for (plane position relative to the tip,
    negative = behind), ``reach_mm`` (where the calibrated detection rate on the calibration
    worlds falls below one half, linear interpolation), the calibration ``seeds`` and
    ``per_arc`` rows (seed, arc mm, tip depth mm, echo level at the target)."""

    echo_threshold: EchoThreshold
    target_mm: float
    reach_mm: float
    seeds: tuple
    per_arc: tuple


def _sweep(detector: CrossSectionDetector, imaging: ServoImaging, seed: int, arc_mm,
           offsets: np.ndarray, gate_mm: float = 2.0):
    """Echo level (-inf: not found near the tip) of the detector with the plane at
    ``offsets`` (mm, + ahead) from the tip at each arc length; (len(arc), len(offsets)) and
    the tips' depths below the probe."""
    w = ServoWorld(seed, 2000, imaging)
    out = np.full((len(arc_mm), len(offsets)), -np.inf)
    depth = np.zeros(len(arc_mm))
    thr, detector.echo_threshold = detector.echo_threshold, None
    try:
        for a, s_tip in enumerate(arc_mm):
            k = min(int(np.searchsorted(w.s, s_tip)), len(w.s) - 1)
            tip = w.tip[k]
            depth[a] = tip[2] - w.probe_z
            w.prepare(np.array([tip[0] + offsets.min(), tip[0] + offsets.max()]))
            for i, di in enumerate(offsets):
                probe = np.array([tip[0] + di, tip[1], w.probe_z])
                found, xz, _ = detector.detect(w.image(k, probe), w.grid)
                if found and np.hypot(probe[1] + xz[0] - tip[1],
                                      probe[2] + xz[1] - tip[2]) < gate_mm:
                    out[a, i] = detector.last["level"]
    finally:
        detector.echo_threshold = thr
    return out, depth


def _fall_point(offsets: np.ndarray, rate: np.ndarray) -> float:
    """The offset where ``rate`` first falls below one half after its maximum (linear
    interpolation); the last offset if it never does."""
    below = np.flatnonzero((rate < 0.5) & (offsets > offsets[np.argmax(rate)]))
    if len(below) == 0:
        return float(offsets[-1])
    j = int(below[0])
    if j == 0:
        return float(offsets[0])
    f = (rate[j - 1] - 0.5) / max(rate[j - 1] - rate[j], 1e-9)
    return float(offsets[j - 1] + f * (offsets[j] - offsets[j - 1]))


_CAL_CACHE: dict = {}


def _source_key(detector: CrossSectionDetector) -> tuple:
    return (detector.name, str(getattr(detector.source, "path", None)),
            detector.target_reference, detector.radius_mm, detector.detect_score,
            detector.min_peak)


def calibrate_detector(detector: CrossSectionDetector, imaging: ServoImaging | None = None,
                       seeds=CALIBRATION_SEEDS,
                       arc_mm=(5.0, 20.0, 35.0, 50.0, 75.0, 105.0, 135.0, 165.0, 190.0),
                       target_mm: float = 0.0,
                       offsets_mm=None) -> DetectorCalibration:
    """Set ``detector.echo_threshold`` so that the needle counts as detected while the plane
    is behind the tip (see the module docstring) and return the :class:`DetectorCalibration`.

    The plane is swept across the tip of one calibration world per seed (keep the seeds
    disjoint from every run's) at arc lengths spanning the path's depths, at ``offsets_mm``
    from the tip (default -0.6 .. +0.4 mm in 0.1 mm steps; + is ahead); at each arc the echo
    level at ``target_mm`` is interpolated from the sweep, and the threshold at a depth is
    their median over seeds, interpolated linearly between the arcs' depths. ``target_mm`` 0:
    detection ends where the plane reaches the tip, Ye's boundary. (Measured in the loop,
    seed 0, 2000 frames: -0.1 kept the probe behind 95-99% of the frames but, after the
    flickers of detection near the boundary, K_e's slow recovery (1.01^t2) let it fall up to
    1 mm behind, out of the slice (in-plane 0.71-0.85); +0.1 raised in-plane to 0.85-0.92 with
    the probe behind only 63-93%; 0 is Ye's definition and lies between.) Cached per
    detector source and settings."""
    imaging = ServoImaging() if imaging is None else imaging
    d = (np.round(np.arange(-0.6, 0.401, 0.1), 6) if offsets_mm is None
         else np.asarray(offsets_mm, float))
    if d.ndim != 1 or len(d) < 3 or np.any(np.diff(d) <= 0):
        raise ValueError("offsets_mm must be at least 3 increasing offsets")
    if not d.min() < target_mm < d.max():
        raise ValueError(f"target_mm {target_mm} must lie inside the offsets "
                         f"[{d.min()}, {d.max()}]")
    seeds = tuple(int(s) for s in seeds)
    if not seeds:
        raise ValueError("calibrate_detector needs at least one seed")
    key = (_source_key(detector), imaging, seeds, tuple(arc_mm), float(target_mm),
           tuple(d.tolist()))
    if key not in _CAL_CACHE:
        rows, curves, depth_all = [], [], []
        for seed in seeds:
            c, depth = _sweep(detector, imaging, seed, arc_mm, d)
            curves.append(c)
            depth_all.append(depth)
            for a, s_tip in enumerate(arc_mm):
                ok = np.isfinite(c[a])
                if ok.sum() >= 2 and d[ok].min() <= target_mm <= d[ok].max():
                    v = float(np.interp(target_mm, d[ok], c[a, ok]))
                    rows.append((seed, float(s_tip), float(depth[a]), v))
        if not rows:
            raise RuntimeError(f"calibrate_detector: the {detector.name} detector never found "
                               f"the needle near the tip on the calibration worlds {seeds}")
        # per arc (one depth): the median over seeds; interpolated in depth
        per = np.array([r[2:] for r in rows])
        zs = np.unique(per[:, 0].round(6))
        lv = [float(np.median(per[np.isclose(per[:, 0], z, atol=1e-6), 1])) for z in zs]
        thr = EchoThreshold(tuple(float(z) for z in zs), tuple(lv))
        # the calibrated detection rate on the same sweeps: where it falls below 1/2
        lim = np.array([thr(z) for z in np.concatenate(depth_all)])
        rate = np.mean(np.concatenate(curves) >= lim[:, None], axis=0)
        _CAL_CACHE[key] = DetectorCalibration(thr, float(target_mm), _fall_point(d, rate),
                                              seeds, tuple(rows))
    cal = _CAL_CACHE[key]
    detector.echo_threshold = cal.echo_threshold
    return cal


_REACH_CACHE: dict = {}


def calibrate_reach(detector: CrossSectionDetector, imaging: ServoImaging | None = None,
                    seed: int = 1_000_005, arc_mm=(30.0, 60.0, 90.0, 120.0, 150.0),
                    offsets_mm=None) -> float:
    """How far ahead of the tip (mm; negative: behind) the detector, as it is set now, still
    finds the needle: the plane is swept across the tip of a world (``seed``; keep it apart
    from the calibration's and the runs' seeds to check a calibration on unseen tissue) at a
    few arc lengths; a detection counts when it lies within 2 mm of the tip; reach = the
    offset where the detection rate first falls below one half (linear interpolation). Cached
    per detector, threshold and imaging."""
    imaging = ServoImaging() if imaging is None else imaging
    d = (np.round(np.arange(-1.0, 3.001, 0.1), 6) if offsets_mm is None
         else np.asarray(offsets_mm, float))
    key = (_source_key(detector), detector.echo_threshold, imaging, int(seed), tuple(arc_mm),
           tuple(d.tolist()))
    if key not in _REACH_CACHE:
        c, depth = _sweep(detector, imaging, int(seed), arc_mm, d)
        lim = np.array([-np.inf if detector.echo_threshold is None
                        else detector.threshold_at(z) for z in depth])
        _REACH_CACHE[key] = _fall_point(d, np.mean(c >= lim[:, None], axis=0))
    return _REACH_CACHE[key]


def servo_world(seed: int, n_samples: int, imaging: ServoImaging | None = None,
                config: YeServoConfig | None = None) -> ServoWorld:
    """A prepared :class:`ServoWorld` for ``n_samples`` frames of Ye's profile."""
    cfg = YeServoConfig() if config is None else config
    w = ServoWorld(seed, n_samples, imaging, cfg.frame_rate_hz)
    w.prepare()
    return w
