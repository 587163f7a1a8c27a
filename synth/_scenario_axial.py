"""The axial scenarios: Carriere 2016's curved needle under a stepped probe, and Ye 2025's
servo world whose probe plane follows the tip."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._probe import PlaneProbe
from ._render import Trajectory
from ._scanner import Scanner
from ._scenario_base import (
    _Base,
    _check_positive,
    _const_pose,
    _n_frames,
    _with_structures,
    interface_along,
    random_scattering_map,
)
from ._world import NeedlePath, Tissue, World

__all__ = ["AxialScenario", "ServoScenario", "ye_insertion_velocity"]


@dataclass(frozen=True)
class AxialScenario(_Base):
    """Carriere 2016: transverse (axial) slices every 0.5 mm following a curved 18 G
    brachytherapy needle (bicycle model), bevel rotated by 180 degrees at depth D.

    Beyond the protocol (for training and robustness tests): a bright interface along the
    insertion axis, which every slice cuts across as a line, and a slice that leads the tip
    (``plane_lag_mm`` < 0: slices past the tip, without the needle)."""

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
    # a bright interface along the insertion axis at this signed distance from the needle's
    # entry (mm, positive: deeper), tilted by interface_tilt_deg from the lateral axis; None:
    # none
    interface_offset_mm: float | None = None
    interface_tilt_deg: float = 0.0
    interface_brightness: float = 3.0  # amplitude gain at the boundary
    interface_factor: float = 1.0  # echogenicity beyond it (deeper side)

    modality = "axial"
    paper = "Carriere 2016"

    def validate(self) -> None:
        super().validate()
        t = self.interface_tilt_deg
        if not (isinstance(t, (int, float)) and np.isfinite(t) and abs(t) < 80.0):
            raise ValueError(f"interface_tilt_deg must be within (-80, 80), got {t!r}")

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
        entry = np.array([d["lateral_mm"], 0.0, p.needle_depth_mm])
        if p.interface_offset_mm is not None:
            tilt = np.deg2rad(p.interface_tilt_deg)
            smap = _with_structures(smap, **interface_along(
                entry, [np.cos(tilt), 0.0, np.sin(tilt)], [0.0, 1.0, 0.0], p.interface_offset_mm,
                p.interface_brightness, p.interface_factor))
        # needle along +y (the probe's elevation): the probe is stepped along it
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
