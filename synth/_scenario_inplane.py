"""The in-plane scenario (Mathiassen 2017): a needle inserted in the plane of a static probe,
from either side, through the skin or the side of the view."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ._probe import PlaneProbe
from ._render import Trajectory
from ._scanner import Scanner
from ._scenario_base import (
    _Base,
    _breathing,
    _const_pose,
    _n_frames,
    _with_structures,
    interface_along,
    random_scattering_map,
)
from ._world import NeedlePath, ScatteringMap, SpecularLine, Tissue, World

__all__ = ["ENTRY_EDGES", "SIDES", "InplaneScenario"]


SIDES = ("right", "left")
# a boundary's specular echo is drawn as a thin shaft's wall (its diffuse share then spans
# 0.5 mm across the boundary)
_INTERFACE_GAUGE = 25
ENTRY_EDGES = ("top", "side")


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
    # the boundary's specular echo where it crosses the image plane (needle_echo's units; the
    # needle's specular lobe and diffuse floor, no reverberation, no tip): a smooth boundary
    # reflects as the needle's wall does. 0: a diffuse boundary only
    interface_echo: float = 0.0
    interface_roughness: float = 0.0  # share of that echo scattered diffusely (a rough boundary)
    interface_tilt_deg: float = 0.0  # the boundary's angle to the needle in the image plane
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
        if not (np.isfinite(self.interface_echo) and self.interface_echo >= 0):
            raise ValueError(f"interface_echo must be >= 0, got {self.interface_echo}")
        if not 0.0 <= self.interface_roughness <= 1.0:
            raise ValueError(f"interface_roughness must be in [0, 1], got "
                             f"{self.interface_roughness}")
        if not abs(self.interface_tilt_deg) < 90.0:
            raise ValueError(f"interface_tilt_deg must be in (-90, 90), got "
                             f"{self.interface_tilt_deg}")

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
        needle = p.needle_spec(None)
        world = World(Tissue(dens, d["tissue_seed"], smap), path, needle,
                      reflectors=self._reflectors(needle, entry, direction))
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

    def _reflectors(self, needle, entry, direction) -> tuple[SpecularLine, ...]:
        """The interface's specular line in the image plane (``interface_echo`` > 0): where
        the plane of :func:`interface_along` crosses y = 0, across the whole view, its wall
        (a radius above the line samples) on the boundary."""
        p = self
        if p.interface_offset_mm is None or p.interface_echo <= 0:
            return ()
        u = self._interface_axis(direction)
        n = np.array([-u[2], 0.0, u[0]])  # the plane's normal in the image plane, deeper
        n = n if n[2] >= 0 else -n
        spec = dataclasses.replace(needle, gauge=_INTERFACE_GAUGE, echo=float(p.interface_echo),
                                   reverb_count=0, tip_gain=0.0, shadow_factor=1.0,
                                   diffuse_fraction=float(p.interface_roughness),
                                   streak_db=None)
        c = np.array([entry[0], 0.0, entry[2]]) + (p.interface_offset_mm
                                                   + spec.radius_mm) * n
        half = 3.0 * max(p.width_mm, p.depth_mm)
        return (SpecularLine(c - half * u, c + half * u, spec),)

    def _interface_axis(self, direction) -> np.ndarray:
        """The interface's direction in the image plane: the needle's, turned by
        ``interface_tilt_deg`` about the elevation axis."""
        u = np.array([direction[0], 0.0, direction[2]])
        u /= np.linalg.norm(u)
        t = np.deg2rad(self.interface_tilt_deg)
        return np.array([u[0] * np.cos(t) - u[2] * np.sin(t), 0.0,
                         u[0] * np.sin(t) + u[2] * np.cos(t)])

    def _structures(self, smap: ScatteringMap, d: dict, entry, direction) -> ScatteringMap:
        """The drawn interface, vessels and shadows added to the scattering map (tissue
        frame = probe frame at the start: x lateral, y elevation, z depth)."""
        p = self
        extra: dict = {}
        if p.interface_offset_mm is not None:
            # the plane holding the needle's in-plane direction (turned by the tilt) and the
            # elevation axis
            u = self._interface_axis(direction)
            extra.update(interface_along(entry, u, [0.0, 1.0, 0.0], p.interface_offset_mm,
                                         p.interface_brightness, p.interface_factor))
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
