"""The external axial set's sequences: the in-plane set's probes on smaller windows, their
elevation beams, and one spec per sequence (fixed seeds)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .specs import PROBES

__all__ = ["AXIAL_PROBES", "AXIAL_SPECS", "AXIAL_VALIDATION_SPECS", "ELEVATION", "AxialSpec",
           "elevation_fwhm_mm"]

# The in-plane probes (same transmits and compounding) on windows around the needle's
# cross-section: every slice needs its own tissue, so the image is kept to what the tracker
# needs around the needle (15 x 15 mm on the L11-5v, a 44-degree sector to 34 mm on the
# P4-2v). The P4-2v's pixels are 0.25 mm (its speckle is ~0.6 mm deep and wider, 2.7 MHz),
# which keeps the set's files small (sequence files store 8-bit frames uncompressed).
AXIAL_PROBES = {
    "L11-5v": replace(PROBES["L11-5v"], x_range_mm=(-7.5, 7.5), z_range_mm=(5.0, 20.0)),
    "P4-2v": replace(PROBES["P4-2v"], spacing_mm=0.25, x_range_mm=(-12.75, 12.75),
                     z_range_mm=(0.0, 34.0), sector_half_angle_deg=22.0),
}

# Elevation aperture height and lens focus (mm) of the two probes (Verasonics data sheets;
# PyMUST's getparam gives the same heights, 5 and 14 mm, and no elevation focus).
ELEVATION = {"L11-5v": (5.0, 18.0), "P4-2v": (14.0, 60.0)}


def elevation_fwhm_mm(probe: str, depth_mm: float, wavelength_mm: float) -> float:
    """-6 dB elevation width of the two-way beam at ``depth_mm``: the diffraction-limited width
    lambda z / H and the geometric width of the converging aperture H |1 - z / F| added in
    quadrature (a Gaussian-beam estimate; Szabo, Diagnostic Ultrasound Imaging, ch. 6)."""
    h, f = ELEVATION[probe]
    return float(np.hypot(wavelength_mm * depth_mm / h, h * abs(1.0 - depth_mm / f)))


@dataclass(frozen=True)
class AxialSpec:
    """One axial sequence. The world frame is the probe frame of slice 0 (x lateral, y
    elevation, z depth; mm); slice k lies at y = k * step_mm. The needle crosses slice 0 at
    ``centre_mm`` (x, z) heading along +y, tilted by ``tilt_x_deg`` towards +x and
    ``tilt_z_deg`` towards +z, bending with radius ``radius_of_curvature_mm`` (None: straight)
    towards the (x, z) direction ``bend_deg`` (0: +x, 90: +z); its tip lies at y =
    ``tip_y_mm``."""

    name: str
    probe: str  # key of AXIAL_PROBES
    seed: int
    needle: bool = True
    centre_mm: tuple[float, float] = (0.0, 12.0)
    tilt_x_deg: float = 6.0
    tilt_z_deg: float = 3.0
    radius_of_curvature_mm: float | None = None
    bend_deg: float = 0.0
    tip_y_mm: float = 17.0
    step_mm: float = 0.75  # probe step per slice (Carriere 2016: 0.5 mm)
    n_frames: int = 30
    frame_rate_hz: float = 20.0
    gauge: int = 18
    target_cr: float = 2.5  # contrast of the upper wall on the reference slice (see generate)
    roughness: float = 1.5  # sd of the wall scatterers' random amplitude around the coherent 1
    arc_half_angle_deg: float = 70.0  # the upper wall: this far either side of the top
    lower_wall_gain: float = 0.4  # the far wall's echo, behind the lumen
    bevel_length_mm: float = 1.5  # the lower wall ends this far before the tip
    bevel_gain: float = 2.0
    reverb_gain: float = 0.35  # amplitude ratio of successive reverberation copies
    n_reverb: int = 3
    shadow: float = 0.3  # amplitude transmitted into the column behind the needle
    interface: tuple[float, float, float] | None = None  # (x_mm, z_mm, slope_deg), along y
    interface_cr: float = 2.5
    vessel: tuple[float, float, float] | None = None  # (x_mm, z_mm, radius_mm), along y
    inhomogeneity: float = 0.25  # sd of the log echogenicity (smooth, ~4 mm correlation)
    snr_db: float = 40.0
    dynamic_range_db: float = 55.0
    gamma: float = 1.0
    tissue_grey: float = 85.0
    feature: str = "plain"


AXIAL_SPECS = (
    AxialSpec("ax_lin_18", "L11-5v", 501, centre_mm=(-2.0, 11.5), tilt_x_deg=8.0,
              tilt_z_deg=4.0, tip_y_mm=17.0, gauge=18, target_cr=2.6, feature="plain"),
    AxialSpec("ax_lin_22_faint", "L11-5v", 502, centre_mm=(1.5, 13.0), tilt_x_deg=-6.0,
              tilt_z_deg=-3.0, radius_of_curvature_mm=900.0, bend_deg=200.0, tip_y_mm=17.5,
              gauge=22, target_cr=1.9, dynamic_range_db=50, gamma=0.9, tissue_grey=95,
              feature="faint, curved (R = 900 mm)"),
    AxialSpec("ax_lin_20_interface", "L11-5v", 503, centre_mm=(-1.0, 10.5), tilt_x_deg=5.0,
              tilt_z_deg=2.0, tip_y_mm=16.5, gauge=20, target_cr=2.5,
              interface=(0.0, 13.2, 4.0), interface_cr=2.3, dynamic_range_db=60, gamma=1.1,
              tissue_grey=80, feature="bright interface 2.1-2.6 mm below the axis"),
    AxialSpec("ax_ph_16", "P4-2v", 601, centre_mm=(-3.0, 20.0), tilt_x_deg=10.0,
              tilt_z_deg=5.0, tip_y_mm=17.0, gauge=16, target_cr=2.8, tissue_grey=80,
              feature="plain"),
    AxialSpec("ax_ph_18_vessel", "P4-2v", 602, centre_mm=(4.0, 18.0), tilt_x_deg=-9.0,
              tilt_z_deg=6.0, tip_y_mm=17.5, gauge=18, target_cr=2.6,
              vessel=(-0.5, 23.0, 2.5), dynamic_range_db=55,
              feature="approaches a vessel (0.5 mm gap at the tip)"),
    AxialSpec("ax_ph_19_curved", "P4-2v", 603, centre_mm=(2.0, 15.0), tilt_x_deg=-4.0,
              tilt_z_deg=8.0, radius_of_curvature_mm=400.0, bend_deg=160.0, tip_y_mm=16.5,
              gauge=19, target_cr=2.4, dynamic_range_db=60, gamma=1.2, tissue_grey=75,
              feature="curved (R = 400 mm), descending"),
    AxialSpec("ax_ph_no_needle", "P4-2v", 604, needle=False, interface=(0.0, 14.0, -10.0),
              interface_cr=2.4, vessel=(3.0, 24.0, 3.0), dynamic_range_db=55, tissue_grey=85,
              feature="no needle; interface, vessel"),
)


# The axial validation set (``needlenet/data/validation_axial``): other seeds, needles and
# scenes, for choosing axial tracker settings and models without looking at the set above.
# Specs fixed before any tracker was run on them.
AXIAL_VALIDATION_SPECS = (
    AxialSpec("axv_ph_17", "P4-2v", 611, centre_mm=(1.0, 17.0), tilt_x_deg=-7.0,
              tilt_z_deg=4.0, tip_y_mm=16.0, gauge=17, target_cr=2.6, feature="plain"),
    AxialSpec("axv_ph_20_interface", "P4-2v", 612, centre_mm=(-2.0, 14.0), tilt_x_deg=6.0,
              tilt_z_deg=3.0, tip_y_mm=17.0, gauge=20, target_cr=2.5,
              interface=(0.0, 17.0, 5.0), interface_cr=2.4, dynamic_range_db=60,
              tissue_grey=80, feature="bright interface about 2.5 mm below the axis"),
    AxialSpec("axv_ph_no_needle", "P4-2v", 613, needle=False, interface=(0.0, 20.0, 8.0),
              interface_cr=2.5, vessel=(-4.0, 12.0, 2.5), dynamic_range_db=50, gamma=0.9,
              tissue_grey=90, feature="no needle; interface, vessel"),
    AxialSpec("axv_lin_19_interface", "L11-5v", 511, centre_mm=(1.0, 12.0), tilt_x_deg=-5.0,
              tilt_z_deg=3.0, tip_y_mm=17.0, gauge=19, target_cr=2.4,
              interface=(0.0, 14.5, -3.0), interface_cr=2.4, dynamic_range_db=55,
              tissue_grey=85, feature="bright interface about 2 mm below the axis"),
    AxialSpec("axv_lin_21", "L11-5v", 512, centre_mm=(-1.5, 10.0), tilt_x_deg=7.0,
              tilt_z_deg=2.0, tip_y_mm=16.0, gauge=21, target_cr=2.2, feature="plain"),
)
