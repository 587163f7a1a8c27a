"""The external volume sets' probes and sequences: a 1-D array swept along its elevation axis
(parallel slices ``slice_step_mm`` apart), its elevation beam, the isotropic voxel grid the
volume is written on, and one spec per sequence (fixed seeds).

Frames: the probe frame of every volume is the file's frame (x lateral, y elevation: the sweep
axis, z depth; mm). The slices lie at y = (k - (K - 1) / 2) * slice_step_mm, k = 0..K-1, so
y = 0 is the middle slice; the array's centre on that slice is the origin.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .specs import PROBES, ProbeSetup

__all__ = ["VOLUME_PROBES", "VOLUME_SETS", "VOLUME_SPECS", "VOLUME_VALIDATION_SPECS",
           "VolumeProbe", "VolumeSpec", "elevation_fwhm_mm", "fine_setup", "needle_direction"]


@dataclass(frozen=True)
class VolumeProbe:
    """A swept 1-D array and the volume it makes.

    The output grid's voxels are ``voxel_mm`` cubes; in x and z their centres run from the
    first to the second value of ``x_mm`` and ``z_mm``; in y there is one voxel per slice
    (``slice_step_mm`` must equal ``voxel_mm``). Each slice is beamformed on pixels
    ``voxel_mm / fine_factor`` apart (the in-plane probe's window, :func:`fine_setup`) and
    its envelope averaged over each voxel's ``fine_factor`` x ``fine_factor`` pixels.
    """

    setup: ProbeSetup  # the in-plane probe: transmits, speckle density, sector (window unused)
    x_mm: tuple[float, float]  # first and last voxel centre, lateral
    z_mm: tuple[float, float]  # first and last voxel centre, depth
    n_slices: int  # slices per volume (voxels along y)
    elevation_aperture_mm: float  # height of the elements (elevation)
    elevation_focus_mm: float  # the elevation lens's focal depth
    voxel_mm: float = 0.5  # the volume model's and Zhao's 0.5 mm (models/volume.onnx metadata)
    slice_step_mm: float = 0.5  # sweep step between slices
    fine_factor: int = 4  # beamformed pixels per voxel along x and z
    band_mm: float = 4.0  # the elevation beam is taken as constant over depth bands this thick

    def __post_init__(self):
        if not np.isclose(self.slice_step_mm, self.voxel_mm):
            raise ValueError(f"VolumeProbe: slice_step_mm ({self.slice_step_mm}) must equal "
                             f"voxel_mm ({self.voxel_mm}): one voxel per slice along y")
        for name in ("x_mm", "z_mm"):
            a, b = getattr(self, name)
            n = (b - a) / self.voxel_mm
            if not (b > a and np.isclose(n, round(n))):
                raise ValueError(f"VolumeProbe.{name} {getattr(self, name)}: the last centre "
                                 f"must lie a whole number of voxels beyond the first")
        if self.n_slices < 2 or self.fine_factor < 1:
            raise ValueError("VolumeProbe: n_slices >= 2 and fine_factor >= 1 needed")

    @property
    def shape(self) -> tuple[int, int, int]:
        """Voxels (Z, Y, X), array order."""
        nz = int(round((self.z_mm[1] - self.z_mm[0]) / self.voxel_mm)) + 1
        nx = int(round((self.x_mm[1] - self.x_mm[0]) / self.voxel_mm)) + 1
        return nz, self.n_slices, nx

    @property
    def slice_y_mm(self) -> np.ndarray:
        """Elevation of every slice (K,), centred on y = 0."""
        k = np.arange(self.n_slices)
        return (k - 0.5 * (self.n_slices - 1)) * self.slice_step_mm

    @property
    def origin_mm(self) -> np.ndarray:
        """Position of voxel [0, 0, 0], array order (z, y, x)."""
        return np.array([self.z_mm[0], self.slice_y_mm[0], self.x_mm[0]])

    @property
    def spacing_mm(self) -> np.ndarray:
        return np.full(3, self.voxel_mm)


def fine_setup(vp: VolumeProbe) -> ProbeSetup:
    """The in-plane probe on each slice's beamformed window: pixels ``voxel_mm / fine_factor``
    apart, the first ``fine_factor`` of them averaging into the first voxel (so the window
    reaches half a voxel beyond the first and last voxel centres, less half a pixel)."""
    s = vp.voxel_mm / vp.fine_factor
    pad = 0.5 * (vp.fine_factor - 1) * s
    return replace(vp.setup, spacing_mm=s, x_range_mm=(vp.x_mm[0] - pad, vp.x_mm[1] + pad),
                   z_range_mm=(vp.z_mm[0] - pad, vp.z_mm[1] + pad))


def elevation_fwhm_mm(vp: VolumeProbe, depth_mm, wavelength_mm: float):
    """-6 dB width of the two-way elevation beam at ``depth_mm`` (range, for a sector): the
    diffraction width lambda z / H and the converging aperture's geometric width H |1 - z / F|
    in quadrature (a Gaussian-beam estimate, as the axial set's; Szabo, Diagnostic Ultrasound
    Imaging, ch. 6)."""
    h, f = vp.elevation_aperture_mm, vp.elevation_focus_mm
    z = np.asarray(depth_mm, float)
    return np.hypot(wavelength_mm * z / h, h * np.abs(1.0 - z / f))


VOLUME_PROBES = {
    # 128 elements, 7.6 MHz; the in-plane set's three plane waves compounded (one plane wave
    # left lateral arcs of the needle's echo brighter than the tissue across the slice), 5
    # scatterers per resolution cell (the 0.5 mm voxels average about 3 cells each).
    # Elevation: 5 mm elements, lens focus 18 mm (data sheet).
    # 48 x 40 x 32 voxels: 24 x 20 x 16 mm, 6-22 mm deep.
    "L11-5v": VolumeProbe(replace(PROBES["L11-5v"], scatterers_per_cell=5.0),
                          x_mm=(-11.75, 11.75), z_mm=(6.25, 21.75), n_slices=40,
                          elevation_aperture_mm=5.0, elevation_focus_mm=18.0),
    # 64 elements, 2.7 MHz; the in-plane set's three diverging waves on a 48-degree sector.
    # Elevation: 14 mm elements focused at 30 mm, in the volume (the P4-2v's own lens focuses
    # at 60 mm, which would make 6-9 mm thick slices at 20-35 mm; a probe swept for 3-D
    # imaging focuses where it images). 64 x 36 x 56 voxels: 32 x 18 x 28 mm, 12-40 mm deep.
    "P4-2v": VolumeProbe(replace(PROBES["P4-2v"], sector_half_angle_deg=24.0),
                         x_mm=(-15.75, 15.75), z_mm=(12.25, 39.75), n_slices=36,
                         elevation_aperture_mm=14.0, elevation_focus_mm=30.0, fine_factor=2),
}


def needle_direction(alpha_deg: float, beta_deg: float) -> np.ndarray:
    """Zhao 2013 eq. (4) inverted: the unit shaft direction with alpha = atan2(u_y, u_x) and
    beta = arccos(u_z)."""
    a, b = np.deg2rad(alpha_deg), np.deg2rad(beta_deg)
    return np.array([np.sin(b) * np.cos(a), np.sin(b) * np.sin(a), np.cos(b)])


@dataclass(frozen=True)
class VolumeSpec:
    """One volume sequence: a straight needle advancing ``step_mm`` per volume along
    ``needle_direction(alpha_deg, beta_deg)`` (from the entry towards the tip) to
    ``tip_mm`` (x, y, z) on the last volume; the probe and the tissue stand still."""

    name: str
    probe: str  # key of VOLUME_PROBES
    seed: int
    needle: bool = True
    tip_mm: tuple[float, float, float] = (4.0, 2.0, 15.0)  # the tip on the last volume
    alpha_deg: float = 30.0  # Zhao eq. (4): the shaft's azimuth, from +x towards +y
    beta_deg: float = 72.0  # Zhao eq. (4): the shaft's angle from +z (Zhao's beta: 73)
    step_mm: float = 3.0  # insertion per volume
    n_volumes: int = 6
    volume_rate_hz: float = 2.0
    gauge: int = 18
    target_cr: float = 2.5  # the wall band's contrast on the last volume (see volume_generate)
    roughness: float = 1.5  # sd of the wall scatterers' random amplitude around the coherent 1
    lower_wall_gain: float = 0.5  # the far wall's echo, behind the lumen
    bevel_length_mm: float = 1.5  # the lower wall ends this far before the tip
    bevel_gain: float = 2.0
    reverb_gain: float = 0.35  # amplitude ratio of successive reverberation copies
    n_reverb: int = 3
    shadow: float = 0.3  # amplitude left to the tissue behind the needle
    interface: tuple[float, float, float] | None = None  # (x_mm, z_mm, slope_deg): a plane
    #   along y through (x, z), descending slope_deg towards +x
    interface_cr: float = 2.5
    vessel: tuple[float, float, float, float, float] | None = None  # (x, y, z, azimuth_deg,
    #   radius_mm): a level tube through (x, y, z) along azimuth (from +x towards +y), anechoic
    inhomogeneity: float = 0.25  # sd of the log echogenicity (smooth, ~4 mm correlation)
    snr_db: float = 40.0  # tissue RF rms over electronic noise rms, per channel
    dynamic_range_db: float = 55.0
    gamma: float = 1.0
    tissue_grey: float = 85.0
    feature: str = "plain"


# The volume validation set (``needlenet/data/validation_volume``): for choosing volume models
# and tracker settings without looking at the test set below. Specs fixed before anything was
# generated or tracked.
VOLUME_VALIDATION_SPECS = (
    VolumeSpec("vv_lin_18", "L11-5v", 701, tip_mm=(5.0, 3.0, 15.5), alpha_deg=35.0,
               beta_deg=72.0, step_mm=3.0, gauge=18, target_cr=2.6, feature="plain"),
    VolumeSpec("vv_lin_20_interface", "L11-5v", 702, tip_mm=(4.0, -3.0, 13.0), alpha_deg=-30.0,
               beta_deg=75.0, step_mm=2.5, gauge=20, target_cr=2.4,
               interface=(4.0, 15.62, 17.2), interface_cr=2.4, dynamic_range_db=60,
               tissue_grey=80, feature="bright interface 2.5 mm below the axis, parallel"),
    VolumeSpec("vv_ph_17", "P4-2v", 801, tip_mm=(-5.0, 2.5, 32.0), alpha_deg=150.0,
               beta_deg=65.0, step_mm=2.5, gauge=17, target_cr=2.8, feature="plain"),
    VolumeSpec("vv_ph_no_needle", "P4-2v", 802, needle=False, interface=(0.0, 30.0, -12.0),
               interface_cr=2.5, vessel=(-4.0, 0.0, 22.0, 60.0, 2.5), dynamic_range_db=50,
               gamma=0.9, tissue_grey=90, feature="no needle; interface, vessel"),
    # a needle-free L11-5v volume with a bright interface across the sweep and a vessel
    VolumeSpec("vv_lin_no_needle", "L11-5v", 703, needle=False, interface=(-2.0, 14.0, -10.0),
               interface_cr=2.5, vessel=(-3.0, 2.0, 10.0, 40.0, 2.0), dynamic_range_db=60,
               tissue_grey=85, feature="no needle; interface, vessel"),
)

# The volume test set (``needlenet/data/external_volume``): other seeds, angles, gauges and
# scenes. Specs fixed before anything was generated or tracked.
VOLUME_SPECS = (
    VolumeSpec("ve_lin_19", "L11-5v", 711, tip_mm=(6.0, 2.0, 16.0), alpha_deg=25.0,
               beta_deg=68.0, step_mm=3.0, gauge=19, target_cr=2.6, feature="plain"),
    VolumeSpec("ve_lin_21_faint", "L11-5v", 712, tip_mm=(-5.0, 2.0, 14.0), alpha_deg=160.0,
               beta_deg=74.0, step_mm=2.5, gauge=21, target_cr=2.0, dynamic_range_db=50,
               gamma=0.9, tissue_grey=95, feature="faint"),
    VolumeSpec("ve_lin_no_needle", "L11-5v", 713, needle=False, interface=(0.0, 12.0, 8.0),
               interface_cr=2.4, vessel=(2.0, -3.0, 17.0, 20.0, 2.5), dynamic_range_db=55,
               tissue_grey=85, feature="no needle; interface, vessel"),
    VolumeSpec("ve_ph_18_interface", "P4-2v", 811, tip_mm=(6.0, 3.0, 30.0), alpha_deg=35.0,
               beta_deg=62.0, step_mm=3.0, gauge=18, target_cr=2.5,
               interface=(6.0, 32.98, 33.0), interface_cr=2.4, dynamic_range_db=55,
               tissue_grey=80, feature="bright interface 2.5 mm below the axis, parallel"),
    VolumeSpec("ve_ph_20_vessel", "P4-2v", 812, tip_mm=(-6.0, 3.0, 33.0), alpha_deg=140.0,
               beta_deg=66.0, step_mm=3.0, gauge=20, target_cr=2.6,
               vessel=(-0.75, -1.4, 29.95, 50.0, 2.5), dynamic_range_db=60, gamma=1.1,
               tissue_grey=75, feature="crosses a vessel"),
    VolumeSpec("ve_ph_19_steep", "P4-2v", 813, tip_mm=(-3.0, -3.0, 34.0), alpha_deg=-150.0,
               beta_deg=55.0, step_mm=2.0, gauge=19, target_cr=3.0, tissue_grey=90,
               feature="steep (35 degrees below level)"),
)
VOLUME_SETS = {"volume": VOLUME_SPECS, "volume-validation": VOLUME_VALIDATION_SPECS}
