"""The external in-plane test set: needle sequences simulated with PyMUST, not with synth.

Run ``python -m needlenet.bench.external.generate --out DIR [--only NAME ...]``; it writes one
sequence file per entry of :data:`SPECS` (``DIR/NAME.npz``). PyMUST (``pip install
'needlenet[external]'``) is imported here only; the runtime never needs it.

Image formation, per sequence and per transmit (PyMUST ``simus``, 2D, a linear model with single
scattering, so the RF of a sum of scatterer sets is the sum of their RFs):

- the tissue RF is simulated once (the echogenicity map, a vessel and the diffuse band of an
  interface are amplitudes of the tissue scatterers);
- the needle is cut into the length it gains between frames; each piece (two walls of the
  gauge's diameter, dense equal-phase scatterers with a little roughness, and reverberation
  copies below them) is simulated once, and the bevel at the tip once per frame;
- frame t's RF = tissue + interface line + the pieces inserted by frame t + the bevel at t
  + electronic noise drawn for frame t; frames are beamformed (``dasmtx``) and compounded.

Every simus call also holds two zero-amplitude scatterers at the far corners of the simulated
domain, so all calls share one frequency grid and one RF length and the sum is exact. The
needle and interface amplitudes are scaled after beamforming so that, on the 8-bit image, the
mean grey within 0.3 mm of the reflector's probe-facing surface is the spec's multiple of the
same pixels' mean grey without it (the needle on the last frame). Each file also carries Zhao
2013's eq. (9) contrast per frame (``contrast_ratio``, as ``synth.contrast_ratio``).

Frames are 8-bit: a fixed depth gain (TGC) flattens the tissue's median envelope, the display
gain puts the tissue's mean grey at the spec's value, then grey = 255 * ((dB + DR) / DR) ** gamma.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from scipy import ndimage

import synth

__all__ = ["PROBES", "SPECS", "ProbeSetup", "SequenceSpec", "generate", "main"]


@dataclass(frozen=True)
class ProbeSetup:
    """A PyMUST probe, its transmits and the image it makes."""

    model: str  # pymust.getparam name
    tilts_deg: tuple[float, ...]  # steering of the compounded transmits
    diverging_width_deg: float | None  # angular width of diverging waves; None: plane waves
    spacing_mm: float  # output pixel size, both axes
    x_range_mm: tuple[float, float]  # lateral extent of the output image
    z_range_mm: tuple[float, float]  # depth extent of the output image
    sector_half_angle_deg: float | None  # sector probes: half opening of the scan-converted fan
    polar_step_deg: float = 0.4  # sector probes: angle between beamformed lines
    margin_mm: float = 1.0  # scatterers extend this far beyond the image
    element_splitting: int | None = None  # simus ElementSplitting; None: PyMUST's rule
    attenuation_db_cm_mhz: float = 0.5
    db_thresh: float = -40.0  # simus keeps the frequencies of the spectrum above this level
    scatterers_per_cell: float = 10.0  # per -6 dB resolution cell, measured on a point target


PROBES = {
    # 128 elements, 7.6 MHz, 0.3 mm pitch; three plane waves compounded. The 0.27 mm elements
    # are in their far field (w^2 / lambda = 0.36 mm) at every simulated depth, so simus need
    # not split them.
    "L11-5v": ProbeSetup("L11-5v", (-5.0, 0.0, 5.0), None, 0.10, (-12.5, 12.5), (1.0, 31.0),
                         None, element_splitting=1),
    # 64 elements, 2.7 MHz; three diverging waves, beamformed on a polar grid and scan-converted
    "P4-2v": ProbeSetup("P4-2v", (-10.0, 0.0, 10.0), 75.0, 0.15, (-26.25, 26.25), (0.0, 45.0),
                        35.0),
}


@dataclass(frozen=True)
class SequenceSpec:
    """One sequence of the set. Lines are given by a point and a slope (degrees from +x towards
    +z: positive descends to the right)."""

    name: str
    probe: str  # key of PROBES
    seed: int
    needle: bool = True
    side: str = "left"  # the needle comes from the left (travels to +x) or from the right
    entry_x_mm: float = 0.0  # where the needle axis crosses the skin line z = 0
    angle_deg: float = 30.0  # angle between needle and skin
    start_mm: float = 10.0  # inserted length (from the skin line) at frame 0
    step_mm: float = 1.5  # insertion per frame
    n_frames: int = 14
    frame_rate_hz: float = 20.0
    gauge: int = 18
    target_cr: float = 2.5  # needle-to-tissue contrast on the last frame (see _local_contrast)
    roughness: float = 1.5  # sd of the wall scatterers' random amplitude around the coherent 1
    bevel_gain: float = 2.0  # sd of the bevel scatterers' (random) amplitude over roughness
    bevel_length_mm: float = 1.5
    reverb_gain: float = 0.35  # amplitude ratio of successive reverberation copies
    n_reverb: int = 3
    interface: tuple[float, float, float] | None = None  # (x_mm, z_mm, slope_deg)
    interface_cr: float = 2.5  # interface-to-tissue contrast, as the needle's
    vessel: tuple[float, float, float] | None = None  # (x_mm, z_mm, radius_mm), anechoic
    inhomogeneity: float = 0.25  # sd of the log echogenicity (smooth, ~4 mm correlation)
    snr_db: float = 40.0  # tissue RF rms over electronic noise rms, per channel
    dynamic_range_db: float = 55.0
    gamma: float = 1.0  # grey map: grey = 255 * ((dB + DR) / DR) ** gamma
    tissue_grey: float = 85.0  # mean grey of the tissue, set by the display gain
    feature: str = "plain"  # a word for the README table


SPECS = (
    SequenceSpec("lin_left_top_30", "L11-5v", 101, side="left", entry_x_mm=-10.0, angle_deg=30,
                 start_mm=7.0, step_mm=1.3, target_cr=2.6, dynamic_range_db=55, tissue_grey=85),
    SequenceSpec("lin_right_side_12", "L11-5v", 102, side="right", entry_x_mm=40.0,
                 angle_deg=12, start_mm=33.0, step_mm=1.5, target_cr=2.8, gauge=20,
                 dynamic_range_db=60, gamma=1.2, tissue_grey=70, feature="shallow"),
    SequenceSpec("lin_left_side_22_faint", "L11-5v", 103, side="left", entry_x_mm=-25.0,
                 angle_deg=22, start_mm=18.0, step_mm=1.4, target_cr=1.9, gauge=21,
                 dynamic_range_db=50, gamma=0.9, tissue_grey=95, feature="faint"),
    SequenceSpec("lin_right_top_40_interface", "L11-5v", 104, side="right", entry_x_mm=11.0,
                 angle_deg=40, start_mm=5.0, step_mm=1.2, target_cr=2.6, gauge=18,
                 interface=(0.0, 13.0, -40.0), interface_cr=2.2, dynamic_range_db=55,
                 tissue_grey=80, feature="bright interface 2.9 mm below, parallel"),
    SequenceSpec("lin_vessel_no_needle", "L11-5v", 105, needle=False,
                 interface=(0.0, 7.0, 8.0), interface_cr=2.4, vessel=(3.0, 19.0, 3.0),
                 dynamic_range_db=55, tissue_grey=85, feature="no needle; vessel, interface"),
    SequenceSpec("ph_right_side_45_vessel", "P4-2v", 201, side="right", entry_x_mm=26.0,
                 angle_deg=45, start_mm=25.6, step_mm=1.5, target_cr=2.6, gauge=18,
                 vessel=(-0.2, 26.2, 3.5), dynamic_range_db=55, tissue_grey=85,
                 feature="crosses a vessel"),
    SequenceSpec("ph_left_side_65_steep", "P4-2v", 202, side="left", entry_x_mm=-14.0,
                 angle_deg=65, start_mm=17.0, step_mm=1.5, target_cr=2.8, gauge=18,
                 dynamic_range_db=60, gamma=1.1, tissue_grey=75, feature="steep"),
    SequenceSpec("ph_left_side_35_interface", "P4-2v", 203, side="left", entry_x_mm=-30.0,
                 angle_deg=35, start_mm=30.0, step_mm=1.8, target_cr=2.4, gauge=17,
                 interface=(0.0, 25.0, 35.0), interface_cr=2.2, dynamic_range_db=50,
                 gamma=0.9, tissue_grey=90, feature="bright interface 3.3 mm below, parallel"),
    SequenceSpec("ph_right_side_55", "P4-2v", 204, side="right", entry_x_mm=22.0, angle_deg=55,
                 start_mm=23.0, step_mm=2.0, target_cr=2.8, gauge=16, dynamic_range_db=55,
                 tissue_grey=80, feature="plain"),
    SequenceSpec("ph_interface_no_needle", "P4-2v", 205, needle=False,
                 interface=(0.0, 22.0, -20.0), interface_cr=2.4, vessel=(6.0, 34.0, 3.5),
                 dynamic_range_db=55, tissue_grey=85, feature="no needle; interface, vessel"),
)

_C = 1540.0  # m/s
CONTRAST_RADIUS_MM = 0.3  # half-width of the band in which a reflector's contrast is measured


# -- geometry of the simulated domain and the image ------------------------------------------

class _Domain:
    """Where scatterers live (mm), the beamforming grid, and the output image grid."""

    def __init__(self, setup: ProbeSetup, wavelength_mm: float):
        self.setup = setup
        s = setup.spacing_mm
        x0, x1 = setup.x_range_mm
        z0, z1 = setup.z_range_mm
        self.nx = int(round((x1 - x0) / s)) + 1
        self.nz = int(round((z1 - z0) / s)) + 1
        self.origin_mm = np.array([z0, x0])  # array order [z, x]
        self.spacing_mm = np.array([s, s])
        zz, xx = np.meshgrid(z0 + s * np.arange(self.nz), x0 + s * np.arange(self.nx),
                             indexing="ij")
        self.img_x, self.img_z = xx, zz
        m = setup.margin_mm
        if setup.sector_half_angle_deg is None:
            self.sector = False
            self.bf_x, self.bf_z = xx, zz
            self.x_lim = (x0 - m, x1 + m)
            self.z_lim = (max(z0 - m, 0.5), z1 + m)
            self.valid = np.ones(xx.shape, bool)
        else:
            self.sector = True
            self.half = np.deg2rad(setup.sector_half_angle_deg)
            self.r_lim = (1.0, z1)
            dr = wavelength_mm / 4
            self.r = np.arange(self.r_lim[0], self.r_lim[1] + m + dr, dr)
            dth = np.deg2rad(setup.polar_step_deg)
            n_th = int(np.ceil((self.half + np.deg2rad(1.0)) / dth))
            self.th = dth * np.arange(-n_th, n_th + 1)
            rr, tt = np.meshgrid(self.r, self.th, indexing="ij")
            self.bf_x, self.bf_z = rr * np.sin(tt), rr * np.cos(tt)
            r_img = np.hypot(xx, zz)
            th_img = np.arctan2(xx, zz)
            self.valid = (r_img >= self.r_lim[0]) & (r_img <= self.r_lim[1]) & (
                np.abs(th_img) <= self.half)
            self._map = np.stack([(r_img - self.r[0]) / dr, (th_img - self.th[0]) / dth])
            self.sim_r = (0.5, self.r_lim[1] + m)
            # the lateral margin as an angle at 20 mm depth, and one degree more
            self.sim_th = self.half + m / 20.0 + np.deg2rad(1.0)

    def inside(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Points (mm) inside the simulated domain."""
        if not self.sector:
            return ((x >= self.x_lim[0]) & (x <= self.x_lim[1]) & (z >= self.z_lim[0])
                    & (z <= self.z_lim[1]))
        r, th = np.hypot(x, z), np.arctan2(x, z)
        return (r >= self.sim_r[0]) & (r <= self.sim_r[1]) & (np.abs(th) <= self.sim_th)

    def in_image(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Points (mm) inside the displayed image (the sector, for sector probes)."""
        x0, x1 = self.setup.x_range_mm
        z0, z1 = self.setup.z_range_mm
        ok = (x >= x0) & (x <= x1) & (z >= z0) & (z <= z1)
        if self.sector:
            r, th = np.hypot(x, z), np.arctan2(x, z)
            ok &= (r >= self.r_lim[0]) & (r <= self.r_lim[1]) & (np.abs(th) <= self.half)
        return ok

    def bounding_box(self) -> tuple[tuple[float, float], tuple[float, float], float]:
        """Box holding the domain, and the domain's area (mm^2)."""
        if not self.sector:
            (a, b), (c, d) = self.x_lim, self.z_lim
            return (a, b), (c, d), (b - a) * (d - c)
        r0, r1 = self.sim_r
        xm = r1 * np.sin(self.sim_th)
        area = self.sim_th * (r1 ** 2 - r0 ** 2)
        return (-xm, xm), (r0 * np.cos(self.sim_th), r1), area

    def far_corners(self) -> np.ndarray:
        """Two points (mm) whose distance to the array bounds every domain point's."""
        if not self.sector:
            return np.array([[self.x_lim[0], self.z_lim[1]], [self.x_lim[1], self.z_lim[1]]])
        r1, th = self.sim_r[1], self.sim_th
        return np.array([[-r1 * np.sin(th), r1 * np.cos(th)], [r1 * np.sin(th), r1 * np.cos(th)]])

    def to_image(self, env_bf: np.ndarray) -> np.ndarray:
        """Beamformed envelope -> envelope on the output grid (0 outside a sector)."""
        if not self.sector:
            return env_bf
        out = ndimage.map_coordinates(env_bf, self._map, order=1, mode="constant", cval=0.0)
        return np.where(self.valid, out, 0.0)

    def beam_axis(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Unit vectors (N, 2) along the beams through the points (depth, or radial)."""
        if not self.sector:
            return np.tile([0.0, 1.0], (len(x), 1))
        r = np.maximum(np.hypot(x, z), 1e-9)
        return np.stack([x / r, z / r], axis=1)


# -- scatterers -------------------------------------------------------------------------------

def _smooth_field(rng: np.random.Generator, box, corr_mm: float, sd: float):
    """A smooth Gaussian log-echogenicity field, returned as a function of (x, z) in mm."""
    (x0, x1), (z0, z1) = box
    step = corr_mm / 2
    nx, nz = int((x1 - x0) / step) + 3, int((z1 - z0) / step) + 3
    g = ndimage.gaussian_filter(rng.standard_normal((nz, nx)), sigma=1.0)
    g *= sd / max(g.std(), 1e-12)

    def field(x, z):
        c = np.stack([(z - z0) / step + 1, (x - x0) / step + 1])
        return ndimage.map_coordinates(g, c, order=1, mode="nearest")

    return field


def _line_distance(x, z, line):
    """Signed distance (mm) of points to a line (x0, z0, slope_deg); positive is deeper."""
    x0, z0, slope = line
    t = np.deg2rad(slope)
    return -(x - x0) * np.sin(t) + (z - z0) * np.cos(t)


def _tissue(spec: SequenceSpec, dom: _Domain, density_mm2: float, rng: np.random.Generator):
    """Tissue scatterers (x, z mm) and Gaussian amplitudes shaped by the echogenicity map."""
    box_x, box_z, area = dom.bounding_box()
    box_area = (box_x[1] - box_x[0]) * (box_z[1] - box_z[0])
    n_box = rng.poisson(density_mm2 * box_area)
    x = rng.uniform(*box_x, n_box)
    z = rng.uniform(*box_z, n_box)
    keep = dom.inside(x, z)
    x, z = x[keep], z[keep]
    log_e = _smooth_field(rng, (box_x, box_z), 4.0, spec.inhomogeneity)(x, z)
    amp = np.exp(log_e)
    if spec.interface is not None:  # the tissue layer that carries the interface is brighter
        d = _line_distance(x, z, spec.interface)
        amp *= np.where(np.abs(d) < 0.6, 1.5, 1.0)
    if spec.vessel is not None:
        vx, vz, vr = spec.vessel
        rv = np.hypot(x - vx, z - vz)
        amp *= np.where(rv < vr, 0.03, np.where(rv < vr + 0.4, 1.8, 1.0))
    return x, z, amp * rng.standard_normal(len(x))


def _line_points(p0, p1, spacing_mm):
    """Points every ``spacing_mm`` from p0 to p1 (excluding p1)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    n = int(np.ceil(np.linalg.norm(p1 - p0) / spacing_mm))
    if n <= 0:
        return np.zeros((0, 2))
    return p0 + (p1 - p0) * (np.arange(n) / n)[:, None]


class _Needle:
    """A straight needle from the skin point ``entry`` along ``d``; lengths s from the entry."""

    def __init__(self, spec: SequenceSpec):
        a = np.deg2rad(spec.angle_deg)
        sx = 1.0 if spec.side == "left" else -1.0
        self.entry = np.array([spec.entry_x_mm, 0.0])
        self.d = np.array([sx * np.cos(a), np.sin(a)])
        n = np.array([-self.d[1], self.d[0]])
        self.n_up = n if n[1] < 0 else -n  # the wall normal towards the probe
        self.r = 0.5 * synth.GAUGE_OUTER_DIAMETER_MM[spec.gauge]
        self.lengths = spec.start_mm + spec.step_mm * np.arange(spec.n_frames)

    def axis(self, s):
        return self.entry + np.asarray(s, float)[..., None] * self.d


def _needle_piece(spec, needle: _Needle, dom: _Domain, s0, s1, spacing, rng):
    """Shaft scatterers gained between inserted lengths s0 and s1: the upper wall over (s0, s1],
    the lower wall over (s0 - b, s1 - b] (b: the bevel length) and their reverberation copies
    along the beam."""
    b = spec.bevel_length_mm
    pts = [_line_points(needle.axis(s0) + needle.r * needle.n_up,
                        needle.axis(s1) + needle.r * needle.n_up, spacing),
           _line_points(needle.axis(s0 - b) - needle.r * needle.n_up,
                        needle.axis(s1 - b) - needle.r * needle.n_up, spacing)]
    p = np.concatenate(pts)
    amp = 1.0 + spec.roughness * rng.standard_normal(len(p))
    # the echo that rings inside the needle repeats one diameter (along the beam) further down
    beam = dom.beam_axis(p[:, 0], p[:, 1])
    cos_i = np.abs(beam @ needle.n_up)
    gap = 2 * needle.r / np.maximum(cos_i, 0.2)
    all_p, all_a = [p], [amp]
    for k in range(1, spec.n_reverb + 1):
        all_p.append(p + (k * gap)[:, None] * beam)
        all_a.append(amp * spec.reverb_gain ** k)
    p, amp = np.concatenate(all_p), np.concatenate(all_a)
    keep = dom.inside(p[:, 0], p[:, 1])
    return p[keep], amp[keep]


def _bevel(spec, needle: _Needle, dom: _Domain, s_tip, spacing, rng):
    """The bevel face at the tip, from the lower wall at s_tip - b to the upper wall at s_tip: a
    rough cut, so its scatterers' amplitudes are random (no equal-phase part)."""
    p = _line_points(needle.axis(s_tip - spec.bevel_length_mm) - needle.r * needle.n_up,
                     needle.axis(s_tip) + needle.r * needle.n_up, spacing)
    amp = spec.bevel_gain * spec.roughness * rng.standard_normal(len(p))
    keep = dom.inside(p[:, 0], p[:, 1])
    return p[keep], amp[keep]


def _interface_line(spec, dom: _Domain, spacing, rng):
    """A specular interface: dense equal-phase scatterers along the spec's line."""
    x0, z0, slope = spec.interface
    t = np.deg2rad(slope)
    u = np.array([np.cos(t), np.sin(t)])
    span = 200.0
    p = _line_points(np.array([x0, z0]) - span * u, np.array([x0, z0]) + span * u, spacing)
    p = p[dom.inside(p[:, 0], p[:, 1])]
    return p, 1.0 + spec.roughness * rng.standard_normal(len(p))


# -- simulation and beamforming ---------------------------------------------------------------

class _Scanner:
    """simus + rf2iq + dasmtx for one probe; every call shares one frequency grid."""

    def __init__(self, setup: ProbeSetup, dom: _Domain):
        import pymust

        self.pm = pymust
        self.setup, self.dom = setup, dom
        p = pymust.getparam(setup.model)
        p.fs = 4 * p.fc
        p.attenuation = setup.attenuation_db_cm_mhz
        p.fnumber = None  # dasmtx: the f-number from the elements' directivity
        self.param = p
        self.opt = pymust.utils.Options()
        self.opt.dBThresh = setup.db_thresh
        self.opt.ParPool = False
        self.opt.WaitBar = False
        if setup.element_splitting is not None:
            self.opt.ElementSplitting = setup.element_splitting
        self.delays = []
        for tilt in setup.tilts_deg:
            if setup.diverging_width_deg is None:
                d = pymust.txdelay(p, np.deg2rad(tilt))
            else:
                d = pymust.txdelay(p, np.deg2rad(tilt), np.deg2rad(setup.diverging_width_deg))
            self.delays.append(np.asarray(d, float).reshape(1, -1))
        self.corners = dom.far_corners() * 1e-3
        self.seconds = 0.0
        self.calls = 0
        self._das = {}

    def rf(self, k: int, pts_mm: np.ndarray, amp: np.ndarray, chunk: int = 20000) -> np.ndarray:
        """RF (n_t, n_elements) of scatterers ``pts_mm`` (N, 2) for transmit k."""
        out = None
        n = max(len(pts_mm), 1)
        for i in range(0, n, chunk):
            p = pts_mm[i:i + chunk] * 1e-3
            a = amp[i:i + chunk]
            x = np.concatenate([self.corners[:, 0], p[:, 0]])
            z = np.concatenate([self.corners[:, 1], p[:, 1]])
            rc = np.concatenate([np.zeros(2), a])
            self.param.TXdelay = self.delays[k]
            t = time.perf_counter()
            rf = self.pm.simus(x, z, rc, self.delays[k], self.param, self.opt)[0]
            self.seconds += time.perf_counter() - t
            self.calls += 1
            out = rf if out is None else out + rf
        return out

    def iq(self, rf: np.ndarray) -> np.ndarray:
        """RF (n_t, n_el, K) -> I/Q of the same shape (down-mixing and a fixed low-pass)."""
        p = self.param
        return self.pm.rf2iq(rf, p.fs, p.fc, p.bandwidth)

    def beamform(self, k: int, iq: np.ndarray) -> np.ndarray:
        """I/Q (n_t, n_el, K) of transmit k -> beamformed (n_pix, K), pixels in bf-grid order."""
        n_t, n_el, n_k = iq.shape
        key = (k, n_t)
        if key not in self._das:
            self._das = {}  # one transmit's matrix at a time
            self.param.TXdelay = self.delays[k]
            self._das[key] = self.pm.dasmtx(
                1j * np.array([n_t, n_el]), self.dom.bf_x * 1e-3, self.dom.bf_z * 1e-3,
                self.delays[k], self.param, "linear")
        cols = iq.transpose(1, 0, 2).reshape(n_el * n_t, n_k)  # each column in Fortran order
        return self._das[key] @ cols


def _cell_area_mm2(scanner: _Scanner, dom: _Domain) -> float:
    """Area (mm^2) of the -6 dB region of the compounded point-spread function at mid-depth."""
    setup = scanner.setup
    zc = 0.5 * sum(setup.z_range_mm)
    box = 6.0 if dom.sector else 3.0  # half-width of the window around the point (mm)
    s = 0.04 if dom.sector else 0.02  # its pixel (mm)
    zz, xx = np.meshgrid(np.arange(zc - box, zc + box, s), np.arange(-box, box, s), indexing="ij")
    das = scanner.pm.dasmtx
    acc = 0.0
    for k in range(len(scanner.delays)):
        rf = scanner.rf(k, np.array([[0.0, zc]]), np.ones(1))
        iq = scanner.iq(rf)
        scanner.param.TXdelay = scanner.delays[k]
        m = das(1j * np.array(iq.shape), xx * 1e-3, zz * 1e-3, scanner.delays[k], scanner.param,
                "linear")
        acc = acc + m @ iq.reshape(-1, order="F")
    env = np.abs(acc)
    return float(np.count_nonzero(env >= 0.5 * env.max()) * s * s)


def _simulate(spec: SequenceSpec, log, scatterers_per_cell: float | None = None) -> dict:
    """All beamformed components of a sequence (compounded I/Q on the bf grid)."""
    setup = PROBES[spec.probe]
    if scatterers_per_cell is not None:
        setup = replace(setup, scatterers_per_cell=scatterers_per_cell)
    import pymust

    lam_mm = _C / pymust.getparam(setup.model).fc * 1e3
    dom = _Domain(setup, lam_mm)
    sc = _Scanner(setup, dom)
    rng = np.random.default_rng(spec.seed)
    cell = _cell_area_mm2(sc, dom)
    density = setup.scatterers_per_cell / cell
    tx, tz, ta = _tissue(spec, dom, density, rng)
    log(f"{spec.name}: cell {cell:.4f} mm2, {density:.0f} scatterers/mm2, {len(tx)} tissue "
        "scatterers")
    spacing = lam_mm / 8
    comps: list[tuple[str, np.ndarray, np.ndarray]] = [("tissue", np.stack([tx, tz], 1), ta)]
    if spec.interface is not None:
        comps.append(("interface", *_interface_line(spec, dom, spacing, rng)))
    needle = _Needle(spec) if spec.needle else None
    if needle is not None:
        # piece i: the shaft gained up to frame i (piece 0 from the skin line)
        bounds = np.concatenate([[0.0], needle.lengths])
        for i in range(spec.n_frames):
            comps.append((f"piece{i}", *_needle_piece(spec, needle, dom, bounds[i],
                                                      bounds[i + 1], spacing, rng)))
        for i, s in enumerate(needle.lengths):
            comps.append((f"bevel{i}", *_bevel(spec, needle, dom, s, spacing, rng)))
    n_needle_sc = sum(len(c[1]) for c in comps if c[0].startswith(("piece", "bevel")))
    log(f"{spec.name}: {n_needle_sc} needle scatterers, {len(comps)} components")
    names = [c[0] for c in comps]
    bf = None
    noise_bf = None
    for k in range(len(sc.delays)):
        t0 = time.perf_counter()
        rfs = [sc.rf(k, p, a) if len(p) else None for _, p, a in comps]
        shape = next(r.shape for r in rfs if r is not None)
        rfs = [np.zeros(shape) if r is None else r for r in rfs]
        tissue_rms = float(np.sqrt(np.mean(rfs[0] ** 2)))
        noise = rng.standard_normal((*shape, spec.n_frames)) * tissue_rms * 10 ** (
            -spec.snr_db / 20)
        stack = np.concatenate([np.stack(rfs, axis=2), noise], axis=2)
        out = sc.beamform(k, sc.iq(stack))
        part, npart = out[:, :len(comps)], out[:, len(comps):]
        bf = part if bf is None else bf + part
        noise_bf = npart if noise_bf is None else noise_bf + npart
        log(f"{spec.name}: transmit {k + 1}/{len(sc.delays)} in {time.perf_counter() - t0:.0f} s"
            f" (simus {sc.seconds:.0f} s over {sc.calls} calls)")
    shape = dom.bf_x.shape
    comp = {n: bf[:, i].reshape(shape, order="F") for i, n in enumerate(names)}
    noise_frames = [noise_bf[:, t].reshape(shape, order="F") for t in range(spec.n_frames)]
    return dict(dom=dom, needle=needle, comp=comp, noise=noise_frames, cell=cell,
                density=density, n_tissue=len(tx), n_needle=n_needle_sc, simus_s=sc.seconds,
                simus_calls=sc.calls, wavelength_mm=lam_mm, param=sc.param)


# -- display and labels ------------------------------------------------------------------------

def _grey(env: np.ndarray, white_db: float, spec: SequenceSpec) -> np.ndarray:
    db = 20 * np.log10(np.maximum(env, 1e-30)) - white_db
    u = np.clip((db + spec.dynamic_range_db) / spec.dynamic_range_db, 0.0, 1.0) ** spec.gamma
    return np.round(255 * u).astype(np.uint8)


def _bisect(f, lo, hi, target, n=30):
    """The smallest x in [lo, hi] with f(x) = target (log-spaced search): f is scanned on a
    coarse grid for its first crossing, which is then bisected; where f never reaches the
    target, the x of its largest value."""
    xs = np.geomspace(lo, hi, 33)
    fs = np.array([f(x) for x in xs])
    above = np.flatnonzero(fs >= target)
    if len(above) == 0:  # out of reach: the first x within 95% of the largest value
        return float(xs[np.flatnonzero(fs >= 0.95 * np.nanmax(fs))[0]])
    if above[0] == 0:
        return float(xs[0])
    a, b = np.log(xs[above[0] - 1]), np.log(xs[above[0]])
    for _ in range(n):
        m = 0.5 * (a + b)
        if f(np.exp(m)) < target:
            a = m
        else:
            b = m
    return float(np.exp(0.5 * (a + b)))


def _near(grid, pts: np.ndarray, radius_mm: float) -> np.ndarray:
    """Flat indices of the pixels within ``radius_mm`` of a polyline."""
    return synth.tube_indices(grid, pts, radius_mm)


def _local_contrast(image: np.ndarray, without: np.ndarray, idx: np.ndarray) -> float:
    """Mean grey over ``idx`` of ``image`` over that of the same frame without the object.

    ``idx`` holds the pixels within CONTRAST_RADIUS_MM of the surface that faces the probe (the
    needle's upper wall, the interface line), over the part in view.
    """
    bg = without.reshape(-1)[idx].astype(float).mean()
    return float(image.reshape(-1)[idx].astype(float).mean() / max(bg, 1e-9))


def _compose(sim: dict, spec: SequenceSpec):
    """Frames, labels and the achieved contrast of a simulated sequence."""
    dom, comp, needle = sim["dom"], sim["comp"], sim["needle"]
    grid = synth.Grid((dom.nz, dom.nx), tuple(dom.spacing_mm), tuple(dom.origin_mm))
    T = spec.n_frames
    # TGC: a fixed gain per depth (per radius for sectors) that flattens the tissue's median
    tissue_env = np.abs(comp["tissue"])
    prof = np.median(tissue_env, axis=1)
    step = np.diff(dom.bf_z[:, 0])[0] if not dom.sector else dom.r[1] - dom.r[0]
    prof = ndimage.gaussian_filter1d(prof, sigma=1.0 / step, mode="nearest")
    gain = (1.0 / np.maximum(prof, prof.max() * 1e-6))[:, None]

    def env_image(iq):
        return dom.to_image(np.abs(iq) * gain)

    valid = dom.valid
    base = comp["tissue"] + sim["noise"][0]
    base_env = env_image(base)

    def mean_grey(white_db):
        return float(_grey(base_env, white_db, spec)[valid].mean())

    ref = 20 * np.log10(np.percentile(base_env[valid], 50))
    # the display gain: tissue mean grey as the spec asks (mean grey falls as white rises)
    lo, hi = ref - 10.0, ref + spec.dynamic_range_db + 30.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if mean_grey(mid) > spec.tissue_grey:
            lo = mid
        else:
            hi = mid
    white = 0.5 * (lo + hi)

    iface_scale = 0.0
    if spec.interface is not None:
        x0, z0, slope = spec.interface
        t = np.deg2rad(slope)
        u = np.array([np.cos(t), np.sin(t)])
        line = np.array([x0, z0]) + np.arange(-200, 200, 0.05)[:, None] * u
        line = line[dom.in_image(line[:, 0], line[:, 1])]

        near_line = _near(grid, line, CONTRAST_RADIUS_MM)

        def iface_cr(scale):
            im = _grey(env_image(base + scale * comp["interface"]), white, spec)
            return _local_contrast(im, base_im, near_line)

        base_im = _grey(base_env, white, spec)
        iface_scale = _bisect(iface_cr, 1e-4, 1e4, spec.interface_cr)
        base = base + iface_scale * comp["interface"]

    pieces = np.zeros((T, *base.shape), complex)
    needle_scale = 0.0
    if needle is not None:
        acc = np.zeros(base.shape, complex)
        for i in range(T):
            acc = acc + comp[f"piece{i}"]
            pieces[i] = acc + comp[f"bevel{i}"]

    def shaft_pts(i, offset_mm=0.0):
        s = np.arange(0.0, needle.lengths[i], 0.05)
        p = needle.axis(s) + offset_mm * needle.n_up
        return p[dom.in_image(p[:, 0], p[:, 1])]

    def wall_near(i):
        return _near(grid, shaft_pts(i, needle.r), CONTRAST_RADIUS_MM)

    if needle is not None:
        last = base - sim["noise"][0] + sim["noise"][T - 1]

        last_im = _grey(env_image(last), white, spec)
        near_last = wall_near(T - 1)

        def needle_cr(scale):
            im = _grey(env_image(last + scale * pieces[T - 1]), white, spec)
            return _local_contrast(im, last_im, near_last)

        needle_scale = _bisect(needle_cr, 1e-4, 1e4, spec.target_cr)

    images = np.zeros((T, dom.nz, dom.nx), np.uint8)
    tip = np.full((T, 2), np.nan)
    direction = np.full((T, 2), np.nan)
    entry = np.zeros((T, 2))
    visible = np.zeros(T, bool)
    cr = np.full(T, np.nan)
    local = np.full(T, np.nan)
    centerline = np.zeros((T, 32, 2))
    shaft_in_view = np.zeros(T)
    static = base - sim["noise"][0]
    for i in range(T):
        bare = static + sim["noise"][i]
        images[i] = _grey(env_image(bare + needle_scale * pieces[i]), white, spec)
        if needle is None:
            continue
        s = needle.lengths[i]
        tip[i] = needle.axis(s)
        direction[i] = needle.d
        entry[i] = needle.entry
        centerline[i] = needle.axis(np.linspace(0.0, s, 32))
        pts = shaft_pts(i)
        shaft_in_view[i] = 0.05 * len(pts)
        visible[i] = bool(dom.in_image(*tip[i])) and shaft_in_view[i] >= 3.0
        cr[i] = synth.contrast_ratio(images[i], grid, pts, needle.r, valid=valid)
        local[i] = _local_contrast(images[i], _grey(env_image(bare), white, spec), wall_near(i))
    return dict(images=images, tip=tip, direction=direction, entry=entry, visible=visible,
                cr=cr, local=local, centerline=centerline, white_db=white,
                needle_scale=needle_scale, interface_scale=iface_scale, grid=grid,
                shaft_in_view=shaft_in_view)


def generate(spec: SequenceSpec, out_dir: Path, log=print,
             scatterers_per_cell: float | None = None) -> Path:
    """Simulate one sequence and write ``out_dir/NAME.npz``."""
    t0 = time.perf_counter()
    sim = _simulate(spec, log, scatterers_per_cell)
    res = _compose(sim, spec)
    setup = PROBES[spec.probe]
    dom = sim["dom"]
    spec_d = asdict(spec)
    meta = {
        "source": "pymust",
        "pymust_version": _version("pymust"),
        "scenario": spec.name,
        "seed": spec.seed,
        "needle": spec.needle,
        "probe": spec.probe,
        "probe_setup": asdict(setup),
        "spec": spec_d,
        "gauge": spec.gauge if spec.needle else None,
        "needle_radius_mm": sim["needle"].r if spec.needle else None,
        "side": spec.side if spec.needle else None,
        "angle_deg": spec.angle_deg if spec.needle else None,
        "target_cr": spec.target_cr if spec.needle else None,
        "needle_tissue_contrast": ([round(float(v), 3) for v in res["local"]]
                                   if spec.needle else None),
        "contrast_ratio_eq9": "per-frame key contrast_ratio: Zhao 2013 eq. 9 (synth)",
        "feature": spec.feature,
        "sector": ({"apex_mm": [0.0, 0.0], "half_angle_deg": setup.sector_half_angle_deg,
                    "r_mm": list(dom.r_lim)} if dom.sector else None),
        "resolution_cell_mm2": sim["cell"],
        "scatterers_per_mm2": sim["density"],
        "n_tissue_scatterers": sim["n_tissue"],
        "n_needle_scatterers": sim["n_needle"],
        "wavelength_mm": sim["wavelength_mm"],
        "fc_hz": float(sim["param"].fc),
        "fs_hz": float(sim["param"].fs),
        "display_white_db": res["white_db"],
        "needle_scale": res["needle_scale"],
        "interface_scale": res["interface_scale"],
        "shaft_in_view_mm": [round(float(v), 2) for v in res["shaft_in_view"]],
        "simus_s": round(sim["simus_s"], 1),
        "simus_calls": sim["simus_calls"],
        "generation_s": round(time.perf_counter() - t0, 1),
        "centerline_frame": "image (x, z) mm, from the skin crossing to the tip",
        "command": f"python -m needlenet.bench.external.generate --out DIR --only {spec.name}",
    }
    T = spec.n_frames
    kw = dict(images=res["images"], spacing_mm=dom.spacing_mm, origin_mm=dom.origin_mm,
              modality="inplane", timestamps_s=np.arange(T) / spec.frame_rate_hz,
              dynamic_range_db=float(spec.dynamic_range_db), meta=meta,
              tip_mm=res["tip"], direction=res["direction"], visible=res["visible"],
              contrast_ratio=res["cr"])
    if spec.needle:
        kw.update(entry_mm=res["entry"], centerline_mm=res["centerline"])
    seq = synth.Sequence(**kw)
    out = synth.save_sequence(seq, Path(out_dir) / f"{spec.name}.npz", overwrite=True)
    log(f"{spec.name}: wrote {out} in {time.perf_counter() - t0:.0f} s "
        f"(simus {sim['simus_s']:.0f} s); needle contrast {res['local'][-1]:.2f}, "
        f"Zhao CR {res['cr'][-1]:.2f}")
    return out


def _version(pkg: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(pkg)
    except PackageNotFoundError:
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m needlenet.bench.external.generate",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path, help="directory for the .npz files")
    ap.add_argument("--only", nargs="+", metavar="NAME", help="generate these sequences only")
    ap.add_argument("--frames", type=int, help="override the frame count (quick looks only)")
    ap.add_argument("--scatterers-per-cell", type=float,
                    help="override the speckle density (quick looks only)")
    args = ap.parse_args(argv)
    try:
        import pymust  # noqa: F401
    except ImportError:
        print("the generator needs PyMUST: pip install 'needlenet[external]'", file=sys.stderr)
        return 2
    names = {s.name for s in SPECS}
    if args.only:
        unknown = sorted(set(args.only) - names)
        if unknown:
            ap.error(f"unknown sequence(s) {unknown}; known: {sorted(names)}")
    args.out.mkdir(parents=True, exist_ok=True)
    specs = [s for s in SPECS if not args.only or s.name in args.only]
    t0 = time.perf_counter()
    for spec in specs:
        if args.frames:
            spec = replace(spec, n_frames=args.frames)
        generate(spec, args.out, log=lambda m: print(m, flush=True),
                 scatterers_per_cell=args.scatterers_per_cell)
    print(f"done: {len(specs)} sequences in {time.perf_counter() - t0:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
