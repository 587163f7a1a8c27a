"""What one training world draws (:func:`randomize`): every random choice of its scenario and
imaging. In-plane and axial worlds are widened to every axis a real scanner or insertion
varies (:func:`randomize_inplane`, :func:`randomize_axial`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

import synth

if TYPE_CHECKING:
    from .data import DataConfig

__all__ = ["randomize", "randomize_inplane", "randomize_axial"]


def _u(rng, a, b):
    return float(rng.uniform(a, b))


def _draw_cr(rng: np.random.Generator, cfg: DataConfig) -> float:
    lo, hi = (float(v) for v in cfg.cr_range)  # checked by DataConfig
    if cfg.cr_log:
        return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    return _u(rng, lo, hi)


def randomize(modality: str, rng: np.random.Generator,
              cfg: DataConfig | None = None) -> tuple[str, dict]:
    """Every random choice of one training world: (scenario name, scenario overrides).
    ``cfg`` supplies the volume worlds' Zhao-mode share and contrast range (defaults of
    :class:`DataConfig` when None)."""
    if cfg is None:
        from .data import DataConfig
        cfg = DataConfig(modality=modality)
    imaging = {
        "center_frequency_mhz": _u(rng, 3.5, 10.0), "fractional_bandwidth": _u(rng, 0.4, 0.9),
        "f_number": _u(rng, 1.3, 3.0), "tx_focus_mm": _u(rng, 10, 40),
        "tx_f_number": _u(rng, 2.0, 4.0), "elevation_f_number": _u(rng, 3.0, 7.0),
        "elevation_focus_mm": _u(rng, 10, 35), "attenuation_db_cm_mhz": _u(rng, 0.3, 0.9),
        "tgc_compensation": _u(rng, 0.7, 1.1), "tissue_gray": _u(rng, 55, 130),
    }
    gauge = int(rng.choice([14, 16, 18, 19, 20, 21, 22]))
    needle = {
        "specular_width_deg": _u(rng, 8, 25), "diffuse_floor": _u(rng, 0.15, 0.6),
        "reverb_decay": _u(rng, 0.25, 0.7), "reverb_count": int(rng.integers(1, 8)),
        "shadow_factor": _u(rng, 0.2, 0.9), "tip_gain": _u(rng, 0.5, 4.0),
    }
    common = {
        "background": "inhomogeneous" if rng.random() < 0.85 else "homogeneous",
        "noise_db": _u(rng, -60, -30), "dynamic_range_db": _u(rng, 45, 75),
        "scatterers_per_cell": _u(rng, 8, 16), "gauge": gauge,
        "needle_echo": float(np.exp(rng.uniform(np.log(12), np.log(150)))),
        "imaging_overrides": imaging, "needle_overrides": needle,
    }
    if modality == "inplane" and cfg.inplane_worlds == "narrow":
        start = _u(rng, 0.0, 30.0)
        narrow = {
            **common, "angle_deg": _u(rng, 15, 70), "speed_mm_s": _u(rng, 3, 20),
            "spacing_mm": _u(rng, 0.12, 0.3), "width_mm": _u(rng, 26, 40),
            "depth_mm": _u(rng, 28, 50), "start_length_mm": start,
            "stop_length_mm": start + 30.0, "out_of_plane_deg": _u(rng, -3, 3),
            "elevation_offset_mm": float(rng.normal(0, 0.7)),
            "tissue_motion_mm": _u(rng, 0, 2) if rng.random() < 0.3 else 0.0,
        }
        if cfg.inplane_boundaries > 0 and _maybe(rng, cfg.inplane_boundaries):
            narrow.update(boundary_beside(rng, narrow["needle_echo"]))
        return "inplane", narrow
    if modality == "inplane":
        return "inplane", randomize_inplane(rng, common)
    if modality == "axial":
        if rng.random() < 0.3:
            servo = {**common, "start_sample": int(rng.integers(150, 1900)),
                     "spacing_mm": _u(rng, 0.2, 0.4), "width_mm": _u(rng, 26, 40),
                     "depth_mm": _u(rng, 26, 40), "plane_lag_mm": _u(rng, -2.0, 2.0),
                     "tip_depth_mm": _u(rng, 10, 25)}
            return "servo", randomize_axial(rng, "servo", servo)
        ins = _u(rng, 15, 35)
        return "axial", randomize_axial(rng, "axial", {
            **common, "spacing_mm": _u(rng, 0.2, 0.4), "width_mm": _u(rng, 26, 40),
            "depth_mm": _u(rng, 26, 40), "insertion_mm": ins,
            "rotation_depth_mm": _u(rng, 5, ins), "radius_of_curvature_mm": _u(rng, 300, 3000),
            "needle_depth_mm": _u(rng, 8, 25), "plane_lag_mm": _u(rng, -2.0, 1.5),
            "theta0_deg": _u(rng, -3, 3),
        })
    if modality == "volume":
        zhao = rng.random() < cfg.zhao_fraction
        vol = {**common, "output_size": int(rng.integers(56, 81)),
               "background": "inhomogeneous" if rng.random() < 0.85 else "homogeneous",
               "center_frequency_mhz": _u(rng, 2.5, 5.0)}
        vol["imaging_overrides"] = {k: v for k, v in imaging.items()
                                    if k not in ("center_frequency_mhz",)}
        vol["imaging_overrides"]["tissue_gray"] = _u(rng, 25, 110)
        if rng.random() < 0.2:
            return "volume-motion", {**vol, "motion_mm": _u(rng, 0, 4),
                                     "motion_deg": _u(rng, 0, 8)}
        start = _u(rng, 0.0, 12.0)
        world = {
            **vol, "zhao_mode": zhao, "cr": _draw_cr(rng, cfg) if zhao else None,
            "alpha_deg": _u(rng, 0, 90), "beta_deg": _u(rng, 55, 85),
            "start_length_mm": start, "stop_length_mm": start + _u(rng, 8, 25),
            "volume_rate_hz": 2.0,
        }
        if cfg.volume_interfaces > 0 and _maybe(rng, cfg.volume_interfaces):
            world.update(interface_in_volume(rng))
        if cfg.volume_needle_free > 0 and _maybe(rng, cfg.volume_needle_free):
            world.update(needle_free=True, cr=None)
        return "volume", world
    raise ValueError(f"unknown modality {modality!r}")


def _maybe(rng, p: float) -> bool:
    return bool(rng.random() < p)


def boundary_beside(rng: np.random.Generator, needle_echo: float) -> dict:
    """A tissue boundary 1-8 mm above or below the needle, drawn with its specular echo (synth's
    ``interface_echo``: a line across the view, 0.25-2.5 times the needle's echo, smooth or up to
    60% rough at even odds, tilted to the needle by a few degrees, sd 5, at most 15) over a
    half-space 1-3 times as bright: the needle-like line a fascia shows beside a needle."""
    return {"interface_offset_mm": float(rng.choice([-1, 1]) * rng.uniform(1.0, 8.0)),
            "interface_brightness": _u(rng, 1.0, 3.0),
            "interface_factor": _u(rng, 0.6, 1.5),
            "interface_echo": needle_echo * float(np.exp(rng.uniform(np.log(0.25),
                                                                     np.log(2.5)))),
            "interface_roughness": 0.0 if _maybe(rng, 0.5) else _u(rng, 0.0, 0.6),
            "interface_tilt_deg": float(np.clip(rng.normal(0.0, 5.0), -15, 15))}


def interface_in_volume(rng: np.random.Generator) -> dict:
    """A bright tissue boundary beside the needle in a volume (synth's volume interface: the
    plane holding the needle's axis, rolled about it by up to 40 degrees and moved 1.5-8 mm off
    it to either side), 1.5-6 times as bright at the boundary as the tissue: a fascia's sheet,
    whose lines along it are needle-like in every slice."""
    return {"interface_offset_mm": float(rng.choice([-1, 1]) * rng.uniform(1.5, 8.0)),
            "interface_roll_deg": _u(rng, -40.0, 40.0),
            "interface_brightness": _u(rng, 1.5, 6.0),
            "interface_factor": _u(rng, 0.6, 1.5)}


def _wide_scanner(rng: np.random.Generator, imaging: dict, low_mhz: float, sector: float,
                  apex_mm: float, face_reverb: float) -> dict:
    """``imaging`` widened to the scanners a user may bring: centre frequency low_mhz-15 MHz
    (log-uniform), TGC, tissue grey, compounding 2-3 looks 50%; grey maps 50%; TGC curves 50%;
    capture margins 30%; sector masks (half-angle 20-50 degrees, apex 0-apex_mm) at share
    ``sector``; probe-face reverberation at share ``face_reverb``."""
    imaging = dict(imaging)
    imaging.update({
        "center_frequency_mhz": float(np.exp(rng.uniform(np.log(low_mhz), np.log(15.0)))),
        "tgc_compensation": _u(rng, 0.6, 1.15), "tissue_gray": _u(rng, 40, 170),
        "compound_looks": int(rng.choice([1, 1, 2, 3])),
    })
    if _maybe(rng, 0.5):
        imaging.update(gray_gamma=float(np.exp(rng.uniform(np.log(0.6), np.log(1.6)))),
                       gray_offset=_u(rng, -15, 25), gray_white=_u(rng, 170, 255))
    if _maybe(rng, 0.5):
        imaging["tgc_curve_db"] = tuple(rng.normal(0.0, 4.0, int(rng.integers(3, 7))).tolist())
    if _maybe(rng, 0.3):
        imaging["margin_mm"] = tuple(float(rng.uniform(0.5, 6.0)) if _maybe(rng, 0.5) else 0.0
                                     for _ in range(4))
    if _maybe(rng, sector):
        imaging.update(sector_half_angle_deg=_u(rng, 20, 50), sector_apex_mm=_u(rng, 0, apex_mm))
    if _maybe(rng, face_reverb):
        imaging.update(face_reverb_gain=_u(rng, 1.0, 8.0), face_reverb_spacing_mm=_u(rng, 0.6, 3),
                       face_reverb_decay=_u(rng, 0.3, 0.75))
    return imaging


def randomize_axial(rng: np.random.Generator, name: str, scenario: dict) -> dict:
    """An axial world's overrides (``scenario``: the Carriere or servo draws of
    :func:`randomize`) widened to the scanners and scenes a user may bring: the scanner axes of
    :func:`_wide_scanner` (2.5-15 MHz; sector masks 35%, probe-face reverberation 30%), dynamic
    range 40-80 dB, needle echoes 8-200, 0-8 reverberations. Carriere's worlds add a bright
    interface along the insertion axis, which every slice cuts across as a line (35%: 1-8 mm
    above or below the needle, tilted up to 20 degrees, 1.5-6 times as bright), and slices
    2-6 mm past the tip, without the needle (20%)."""
    imaging = _wide_scanner(rng, scenario["imaging_overrides"], low_mhz=2.5, sector=0.35,
                            apex_mm=30.0, face_reverb=0.3)
    needle = dict(scenario["needle_overrides"])
    needle.update({"reverb_count": 0 if _maybe(rng, 0.2) else int(rng.integers(1, 9)),
                   "shadow_factor": _u(rng, 0.1, 0.95)})
    out = {**scenario, "imaging_overrides": imaging, "needle_overrides": needle,
           "dynamic_range_db": _u(rng, 40, 80), "noise_db": _u(rng, -65, -30),
           "needle_echo": float(np.exp(rng.uniform(np.log(8), np.log(200))))}
    if name != "axial":
        return out
    if _maybe(rng, 0.35):
        out.update(interface_offset_mm=float(rng.choice([-1, 1]) * rng.uniform(1.0, 8.0)),
                   interface_tilt_deg=_u(rng, -20, 20),
                   interface_brightness=float(np.exp(rng.uniform(np.log(1.5), np.log(6.0)))),
                   interface_factor=_u(rng, 0.6, 1.5))
    if _maybe(rng, 0.2):
        out["plane_lag_mm"] = _u(rng, -6.0, -2.0)
    return out


def randomize_inplane(rng: np.random.Generator, common: dict) -> dict:
    """The in-plane world's overrides: ``common`` (the draws every modality shares) widened
    to every axis a real scanner or insertion varies. Shares: needle-free worlds 10%; entry
    through the lateral border 35%; shallow (3-20 degree) insertions 40%; compounding 2-3
    looks 50%; grey maps 50%; TGC curves 50%; capture margins 30%; sector masks 20%;
    probe-face reverberation 40%; an interface parallel to the needle 30%; vessels 25%;
    shadows 15%; diffuse shafts 30%; no reverberation tail 25%; dark bevels 25%; the streak
    of unfocused imaging past the tip 30% (levels around those measured on PyMUST)."""
    imaging = _wide_scanner(rng, common["imaging_overrides"], low_mhz=3.0, sector=0.2,
                            apex_mm=40.0, face_reverb=0.4)
    needle = dict(common["needle_overrides"])
    needle.update({
        "specular_width_deg": _u(rng, 5, 30), "diffuse_floor": _u(rng, 0.1, 0.6),
        "reverb_count": 0 if _maybe(rng, 0.25) else int(rng.integers(1, 9)),
        "shadow_factor": _u(rng, 0.1, 0.95),
        "tip_gain": _u(rng, 0.0, 0.3) if _maybe(rng, 0.25) else _u(rng, 0.5, 5.0),
        "diffuse_fraction": _u(rng, 0.3, 1.0) if _maybe(rng, 0.3) else 0.0,
        "diffuse_seed": int(rng.integers(2**31)),
    })
    width, depth = _u(rng, 26, 50), _u(rng, 25, 60)
    angle = _u(rng, 3, 20) if _maybe(rng, 0.4) else _u(rng, 20, 85)
    edge = "side" if _maybe(rng, 0.35) else "top"
    if edge == "side":
        offset = (0.0, 2.0)
    elif angle > 50:  # steep: the skin entry lies over the image
        offset = (-0.6 * width, 0.0)
    else:
        offset = (-0.3 * width, 3.0)
    start = _u(rng, 0.0, 30.0)
    out = {
        **common, "imaging_overrides": imaging, "needle_overrides": needle,
        "gauge": int(rng.choice(sorted(k for k in synth.GAUGE_OUTER_DIAMETER_MM
                                       if 14 <= k <= 25))),
        "needle_echo": float(np.exp(rng.uniform(np.log(8), np.log(200)))),
        "noise_db": _u(rng, -65, -30), "dynamic_range_db": _u(rng, 40, 80),
        "angle_deg": angle, "speed_mm_s": _u(rng, 3, 20), "side": str(rng.choice(["right",
                                                                                "left"])),
        "entry_edge": edge, "entry_offset_range_mm": offset,
        "entry_depth_range_mm": (2.0, 0.7 * depth),
        "spacing_mm": _u(rng, 0.1, 0.3), "width_mm": width, "depth_mm": depth,
        "start_length_mm": start, "stop_length_mm": start + 30.0,
        "out_of_plane_deg": _u(rng, -4, 4), "elevation_offset_mm": float(rng.normal(0, 0.5)),
        "needle_free": _maybe(rng, 0.1),
        "vessels": int(rng.integers(1, 3)) if _maybe(rng, 0.25) else 0,
        "shadows": int(rng.integers(1, 3)) if _maybe(rng, 0.15) else 0,
    }
    if _maybe(rng, 0.3):  # unfocused (plane-wave) imaging: the streak past the tip
        needle.update(streak_db=_u(rng, -20, -6), streak_db_per_deg=_u(rng, -0.9, -0.4),
                      streak_fade_db_per_mm=_u(rng, 0.5, 4.0))
    if _maybe(rng, 0.3):
        out.update(interface_offset_mm=float(rng.choice([-1, 1]) * rng.uniform(1.2, 8.0)),
                   interface_brightness=_u(rng, 1.5, 6.0), interface_factor=_u(rng, 0.6, 1.5))
    return out
