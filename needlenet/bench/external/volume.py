"""The scatterer scene of an external volume sequence: the needle's 3-D axis, walls, bevel and
the tissue it hollows and shadows; the tissue cloud cut into elevation layers per depth band;
the elevation weights that turn 3-D scatterers into each slice's 2-D scene.

A slice sees a scatterer at elevation y with the two-way elevation profile w(y - y_k), a
Gaussian of the probe's elevation FWHM at the scatterer's depth (``elevation_fwhm_mm``; range
for a sector), cut where it falls below exp(-2). simus is 2-D and linear in the amplitudes, so:

- tissue: the cloud is cut into depth bands (``band_mm``), each with the FWHM at its centre,
  and each band into layers sigma / 2 thick along y; a layer is simulated once and slice k is
  the sum of the layers weighted by w at their centres. Neighbouring slices share the layers
  their beams overlap, so the speckle decorrelates along y by the physical amount. The density
  is set per band so that a slice holds ``scatterers_per_cell`` per resolution cell counted
  with the weights (rho_3 * sigma * sqrt(pi) per mm^2), as in the axial set;
- the needle: its points (walls, reverberations, bevel) are projected onto each slice's plane
  with their own weight w(y - y_k), so a shaft crossing the slices obliquely appears in each
  over the length the elevation beam holds, fading towards its edges;
- the lumen and the acoustic shadow are changes of tissue scatterers (amplitude removed, or
  scaled to ``shadow``), simulated with the weights of the layers those scatterers belong to,
  so they cancel the same scatterers' echoes exactly.

The needle's wall is a line of dense equal-phase scatterers (lambda / 8 apart, rough
amplitudes) one radius from the axis towards the probe, the far wall one radius away from it
(weaker, missing within the bevel's length of the tip), reverberation copies of both one
diameter apart along the beam, and a rough bevel from the far wall to the tip. The needle
advances between volumes: the piece of shaft it gains, and the tissue that piece hollows and
shadows, are separate components, so volume t sums the pieces up to t.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

import synth

from .scene import _Domain, _line_distance
from .volume_specs import VolumeProbe, VolumeSpec, elevation_fwhm_mm, needle_direction

__all__ = ["ElevationBand", "VolumeNeedle", "elevation_bands", "elevation_weights",
           "in_view", "smooth_field_3d", "tissue_band"]

_FWHM_TO_SIGMA = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))
_CUT = 2.0  # weights below exp(-_CUT), i.e. beyond 2 sigma, are dropped


def _depth(dom: _Domain, x, z):
    """The depth the elevation lens acts over: z for a linear array, the range for a sector."""
    return np.hypot(x, z) if dom.sector else np.asarray(z, float)


def _beam(dom: _Domain, p: np.ndarray) -> np.ndarray:
    """Unit vectors (N, 3) along the beam through points (N, 3), in each point's slice plane."""
    b2 = dom.beam_axis(p[:, 0], p[:, 2])
    return np.stack([b2[:, 0], np.zeros(len(p)), b2[:, 1]], 1)


@dataclass(frozen=True)
class ElevationBand:
    """The tissue of one depth band: its depth range (mm, range for a sector), its elevation
    sigma, the centres (L,) of its layers along y, their thickness, and the weight (L, K) of
    layer j in slice k."""

    depth_mm: tuple[float, float]
    sigma_mm: float
    layer_y_mm: np.ndarray
    layer_mm: float
    weights: np.ndarray


def elevation_bands(vp: VolumeProbe, dom: _Domain, wavelength_mm: float) -> list[ElevationBand]:
    """Bands ``vp.band_mm`` deep over the simulated domain's depths, each cut into layers
    sigma / 2 thick covering the slices' y range +- 2 sigma."""
    lo, hi = (dom.sim_r if dom.sector else dom.z_lim)
    edges = np.append(np.arange(lo, hi, vp.band_mm), hi)
    y = vp.slice_y_mm
    out = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        sigma = float(elevation_fwhm_mm(vp, 0.5 * (a + b), wavelength_mm)) * _FWHM_TO_SIGMA
        dy = sigma / 2
        y0, y1 = y[0] - _CUT * sigma, y[-1] + _CUT * sigma
        n = int(np.ceil((y1 - y0) / dy))
        yc = y0 + dy * (np.arange(n) + 0.5)
        w = np.exp(-0.5 * ((yc[:, None] - y[None]) / sigma) ** 2)
        w[w < np.exp(-_CUT)] = 0.0
        out.append(ElevationBand((float(a), float(b)), sigma, yc, dy, w))
    return out


def elevation_weights(vp: VolumeProbe, dom: _Domain, p: np.ndarray,
                      wavelength_mm: float) -> np.ndarray:
    """Weights (N, K) of points (N, 3) in every slice, each with the elevation sigma at its
    own depth; 0 below exp(-2)."""
    sigma = elevation_fwhm_mm(vp, _depth(dom, p[:, 0], p[:, 2]), wavelength_mm) * _FWHM_TO_SIGMA
    w = np.exp(-0.5 * ((p[:, 1:2] - vp.slice_y_mm[None]) / sigma[:, None]) ** 2)
    w[w < np.exp(-_CUT)] = 0.0
    return w


def smooth_field_3d(rng: np.random.Generator, box, corr_mm: float, sd: float):
    """A smooth Gaussian log-echogenicity field over ``box`` ((x0, x1), (y0, y1), (z0, z1)),
    returned as a function of points (N, 3)."""
    step = corr_mm / 2
    lo = np.array([b[0] for b in box])
    n = [int((b[1] - b[0]) / step) + 3 for b in box]
    g = ndimage.gaussian_filter(rng.standard_normal(n), sigma=1.0)
    g *= sd / max(g.std(), 1e-12)

    def field(p):
        c = ((np.asarray(p, float) - lo) / step + 1).T
        return ndimage.map_coordinates(g, c, order=1, mode="nearest")

    return field


def _vessel_distance(p: np.ndarray, vessel) -> np.ndarray:
    """Distance (mm) of points (N, 3) to the axis of a level tube (x, y, z, azimuth, r)."""
    x, y, z, az, _ = vessel
    v = np.array([np.cos(np.deg2rad(az)), np.sin(np.deg2rad(az)), 0.0])
    d = p - np.array([x, y, z])
    return np.linalg.norm(d - (d @ v)[:, None] * v, axis=1)


def tissue_band(spec: VolumeSpec, dom: _Domain, band: ElevationBand, density_mm3: float,
                field, rng: np.random.Generator):
    """Scatterers of one band: points (N, 3), Gaussian amplitudes (N,) shaped by the
    echogenicity ``field``, an interface's brighter band and a vessel's anechoic lumen and
    bright wall, and the layer (N,) each belongs to."""
    box_x, box_z, _ = dom.bounding_box()
    a, b = band.depth_mm
    z_lo = max(box_z[0], a * np.cos(dom.sim_th)) if dom.sector else a
    z_hi = min(box_z[1], b)
    y0 = band.layer_y_mm[0] - band.layer_mm / 2
    y1 = band.layer_y_mm[-1] + band.layer_mm / 2
    n = rng.poisson(density_mm3 * (box_x[1] - box_x[0]) * (z_hi - z_lo) * (y1 - y0))
    p = np.stack([rng.uniform(*box_x, n), rng.uniform(y0, y1, n), rng.uniform(z_lo, z_hi, n)], 1)
    d = _depth(dom, p[:, 0], p[:, 2])
    keep = dom.inside(p[:, 0], p[:, 2]) & (d >= a) & (d < b)
    p = p[keep]
    amp = np.exp(field(p))
    if spec.interface is not None:
        amp *= np.where(np.abs(_line_distance(p[:, 0], p[:, 2], spec.interface)) < 0.6, 1.5, 1.0)
    if spec.vessel is not None:
        rv, r = _vessel_distance(p, spec.vessel), spec.vessel[4]
        amp *= np.where(rv < r, 0.03, np.where(rv < r + 0.4, 1.8, 1.0))
    layer = np.minimum(((p[:, 1] - y0) / band.layer_mm).astype(int), len(band.layer_y_mm) - 1)
    return p, amp * rng.standard_normal(len(p)), layer


def in_view(vp: VolumeProbe, dom: _Domain, p: np.ndarray) -> np.ndarray:
    """Points (N, 3) inside the displayed volume: within the voxels' extent and, for a sector
    probe, inside the sector."""
    h = 0.5 * vp.voxel_mm
    y = vp.slice_y_mm
    ok = ((p[:, 0] >= vp.x_mm[0] - h) & (p[:, 0] <= vp.x_mm[1] + h)
          & (p[:, 2] >= vp.z_mm[0] - h) & (p[:, 2] <= vp.z_mm[1] + h)
          & (p[:, 1] >= y[0] - h) & (p[:, 1] <= y[-1] + h))
    if dom.sector:
        r, th = np.hypot(p[:, 0], p[:, 2]), np.arctan2(p[:, 0], p[:, 2])
        ok &= (r >= dom.r_lim[0]) & (r <= dom.r_lim[1]) & (np.abs(th) <= dom.half)
    return ok


class VolumeNeedle:
    """The straight needle of a spec: arc length s along the axis from the last volume's tip
    (s = 0 there, negative along the shaft); volume t's tip at s_t = -(T - 1 - t) step."""

    def __init__(self, spec: VolumeSpec, vp: VolumeProbe, dom: _Domain, ds_mm: float = 0.01):
        self.spec, self.vp, self.dom = spec, vp, dom
        self.u = needle_direction(spec.alpha_deg, spec.beta_deg)
        self.tip_last = np.asarray(spec.tip_mm, float)
        self.r = 0.5 * synth.GAUGE_OUTER_DIAMETER_MM[spec.gauge]
        T = spec.n_volumes
        self.s_tips = -spec.step_mm * (T - 1 - np.arange(T, dtype=float))
        # the shaft runs back until it has left the simulated domain by a margin
        box_x, box_z, _ = dom.bounding_box()
        span = np.hypot(np.hypot(box_x[1] - box_x[0], box_z[1] - box_z[0]),
                        vp.n_slices * vp.slice_step_mm) + 10.0
        self.s_back = -span
        s = np.arange(self.s_back, self.s_tips[0] + ds_mm, ds_mm)
        inside = in_view(vp, dom, self.axis(s))
        if not inside.any():
            raise ValueError(f"{spec.name}: the needle's first tip lies outside the volume")
        self.s_entry = float(s[np.argmax(inside)])  # where the axis enters the volume

    def axis(self, s) -> np.ndarray:
        return self.tip_last + np.asarray(s, float)[:, None] * self.u

    @property
    def tips(self) -> np.ndarray:
        return self.axis(self.s_tips)

    @property
    def entry(self) -> np.ndarray:
        return self.axis(np.array([self.s_entry]))[0]

    def centreline(self, t: int, n: int = 64) -> np.ndarray:
        """n points (n, 3) from where the axis enters the volume to volume t's tip."""
        return self.axis(np.linspace(self.s_entry, self.s_tips[t], n))

    def near_wall(self, t: int, ds_mm: float = 0.05) -> np.ndarray:
        """Points (N, 3) of the wall facing the probe, one radius from the axis, from where the
        axis enters the volume to volume t's tip."""
        a = self.axis(np.arange(self.s_entry, self.s_tips[t] + 1e-9, ds_mm))
        return a + self.r * self._up(a)[0]

    def _up(self, a: np.ndarray):
        """Unit normals (N, 3) to the axis towards the probe at axis points ``a``, and the
        beam directions there."""
        b = _beam(self.dom, a)
        n = -b + (b @ self.u)[:, None] * self.u
        return n / np.linalg.norm(n, axis=1, keepdims=True), b

    def walls(self, s0: float, s1: float, spacing: float, rng: np.random.Generator):
        """Scatterers (N, 3) and amplitudes of the shaft gained from s0 to s1: the near wall
        over (s0, s1], the far wall over (s0 - b, s1 - b] (b: the bevel's length), and their
        reverberation copies along the beam. Points lie on one lattice of ``spacing`` along
        the axis, so pieces join into one even wall."""
        sp = self.spec
        s = spacing * np.arange(np.floor(s0 / spacing) + 1, np.floor(s1 / spacing) + 1)
        a_up = self.axis(s)
        a_lo = self.axis(s - sp.bevel_length_mm)
        n_up, _ = self._up(a_up)
        n_lo, _ = self._up(a_lo)
        p = np.concatenate([a_up + self.r * n_up, a_lo - self.r * n_lo])
        n = np.concatenate([n_up, n_lo])
        amp = 1.0 + sp.roughness * rng.standard_normal(len(p))
        amp[len(s):] *= sp.lower_wall_gain
        beam = _beam(self.dom, p)
        gap = 2 * self.r / np.maximum(np.abs(np.sum(beam * n, 1)), 0.2)
        parts, amps = [p], [amp]
        for k in range(1, sp.n_reverb + 1):  # the echo ringing in the lumen repeats
            parts.append(p + (k * gap)[:, None] * beam)
            amps.append(amp * sp.reverb_gain ** k)
        return np.concatenate(parts), np.concatenate(amps)

    def bevel(self, s_tip: float, spacing: float, rng: np.random.Generator):
        """The bevel face at a tip at s_tip: a rough line from the far wall at s_tip - b to
        the near wall at the tip (random amplitudes: no equal-phase part)."""
        sp = self.spec
        a = self.axis(np.array([s_tip - sp.bevel_length_mm, s_tip]))
        n, _ = self._up(a)
        p0, p1 = a[0] - self.r * n[0], a[1] + self.r * n[1]
        k = max(int(np.ceil(np.linalg.norm(p1 - p0) / spacing)), 2)
        p = p0 + (p1 - p0) * (np.arange(k) / k)[:, None]
        return p, sp.bevel_gain * sp.roughness * rng.standard_normal(len(p))

    def tissue_effect(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For tissue points (N, 3): the piece of shaft (index of the first volume whose needle
        reaches it; -1: none) that puts the point in the lumen or the shadow, and the factor
        its amplitude gains then (-1 in the lumen, -(1 - shadow) in the shadow). The shadow is
        the column behind the needle along the beam: the ray from the array to the point
        passes within a radius of the axis, in front of the point."""
        u, r = self.u, self.r
        rel = p - self.tip_last
        s_p = rel @ u
        lumen = np.linalg.norm(rel - s_p[:, None] * u, axis=1) < r
        if self.dom.sector:
            origin = np.stack([np.zeros(len(p)), p[:, 1], np.zeros(len(p))], 1)
            t_p = np.hypot(p[:, 0], p[:, 2])
        else:
            origin = np.stack([p[:, 0], p[:, 1], np.zeros(len(p))], 1)
            t_p = p[:, 2]
        b = _beam(self.dom, p)
        # the closest points of the ray (origin + t b) and the axis (tip_last + s u)
        w0 = origin - self.tip_last
        bu, d, e = b @ u, np.sum(b * w0, 1), w0 @ u
        den = np.maximum(1.0 - bu ** 2, 1e-9)
        t = (bu * e - d) / den
        s = (e - bu * d) / den
        dist = np.linalg.norm(w0 + t[:, None] * b - s[:, None] * u, axis=1)
        shadow = ~lumen & (dist < r) & (t < t_p)
        s_eff = np.where(lumen, s_p, s)
        piece = np.searchsorted(self.s_tips, s_eff, side="left")
        piece = np.where((lumen | shadow) & (piece < len(self.s_tips)), piece, -1)
        factor = np.where(lumen, -1.0, -(1.0 - self.spec.shadow))
        return piece, factor
