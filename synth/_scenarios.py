"""Seeded scenarios reproducing the protocols of the five papers.

Each scenario is a frozen dataclass of parameters with the paper's defaults, a ``draw``
method that makes every random choice of the scenario in one place from one seed (so a seed
reproduces a sequence exactly), and a ``build`` method that turns the draw into a scanner and
a trajectory. :func:`generate` runs it and returns a labelled :class:`Sequence`.

| name            | paper           | modality | what moves                                      |
|-----------------|-----------------|----------|-------------------------------------------------|
| ``inplane``       | Mathiassen 2017 | inplane  | needle inserted in the plane of a static probe  |
| ``volume``        | Zhao 2013       | volume   | needle inserted in a static sector volume       |
| ``volume-motion`` | Chatelain 2013  | volume   | insertion, withdrawal, re-insertion; phantom    |
| ``axial``         | Carriere 2016   | axial    | curved needle; probe stepped 0.5 mm per frame   |
| ``servo``         | Ye 2025         | axial    | Ye's tip path; probe plane following the tip    |
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field, fields

import numpy as np

from ._geometry import rigid_transform, rotation_matrix
from ._probe import PlaneProbe, SectorProbe
from ._render import Trajectory, render_sequence
from ._scanner import ImagingParams, Scanner
from ._sequence import Sequence
from ._world import NeedlePath, NeedleSpec, ScatteringMap, Tissue, World, needle_radius_mm

__all__ = ["SCENARIOS", "generate", "scenario_params", "random_scattering_map", "describe"]

BACKGROUNDS = ("homogeneous", "inhomogeneous")


def random_scattering_map(rng: np.random.Generator, lo, hi, background: str,
                          plane_bias: bool = True, distractors: bool = True) -> ScatteringMap:
    """An inhomogeneous scattering map over the box lo-hi (tissue frame), or a homogeneous one.

    Smooth log-normal inhomogeneity, interfaces between layers, line-like structures, anechoic
    cysts and bright needle-like distractors; Zhao 2013 used a breast scattering map that
    "contains complicated patterns such as line-like structures".
    """
    if background not in BACKGROUNDS:
        raise ValueError(f"background must be one of {BACKGROUNDS}, got {background!r}")
    if background == "homogeneous":
        return ScatteringMap()
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    size = hi - lo
    K = 16
    dirs = rng.normal(size=(K, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    wavelengths = rng.uniform(6.0, 30.0, K)
    wave_vectors = dirs * (2 * np.pi / wavelengths)[:, None]

    def point(n):
        return lo + rng.random((n, 3)) * size

    n_int = int(rng.integers(1, 4))
    normals = np.tile([0.0, 0.0, 1.0], (n_int, 1)) + rng.normal(0, 0.25, (n_int, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    offsets = np.einsum("nd,nd->n", normals, point(n_int))
    n_line = int(rng.integers(2, 6))
    n_dist = int(rng.integers(1, 3))
    a = point(n_line + n_dist)
    d = rng.normal(size=(n_line + n_dist, 3))
    if plane_bias:
        d[:, 1] *= 0.15  # mostly across the image plane, so they show as lines
        a[:, 1] = rng.normal(0.0, 0.5, n_line + n_dist)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    length = np.concatenate([rng.uniform(10, 40, n_line), rng.uniform(10, 30, n_dist)])
    b = a + d * length[:, None]
    radius = np.concatenate([rng.uniform(0.2, 0.6, n_line), rng.uniform(0.25, 0.45, n_dist)])
    gain = np.concatenate([rng.uniform(1.8, 3.5, n_line), rng.uniform(5.0, 9.0, n_dist)])
    if not distractors:  # the same draws (a seed gives the same tissue), without the needle-like
        gain[n_line:] = 1.0  # bright lines
    n_cyst = int(rng.integers(0, 3))
    return ScatteringMap(
        smooth_sigma=float(rng.uniform(0.2, 0.45)), wave_vectors=wave_vectors,
        wave_phases=rng.uniform(0, 2 * np.pi, K),
        interface_normals=normals, interface_offsets=offsets,
        interface_factors=rng.uniform(0.5, 1.8, n_int),
        interface_brightness=rng.uniform(0.3, 1.5, n_int),
        line_a=a, line_b=b, line_radius=radius, line_gain=gain,
        cyst_centers=point(n_cyst), cyst_radii=rng.uniform(1.5, 4.5, n_cyst),
    )


def _check_positive(name: str, v) -> None:
    if v is not None and (not np.isfinite(v) or v <= 0):
        raise ValueError(f"{name} must be positive, got {v}")


MAX_FRAME_PIXELS = 1 << 24  # 4096 x 4096: beyond any scanner's frame


def _check_frame_size(p) -> None:
    """A 2D scenario's frame (width and depth over the pixel spacing) must stay within
    :data:`MAX_FRAME_PIXELS`: a 1e-6 mm spacing asks for 10^15 pixels."""
    sp, w, d = (getattr(p, k, None) for k in ("spacing_mm", "width_mm", "depth_mm"))
    if not all(isinstance(v, (int, float)) for v in (sp, w, d)):
        return
    pixels = (w / sp) * (d / sp)
    if pixels > MAX_FRAME_PIXELS:
        raise ValueError(f"spacing_mm={sp:g} over {w:g} x {d:g} mm makes frames of {pixels:.3g} "
                         f"pixels (at most {MAX_FRAME_PIXELS}); use a coarser spacing_mm")


def _check_cr(cr) -> None:
    if cr is not None and (not np.isfinite(cr) or not 1.05 <= cr <= 10.0):
        raise ValueError(f"cr (contrast ratio, Zhao eq. 9) must be in [1.05, 10], got {cr}")


@dataclass(frozen=True)
class _Base:
    """Parameters shared by every scenario."""

    frames: int | None = None
    background: str = "inhomogeneous"
    cr: float | None = None
    gauge: int = 18
    needle_echo: float = 60.0
    noise_db: float = -45.0
    dynamic_range_db: float = 70.0
    scatterers_per_cell: float = 40.0
    # any ImagingParams / NeedleSpec field, e.g. {"center_frequency_mhz": 7.5}: training
    # randomises the imaging through these
    imaging_overrides: dict = field(default_factory=dict)
    needle_overrides: dict = field(default_factory=dict)
    distractors: bool = True  # bright needle-like lines in an inhomogeneous background

    modality = "inplane"
    paper = ""

    def validate(self) -> None:
        if self.frames is not None and (int(self.frames) != self.frames or self.frames < 1):
            raise ValueError(f"frames must be a positive integer, got {self.frames}")
        if self.background not in BACKGROUNDS:
            raise ValueError(f"background must be one of {BACKGROUNDS}, got {self.background!r}")
        _check_cr(self.cr)
        needle_radius_mm(self.gauge)
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name.endswith(("_mm_s", "_hz", "spacing_mm", "width_mm", "depth_mm")) and \
                    isinstance(v, (int, float)):
                _check_positive(f.name, v)
        _check_positive("scatterers_per_cell", self.scatterers_per_cell)
        _check_positive("dynamic_range_db", self.dynamic_range_db)
        _check_frame_size(self)
        a, b = getattr(self, "start_length_mm", None), getattr(self, "stop_length_mm", None)
        if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not (
                np.isfinite(a) and np.isfinite(b) and 0.0 <= a < b):
            raise ValueError(f"need 0 <= start_length_mm < stop_length_mm (finite), got "
                             f"{a} and {b}")

    def imaging(self) -> ImagingParams:
        return self._with_overrides(ImagingParams(
            noise_db=self.noise_db, dynamic_range_db=self.dynamic_range_db,
            scatterers_per_cell=self.scatterers_per_cell))

    def _with_overrides(self, params: ImagingParams) -> ImagingParams:
        try:
            return dataclasses.replace(params, **self.imaging_overrides)
        except TypeError as exc:
            raise ValueError(f"imaging_overrides: {exc}") from None

    def needle_spec(self, rng) -> NeedleSpec:
        try:
            return dataclasses.replace(NeedleSpec(gauge=self.gauge, echo=self.needle_echo),
                                       **self.needle_overrides)
        except TypeError as exc:
            raise ValueError(f"needle_overrides: {exc}") from None


def _n_frames(p, default: int) -> int:
    return int(p.frames) if p.frames is not None else default


def _const_pose(T: int, pose=None) -> np.ndarray:
    return np.repeat((np.eye(4) if pose is None else pose)[None], T, axis=0)


def _breathing(T, dt, amp_mm, rng) -> np.ndarray:
    """Rigid tissue motion: breathing-like sinusoids (period 3-5 s) along a random direction."""
    poses = _const_pose(T)
    if amp_mm <= 0:
        return poses
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    period = rng.uniform(3.0, 5.0)
    ph = rng.uniform(0, 2 * np.pi)
    t = np.arange(T) * dt
    poses[:, :3, 3] = amp_mm * np.sin(2 * np.pi * t / period + ph)[:, None] * d
    return poses


SIDES = ("right", "left")
ENTRY_EDGES = ("top", "side")


def _with_structures(smap: ScatteringMap, **extra) -> ScatteringMap:
    """``smap`` with structures appended: each keyword names a ScatteringMap array field and
    gives the rows to add to it."""
    return dataclasses.replace(smap, **{
        k: np.concatenate([np.asarray(getattr(smap, k), float).reshape(
            (-1,) + np.shape(v)[1:]), np.asarray(v, float)]) for k, v in extra.items()})


@dataclass(frozen=True)
class InplaneScenario(_Base):
    """Mathiassen 2017: in-plane insertion, 35/45 degrees, 5/10/15 mm/s, 20 frames/s,
    0.1 mm/px, 5 cm depth, 14 G biopsy needle entering at the top right of the image.

    Beyond the protocol (for training and robustness tests): the needle from the left, or
    through the lateral border at a depth instead of the top edge; a bright interface
    parallel to the needle; vessels (anechoic tubes); acoustic shadows under occluders; and
    worlds with no needle at all."""

    angle_deg: float | None = None  # None: drawn from (35, 45)
    speed_mm_s: float | None = None  # None: drawn from (5, 10, 15)
    frame_rate_hz: float = 20.0
    spacing_mm: float = 0.1
    depth_mm: float = 50.0
    width_mm: float = 38.4
    gauge: int = 14
    start_length_mm: float = 11.0  # Mathiassen Table I: mean start 11 mm, stop 42-46 mm
    stop_length_mm: float = 46.0
    out_of_plane_deg: float = 0.0
    elevation_offset_mm: float = 0.0
    tissue_motion_mm: float = 0.0
    side: str | None = "right"  # the needle enters from the "right" or "left"; None: drawn
    entry_edge: str | None = "top"  # through the "top" (skin) or the "side" border; None: drawn
    # lateral position of the entry beyond the image's edge on the needle's side (negative:
    # inside the image), drawn uniformly in this range
    entry_offset_range_mm: tuple[float, float] = (-1.0, 3.0)
    # depth of a side entry, drawn uniformly in this range (mm)
    entry_depth_range_mm: tuple[float, float] = (3.0, 25.0)
    # a bright interface (fascia, a tendon's or an organ's boundary) parallel to the needle at
    # this signed distance from its axis (mm, positive: deeper); None: none
    interface_offset_mm: float | None = None
    interface_brightness: float = 3.0  # amplitude gain at the boundary
    interface_factor: float = 1.0  # echogenicity beyond it (deeper side)
    vessels: int = 0  # anechoic tubes, radius 1-4 mm, drawn across or along the image plane
    shadows: int = 0  # occluders (a bright segment) casting an acoustic shadow to the bottom
    needle_free: bool = False  # a world with no needle: every frame without one

    modality = "inplane"
    paper = "Mathiassen 2017"

    def validate(self) -> None:
        super().validate()
        if self.side is not None and self.side not in SIDES:
            raise ValueError(f"side must be one of {SIDES} or None, got {self.side!r}")
        if self.entry_edge is not None and self.entry_edge not in ENTRY_EDGES:
            raise ValueError(f"entry_edge must be one of {ENTRY_EDGES} or None, got "
                             f"{self.entry_edge!r}")
        for name in ("entry_offset_range_mm", "entry_depth_range_mm"):
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ValueError(f"{name} must be (low, high) with low <= high, got "
                                 f"{getattr(self, name)}")
        if self.angle_deg is not None and not 0.0 < self.angle_deg < 90.0:
            raise ValueError(f"angle_deg must be in (0, 90), got {self.angle_deg}")
        if self.vessels < 0 or self.shadows < 0:
            raise ValueError("vessels and shadows must be counts >= 0")

    def draw(self, rng: np.random.Generator) -> dict:
        d = {
            "angle_deg": float(self.angle_deg if self.angle_deg is not None
                               else rng.choice([35.0, 45.0])),
            "speed_mm_s": float(self.speed_mm_s if self.speed_mm_s is not None
                                else rng.choice([5.0, 10.0, 15.0])),
            "entry_offset_mm": float(rng.uniform(*self.entry_offset_range_mm)),
            "tissue_seed": int(rng.integers(2**31)),
            "map_rng": int(rng.integers(2**31)),
            "motion_rng": int(rng.integers(2**31)),
        }
        # the draws beyond Mathiassen's protocol come after hers, so her seeds are unchanged
        d["side"] = self.side if self.side is not None else str(rng.choice(SIDES))
        d["entry_edge"] = (self.entry_edge if self.entry_edge is not None
                           else str(rng.choice(ENTRY_EDGES)))
        if d["entry_edge"] == "side":
            lo, hi = self.entry_depth_range_mm
            d["entry_depth_mm"] = float(rng.uniform(lo, min(hi, 0.8 * self.depth_mm)))
        w, z = self.width_mm, self.depth_mm
        d["vessels"] = []
        for _ in range(int(self.vessels)):
            r = float(rng.uniform(1.0, 4.0))
            c = [float(rng.uniform(-0.45 * w, 0.45 * w)), 0.0, float(rng.uniform(r + 2, z))]
            if rng.random() < 0.6:  # across the plane: a circle
                u = [float(rng.normal(0, 0.2)), 1.0, float(rng.normal(0, 0.2))]
            else:  # along it: a dark band
                a = rng.uniform(-0.3, 0.3)
                u = [float(np.cos(a)), float(rng.normal(0, 0.05)), float(np.sin(a))]
            d["vessels"].append({"center": c, "direction": u, "radius_mm": r,
                                 "factor": float(rng.uniform(0.0, 0.08)),
                                 "wall": float(rng.uniform(0.3, 2.0))})
        d["shadows"] = []
        for _ in range(int(self.shadows)):
            x0 = float(rng.uniform(-0.5 * w, 0.4 * w))
            z0 = float(rng.uniform(2.0, 0.6 * z))
            length = float(rng.uniform(1.5, 8.0))
            tilt = float(rng.uniform(-0.3, 0.3))
            d["shadows"].append({"a": [x0, 0.0, z0], "b": [x0 + length, 0.0, z0 + tilt * length],
                                 "factor": float(rng.uniform(0.05, 0.5)),
                                 "brightness": float(rng.uniform(1.5, 6.0))})
        return d

    def build(self, d: dict):
        p = self
        if p.stop_length_mm <= p.start_length_mm:
            raise ValueError("stop_length_mm must exceed start_length_mm")
        probe = PlaneProbe(width_mm=p.width_mm, depth_mm=p.depth_mm, spacing_mm=p.spacing_mm)
        imaging = p.imaging()
        dens = imaging.scatterer_density(probe.range_of_rows())
        lo, hi = [-p.width_mm / 2, -4, 0], [p.width_mm / 2, 4, p.depth_mm]
        smap = random_scattering_map(np.random.default_rng(d["map_rng"]), lo, hi, p.background,
                                     distractors=p.distractors)
        th = np.deg2rad(d["angle_deg"])
        oop = np.deg2rad(p.out_of_plane_deg)
        # right: enters right of the image and goes down-left; left: the mirror image
        sx = 1.0 if d.get("side", "right") == "right" else -1.0
        direction = np.array([-sx * np.cos(th) * np.cos(oop), np.sin(oop),
                              np.sin(th) * np.cos(oop)])
        # through the skin (z = 0), or through the lateral border at a depth
        z_entry = d["entry_depth_mm"] if d.get("entry_edge", "top") == "side" else 0.0
        entry = np.array([sx * (p.width_mm / 2 + d["entry_offset_mm"]), p.elevation_offset_mm,
                          z_entry])
        path = NeedlePath(entry=entry, direction=direction)
        smap = self._structures(smap, d, entry, direction)
        world = World(Tissue(dens, d["tissue_seed"], smap), path, p.needle_spec(None))
        dt = 1.0 / p.frame_rate_hz
        default_T = int(np.ceil((p.stop_length_mm - p.start_length_mm) / d["speed_mm_s"]
                                * p.frame_rate_hz)) + 1
        T = _n_frames(p, default_T)
        t = np.arange(T) * dt
        ins = np.minimum(p.start_length_mm + d["speed_mm_s"] * t, path.max_length_mm)
        if p.needle_free:
            ins = np.zeros(T)  # the needle never enters: no echo, no labelled shaft
        tissue = _breathing(T, dt, p.tissue_motion_mm, np.random.default_rng(d["motion_rng"]))
        traj = Trajectory(t, ins, _const_pose(T), tissue)
        return Scanner(probe, imaging, world), traj

    def _structures(self, smap: ScatteringMap, d: dict, entry, direction) -> ScatteringMap:
        """The drawn interface, vessels and shadows added to the scattering map (tissue
        frame = probe frame at the start: x lateral, y elevation, z depth)."""
        p = self
        extra: dict = {}
        if p.interface_offset_mm is not None:
            # the plane holding the needle's in-plane direction and the elevation axis,
            # moved along its normal (pointing deeper) by the offset
            u = np.array([direction[0], 0.0, direction[2]])
            u /= np.linalg.norm(u)
            n = np.array([-u[2], 0.0, u[0]])
            n = n if n[2] >= 0 else -n
            extra.update(interface_normals=[n],
                         interface_offsets=[float(n @ entry) + p.interface_offset_mm],
                         interface_factors=[p.interface_factor],
                         interface_brightness=[p.interface_brightness])
        vs = d.get("vessels", [])
        if vs:
            half = 3.0 * max(p.width_mm, p.depth_mm)
            c = np.array([v["center"] for v in vs])
            u = np.array([v["direction"] for v in vs])
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            extra.update(tube_a=c - half * u, tube_b=c + half * u,
                         tube_radius=[v["radius_mm"] for v in vs],
                         tube_factor=[v["factor"] for v in vs],
                         tube_wall=[v["wall"] for v in vs])
        sh = d.get("shadows", [])
        if sh:
            a = np.array([v["a"] for v in sh])
            b = np.array([v["b"] for v in sh])
            extra.update(cast_a=a, cast_b=b, cast_factor=[v["factor"] for v in sh],
                         cast_half_width=[4.0] * len(sh),
                         line_a=a, line_b=b, line_radius=[0.35] * len(sh),
                         line_gain=[v["brightness"] for v in sh])
        return _with_structures(smap, **extra) if extra else smap


def _inside_sector(probe: SectorProbe, pts: np.ndarray, margin_px: float = 2.0) -> np.ndarray:
    idx = probe.to_beam_index(np.atleast_2d(pts))
    shape = np.asarray(probe.beam_grid.shape)
    return np.all((idx >= margin_px) & (idx <= shape - 1 - margin_px), axis=1)


def _sector_entry(probe: SectorProbe, u: np.ndarray, length_mm: float,
                  jitter_mm: np.ndarray) -> np.ndarray:
    """Where a needle along ``u`` enters the imaged sector so that ``length_mm`` of it fits.

    The entry lies on the sector's boundary (the needle comes in through a face of the volume,
    as in Zhao 2013's and Chatelain 2013's volumes); the deepest centre depth that holds the
    whole needle is chosen.
    """
    s = np.linspace(0.0, 80.0, 801)
    best = None
    for depth in np.linspace(0.75, 0.35, 9) * probe.r_max:
        c = np.array([0.0, 0.0, depth]) + jitter_mm
        back = c[None] - s[:, None] * u[None]
        inside = _inside_sector(probe, back)
        if not inside[0]:
            continue
        k = np.argmin(inside) if not inside.all() else len(s) - 1
        entry = back[max(k - 1, 0)]
        tip = entry + length_mm * u
        if _inside_sector(probe, tip[None])[0]:
            return entry
        if best is None:
            best = entry
    if best is not None:
        return best
    return np.array([0.0, 0.0, 0.5 * probe.r_max]) - 0.5 * length_mm * u


@dataclass(frozen=True)
class VolumeScenario(_Base):
    """Zhao 2013: alpha 0/30/60/90 degrees, beta 73 degrees, needle 6 to 25 mm long at
    1 mm/s, radius 0.5 mm, CR 4.7 (group 1) or 2.0-3.5 (group 2), needle voxels N(140, 28),
    55 x 64 x 160 sector volumes scan-converted to 128^3."""

    alpha_deg: float | None = None  # None: drawn from (0, 30, 60, 90)
    beta_deg: float = 73.0
    speed_mm_s: float = 1.0
    volume_rate_hz: float = 1.0
    start_length_mm: float = 6.0
    stop_length_mm: float = 25.0
    gauge: int = 19  # radius 0.53 mm: Zhao's 0.5 mm needle
    cr: float | None = 4.7
    zhao_mode: bool = True
    center_frequency_mhz: float = 3.5  # ~0.3 mm axial, ~0.7 mm lateral as Zhao's simulation
    scatterers_per_cell: float = 10.0
    output_size: int = 128
    tissue_motion_mm: float = 0.0
    # Zhao's background: CR 2.0-3.5 came from needle means of 70-115, i.e. a background mean
    # near 33 gray levels; over 70 dB its 99th percentile sits near Zhao's lowest threshold, 60.
    tissue_gray: float = 33.0
    dynamic_range_db: float = 70.0

    modality = "volume"
    paper = "Zhao 2013"

    def imaging(self) -> ImagingParams:
        return self._with_overrides(ImagingParams(
            center_frequency_mhz=self.center_frequency_mhz, f_number=1.2, tx_f_number=2.0,
            tx_focus_mm=30.0, elevation_f_number=2.2, elevation_focus_mm=30.0,
            noise_db=self.noise_db, dynamic_range_db=self.dynamic_range_db,
            scatterers_per_cell=self.scatterers_per_cell, tissue_gray=self.tissue_gray))

    def probe(self) -> SectorProbe:
        n = int(self.output_size)
        return SectorProbe(output_shape=(n, n, n))

    def draw(self, rng: np.random.Generator) -> dict:
        return {
            "alpha_deg": float(self.alpha_deg if self.alpha_deg is not None
                               else rng.choice([0.0, 30.0, 60.0, 90.0])),
            "centre_jitter_mm": rng.uniform(-2, 2, 3).tolist(),
            "tissue_seed": int(rng.integers(2**31)),
            "map_rng": int(rng.integers(2**31)),
            "motion_rng": int(rng.integers(2**31)),
        }

    def _direction(self, alpha_deg: float) -> np.ndarray:
        # Zhao eq. (4): alpha = arctan(u_y / u_x), beta = arccos(u_z / |u|)
        a, b = np.deg2rad(alpha_deg), np.deg2rad(self.beta_deg)
        return np.array([np.sin(b) * np.cos(a), np.sin(b) * np.sin(a), np.cos(b)])

    def build(self, d: dict):
        p = self
        if p.stop_length_mm <= p.start_length_mm:
            raise ValueError("stop_length_mm must exceed start_length_mm")
        probe = p.probe()
        imaging = p.imaging()
        g = probe.grid
        dens = imaging.scatterer_density(np.linspace(probe.start_depth_mm, probe.r_max, 50))
        lo = np.array(g.index_to_points(np.zeros(3)))
        hi = np.array(g.index_to_points(np.asarray(g.shape, float) - 1))
        smap = random_scattering_map(np.random.default_rng(d["map_rng"]), lo, hi, p.background,
                                     plane_bias=False, distractors=p.distractors)
        u = self._direction(d["alpha_deg"])
        entry = _sector_entry(probe, u, p.stop_length_mm, np.asarray(d["centre_jitter_mm"]))
        path = NeedlePath(entry=entry, direction=u)
        world = World(Tissue(dens, d["tissue_seed"], smap), path, p.needle_spec(None))
        dt = 1.0 / p.volume_rate_hz
        default_T = int(round((p.stop_length_mm - p.start_length_mm) / (p.speed_mm_s * dt))) + 1
        T = _n_frames(p, default_T)
        t = np.arange(T) * dt
        ins = np.minimum(p.start_length_mm + p.speed_mm_s * t, path.max_length_mm)
        tissue = _breathing(T, dt, p.tissue_motion_mm, np.random.default_rng(d["motion_rng"]))
        return Scanner(probe, imaging, world, zhao_mode=p.zhao_mode), Trajectory(
            t, ins, _const_pose(T), tissue)


@dataclass(frozen=True)
class VolumeMotionScenario(VolumeScenario):
    """Chatelain 2013: insertion from an arbitrary direction, withdrawal and re-insertion
    (Fig. 4), while the phantom moves (translations and rotations); physical needle echo."""

    max_misalignment_deg: float = 40.0  # angle between the needle and the probe's X axis
    speed_mm_s: float = 3.0
    volume_rate_hz: float = 5.0
    insert_mm: float = 25.0
    withdraw_mm: float = 10.0
    motion_mm: float = 4.0
    motion_deg: float = 5.0
    zhao_mode: bool = False
    cr: float | None = None
    gauge: int = 18
    output_size: int = 96

    paper = "Chatelain 2013"

    def draw(self, rng: np.random.Generator) -> dict:
        az = float(rng.uniform(-self.max_misalignment_deg, self.max_misalignment_deg))
        return {
            "azimuth_deg": az,
            "elevation_deg": float(rng.uniform(10, 25)),
            "side": float(rng.choice([-1.0, 1.0])),
            "centre_jitter_mm": rng.uniform(-2, 2, 3).tolist(),
            "tissue_seed": int(rng.integers(2**31)),
            "map_rng": int(rng.integers(2**31)),
            "motion_axis": rng.normal(size=3).tolist(),
            "motion_dir": rng.normal(size=3).tolist(),
            "motion_period_s": float(rng.uniform(4.0, 8.0)),
        }

    def build(self, d: dict):
        p = self
        probe = p.probe()
        imaging = p.imaging()
        g = probe.grid
        dens = imaging.scatterer_density(np.linspace(probe.start_depth_mm, probe.r_max, 50))
        lo = np.array(g.index_to_points(np.zeros(3))) - 10
        hi = np.array(g.index_to_points(np.asarray(g.shape, float) - 1)) + 10
        smap = random_scattering_map(np.random.default_rng(d["map_rng"]), lo, hi, p.background,
                                     plane_bias=False, distractors=p.distractors)
        az, el = np.deg2rad(d["azimuth_deg"]), np.deg2rad(d["elevation_deg"])
        u = np.array([d["side"] * np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        entry = _sector_entry(probe, u, p.insert_mm, np.asarray(d["centre_jitter_mm"]))
        centre = entry + 0.5 * p.insert_mm * u
        path = NeedlePath(entry=entry, direction=u)
        world = World(Tissue(dens, d["tissue_seed"], smap), path, p.needle_spec(None),
                      needle_in_tissue=True)
        dt = 1.0 / p.volume_rate_hz
        # insert, withdraw, re-insert (Chatelain Fig. 4)
        legs = [p.insert_mm, p.withdraw_mm, p.withdraw_mm]
        t_legs = np.cumsum([L / p.speed_mm_s for L in legs])
        default_T = int(np.ceil(t_legs[-1] / dt)) + 1
        T = _n_frames(p, default_T)
        t = np.arange(T) * dt
        ins = np.interp(t, np.concatenate([[0.0], t_legs]),
                        [0.0, p.insert_mm, p.insert_mm - p.withdraw_mm, p.insert_mm])
        axis = np.asarray(d["motion_axis"])
        mdir = np.asarray(d["motion_dir"])
        mdir /= np.linalg.norm(mdir)
        s = np.sin(2 * np.pi * t / d["motion_period_s"])
        tissue = np.zeros((T, 4, 4))
        for i in range(T):  # a handful of 4x4 poses, not a per-pixel loop
            R = rotation_matrix(axis, np.deg2rad(p.motion_deg) * s[i])
            tissue[i] = rigid_transform(R, p.motion_mm * s[i] * mdir + centre - R @ centre)
        return Scanner(probe, imaging, world, zhao_mode=p.zhao_mode), Trajectory(
            t, ins, _const_pose(T), tissue)


@dataclass(frozen=True)
class AxialScenario(_Base):
    """Carriere 2016: transverse (axial) slices every 0.5 mm following a curved 18 G
    brachytherapy needle (bicycle model), bevel rotated by 180 degrees at depth D."""

    step_mm: float = 0.5
    frame_rate_hz: float = 20.0
    insertion_mm: float = 100.0
    rotation_depth_mm: float = 60.0  # D = 60 or 80 in Carriere 2016
    radius_of_curvature_mm: float | None = None  # None: drawn around 1500 (Carriere's prior)
    theta0_deg: float = 0.0
    needle_depth_mm: float = 22.0
    spacing_mm: float = 0.3
    width_mm: float = 38.4
    depth_mm: float = 38.4
    plane_lag_mm: float = 0.25  # the slice sits this far behind the tip
    gauge: int = 18

    modality = "axial"
    paper = "Carriere 2016"

    def draw(self, rng: np.random.Generator) -> dict:
        R = self.radius_of_curvature_mm
        return {
            "radius_of_curvature_mm": float(R if R is not None
                                            else np.clip(rng.normal(1500, 400), 600, 3000)),
            "bend_phi_deg": float(rng.uniform(0, 360)),
            "lateral_mm": float(rng.uniform(-5, 5)),
            "tissue_seed": int(rng.integers(2**31)),
            "map_rng": int(rng.integers(2**31)),
        }

    def build(self, d: dict):
        p = self
        _check_positive("step_mm", p.step_mm)
        probe = PlaneProbe(width_mm=p.width_mm, depth_mm=p.depth_mm, spacing_mm=p.spacing_mm)
        imaging = p.imaging()
        dens = imaging.scatterer_density(probe.range_of_rows())
        lo = [-p.width_mm / 2, -5, 0]
        hi = [p.width_mm / 2, p.insertion_mm + 5, p.depth_mm]
        smap = random_scattering_map(np.random.default_rng(d["map_rng"]), lo, hi, p.background,
                                     plane_bias=False, distractors=p.distractors)
        phi = np.deg2rad(d["bend_phi_deg"])
        # needle along +y (the probe's elevation): the probe is stepped along it
        entry = np.array([d["lateral_mm"], 0.0, p.needle_depth_mm])
        path = NeedlePath(entry=entry, direction=[0, 1, 0],
                          radius_of_curvature_mm=d["radius_of_curvature_mm"],
                          bend_direction=[np.cos(phi), 0.0, np.sin(phi)],
                          theta0_deg=p.theta0_deg, turn_lengths_mm=(p.rotation_depth_mm,))
        world = World(Tissue(dens, d["tissue_seed"], smap), path, p.needle_spec(None))
        default_T = int(np.floor(p.insertion_mm / p.step_mm))
        T = _n_frames(p, default_T)
        ins = p.step_mm * (np.arange(T) + 1) + p.plane_lag_mm
        t = np.arange(T) / p.frame_rate_hz
        probe_pose = _const_pose(T)
        # the slice follows the tip's depth along the insertion axis
        probe_pose[:, 1, 3] = path.point_at(ins)[:, 1] - p.plane_lag_mm
        return Scanner(probe, imaging, world), Trajectory(t, ins, probe_pose, _const_pose(T))


def ye_insertion_velocity(n: int, fs_hz: float = 25.0, perturb_mm_s: float = 0.025,
                          perturb_period_s: float = 20.0) -> np.ndarray:
    """Ye 2025 section 4.1: v_in accelerates 0 -> 2 mm/s over 100 samples, stays, jumps to
    3 mm/s at sample 500, back to 2 mm/s at 1500 (to 2000); plus a 0.025 mm/s sinusoid of
    period 20 s."""
    k = np.arange(n)
    v = np.where(k < 100, 2.0 * k / 100.0, 2.0)
    v = np.where((k >= 500) & (k < 1500), 3.0, v)
    return v + perturb_mm_s * np.sin(2 * np.pi * k / fs_hz / perturb_period_s)


@dataclass(frozen=True)
class ServoScenario(_Base):
    """Ye 2025: the tip path of section 4.1 (25 Hz, 2000 samples; the needle starts along +X
    and bends towards +Y and +Z), imaged by a transverse plane (yOz) that follows the tip."""

    frame_rate_hz: float = 25.0
    n_samples: int = 2000
    start_sample: int = 0  # first sample of the profile to image (a window of it)
    radius_of_curvature_mm: float = 400.0
    plane_lag_mm: float = 0.5
    spacing_mm: float = 0.3
    width_mm: float = 38.4
    depth_mm: float = 38.4
    tip_depth_mm: float = 20.0
    gauge: int = 18

    modality = "axial"
    paper = "Ye 2025"

    def draw(self, rng: np.random.Generator) -> dict:
        return {"tissue_seed": int(rng.integers(2**31)), "map_rng": int(rng.integers(2**31))}

    def build(self, d: dict):
        p = self
        k0 = int(p.start_sample)
        if k0 < 0:
            raise ValueError(f"start_sample must be >= 0, got {k0}")
        T = _n_frames(p, max(p.n_samples - k0, 1))
        probe = PlaneProbe(width_mm=p.width_mm, depth_mm=p.depth_mm, spacing_mm=p.spacing_mm)
        imaging = p.imaging()
        dens = imaging.scatterer_density(probe.range_of_rows())
        v = ye_insertion_velocity(k0 + T, p.frame_rate_hz)
        s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) / p.frame_rate_hz)])[k0:]
        # The path bends from +X towards +Y and +Z, so v_y, v_z grow (Ye 2025, Fig. 7).
        path = NeedlePath(entry=np.zeros(3), direction=[1, 0, 0],
                          radius_of_curvature_mm=p.radius_of_curvature_mm,
                          bend_direction=[0, 1, 1], max_length_mm=max(250.0, s[-1] + 10))
        lo = [-10, -p.width_mm / 2 - 5, -p.tip_depth_mm]
        hi = [s[-1] + 10, p.width_mm / 2 + 20, p.depth_mm]
        smap = random_scattering_map(np.random.default_rng(d["map_rng"]), lo, hi, p.background,
                                     plane_bias=False, distractors=p.distractors)
        # tissue coordinates = world; the world origin is the tip's start, Z down
        world = World(Tissue(dens, d["tissue_seed"], smap), path, p.needle_spec(None))
        tip = path.point_at(s)
        # probe frame: x_p = +Y (lateral), y_p = -X (elevation), z_p = +Z (depth)
        R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        probe_pose = np.repeat(np.eye(4)[None], T, 0)
        probe_pose[:, :3, :3] = R
        probe_pose[:, 0, 3] = tip[:, 0] - p.plane_lag_mm
        probe_pose[:, 1, 3] = np.round(tip[:, 1], 1)  # the probe centred on the tip laterally
        probe_pose[:, 2, 3] = -p.tip_depth_mm
        t = (k0 + np.arange(T)) / p.frame_rate_hz
        return Scanner(probe, imaging, world), Trajectory(t, s, probe_pose, _const_pose(T))


SCENARIOS = {
    "inplane": InplaneScenario,
    "volume": VolumeScenario,
    "volume-motion": VolumeMotionScenario,
    "axial": AxialScenario,
    "servo": ServoScenario,
}


def scenario_params(name: str, **overrides):
    """The scenario's parameter dataclass with ``overrides`` applied and validated."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; choose one of {sorted(SCENARIOS)}")
    cls = SCENARIOS[name]
    names = {f.name for f in fields(cls)}
    bad = [k for k in overrides if k not in names]
    if bad:
        raise ValueError(f"scenario {name!r} has no parameter {bad[0]!r}; "
                         f"it has {sorted(names)}")
    p = cls(**overrides)
    p.validate()
    return p


def generate(name: str, seed: int = 0, progress: bool = False, timings: dict | None = None,
             **overrides) -> Sequence:
    """Generate a labelled sequence of scenario ``name``; the same seed gives the same data.

    ``timings`` (optional) receives the world set-up time and per-frame times.
    """
    p = scenario_params(name, **overrides)
    rng = np.random.default_rng(seed)
    draw = p.draw(rng)  # every random choice of the scenario, in one place
    scanner, traj = p.build(draw)
    noise_rng = np.random.default_rng([seed, 1])
    meta = {
        "scenario": name, "paper": p.paper, "seed": int(seed),
        "params": _jsonable(dataclasses.asdict(p)), "draw": _jsonable(draw),
        "imaging": _jsonable(dataclasses.asdict(scanner.params)),
        "probe": {"type": type(scanner.probe).__name__,
                  **_jsonable(dataclasses.asdict(scanner.probe))},
        "needle": {**_jsonable(dataclasses.asdict(scanner.world.needle)),
                   "radius_mm": scanner.world.needle.radius_mm},
        "tissue_density_per_mm3": scanner.world.tissue.density_per_mm3,
        "zhao_mode": bool(scanner.zhao_mode),
    }
    t0 = time.perf_counter()
    seq = render_sequence(scanner, traj, p.modality, noise_rng, meta, target_cr=p.cr,
                          progress=progress, timings=timings)
    if timings is not None:
        timings["total_s"] = time.perf_counter() - t0
    return seq


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, float) and not np.isfinite(x):
        return str(x)
    return x


def describe() -> str:
    """A human-readable list of the scenarios with their parameters and defaults."""
    lines = []
    for name, cls in SCENARIOS.items():
        doc = " ".join((cls.__doc__ or "").split())
        lines.append(f"{name}  [{cls.modality}]  {doc}")
        for f in fields(cls):
            if f.default is not dataclasses.MISSING:
                default = f.default
            elif f.default_factory is not dataclasses.MISSING:
                default = f.default_factory()
            else:
                default = "(required)"
            if isinstance(default, dict):
                lines.append(f"    {f.name}={default} (Python API: a dict of overrides)")
            else:
                lines.append(f"    --param {f.name}={default}")
        lines.append("")
    return "\n".join(lines)
