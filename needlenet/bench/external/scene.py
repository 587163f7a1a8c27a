"""The scatterer scene of an external sequence: the simulated domain and its image grid, the
tissue, and the needle and interface reflectors (positions and amplitudes for PyMUST)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

import synth

from .specs import ProbeSetup, SequenceSpec

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

