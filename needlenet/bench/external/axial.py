"""The scatterer scene of an external axial sequence: the needle's 3-D path and its crossings
with the slices, the cross-section's reflectors in one slice, and the tissue as a 3-D cloud
cut into layers along the stepping axis and weighted by the elevation beam.

Tissue. A 3-D cloud of Gaussian-amplitude scatterers sliced by the elevation beam: slice k
sees every scatterer with the amplitude weight w(y - y_k) of the two-way elevation profile (a
Gaussian of the probe's elevation FWHM at the needle's depth, ``elevation_fwhm_mm``). simus is
linear in the amplitudes, so the cloud is cut into layers of thickness sigma / 2 along y, each
layer is simulated once, and slice k is the sum of the layers weighted by w at their centres.
Neighbouring slices share scatterers as far as their beams overlap, so the speckle decorrelates
by the physical amount: by 0.75 mm on the L11-5v (elevation FWHM ~1.2 mm) and little on the
P4-2v (FWHM ~9 mm at 20 mm; its slices look alike from step to step, as a thick elevation
beam makes them). Independent scatterers per slice would decorrelate every step completely,
which no probe does. The density is set so that a slice holds ``scatterers_per_cell`` per
resolution cell counted with the weights (rho_3 * sigma * sqrt(pi) per mm^2).

Needle. The shaft crosses the slice plane at one point; its wall there is the slice's cut of
the cylinder (an ellipse of semi-axes r and r / cos(alpha), alpha the angle between shaft and
slice normal). The upper wall is an arc of dense equal-phase scatterers (lambda / 8 apart,
with random roughness) over the probe-facing part of that ellipse, so the wall reflects
specularly as a steel surface does; the far wall is a weaker arc behind the lumen, missing
within the bevel's length of the tip, where the bevel face crosses the lumen as a rough chord;
the echo that rings between the walls repeats one diameter further along the beam
(reverberation copies of the upper wall, each ``reverb_gain`` weaker). Tissue in the lumen is
removed and tissue behind the needle (within its radius of the beam through its centre) is
scaled by ``shadow`` (the steel reflects most of the energy: the acoustic shadow); the needle
stands still while the probe steps, so both are fixed properties of the cloud, set where each
scatterer's own y meets the shaft. The needle's
echo is that of its crossing with the slice's centre plane only; the elevation beam's
integration along the shaft near the crossing is left out, so the cross-section vanishes at
the tip rather than fading over the beam's width.
"""

from __future__ import annotations

import numpy as np

import synth

from .axial_specs import AxialSpec
from .scene import _Domain, _line_distance, _smooth_field

__all__ = ["AxialNeedle", "cross_section", "elevation_layers", "layer_tissue", "lumen_and_shadow",
           "tissue_field"]


class AxialNeedle:
    """The needle's 3-D path (world = probe frame of slice 0), sampled densely by arc length
    s from its crossing with slice 0 (s = 0)."""

    def __init__(self, spec: AxialSpec, ds_mm: float = 0.02):
        tx, tz = np.tan(np.deg2rad([spec.tilt_x_deg, spec.tilt_z_deg]))
        d = np.array([tx, 1.0, tz])
        self.d0 = d / np.linalg.norm(d)
        self.c0 = np.array([spec.centre_mm[0], 0.0, spec.centre_mm[1]])
        self.r = 0.5 * synth.GAUGE_OUTER_DIAMETER_MM[spec.gauge]
        b = np.deg2rad(spec.bend_deg)
        bend = np.array([np.cos(b), 0.0, np.sin(b)])
        bend = bend - (bend @ self.d0) * self.d0  # the bend normal to the shaft
        self.bend = bend / np.linalg.norm(bend)
        self.R = spec.radius_of_curvature_mm
        s = np.arange(-10.0, spec.tip_y_mm * 1.5 + 10.0, ds_mm)
        pts, tan = self._curve(s)
        # the tip: where the path reaches y = tip_y_mm (y grows with s: the shaft heads along +y)
        i = int(np.searchsorted(pts[:, 1], spec.tip_y_mm))
        self.s_tip = float(np.interp(spec.tip_y_mm, pts[:, 1], s))
        keep = np.arange(len(s)) < i
        self.s, self.pts, self.tan = s[keep], pts[keep], tan[keep]
        self.tip = self._curve(np.array([self.s_tip]))[0][0]

    def _curve(self, s: np.ndarray):
        """Points (N, 3) and unit tangents (N, 3) at arc lengths s (a circle of radius R in the
        plane of d0 and the bend; a line when R is None)."""
        s = np.asarray(s, float)[:, None]
        if self.R is None:
            return self.c0 + s * self.d0, np.repeat(self.d0[None], len(s), 0)
        a = s / self.R
        pts = self.c0 + self.R * np.sin(a) * self.d0 + self.R * (1 - np.cos(a)) * self.bend
        return pts, np.cos(a) * self.d0 + np.sin(a) * self.bend

    def crossing(self, y: float):
        """(centre (x, z), unit tangent (3,), arc length s) where the shaft crosses the plane
        y; None past the tip."""
        if y > self.tip[1]:
            return None
        s = float(np.interp(y, self.pts[:, 1], self.s))
        p, t = self._curve(np.array([s]))
        return p[0, [0, 2]], t[0], s

    def centreline(self, n: int = 64) -> np.ndarray:
        """n points (n, 3) from the path's start in view of slice 0's neighbourhood to the tip."""
        return self._curve(np.linspace(self.s[0], self.s_tip, n))[0]


def elevation_layers(spec: AxialSpec, fwhm_mm: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Layer centres (L,) along y, the weights (L, T) of layer j in slice k, and the layer
    thickness: layers sigma / 2 thick cover the slices' y range +- 2 sigma (weights below
    exp(-2) are dropped)."""
    sigma = fwhm_mm / (2 * np.sqrt(2 * np.log(2)))
    dy = sigma / 2
    y_slices = spec.step_mm * np.arange(spec.n_frames)
    lo, hi = y_slices[0] - 2 * sigma, y_slices[-1] + 2 * sigma
    n = int(np.ceil((hi - lo) / dy))
    yc = lo + dy * (np.arange(n) + 0.5)
    w = np.exp(-0.5 * ((yc[:, None] - y_slices[None]) / sigma) ** 2)
    w[w < np.exp(-2.0)] = 0.0
    return yc, w, dy


def layer_tissue(spec: AxialSpec, dom: _Domain, field, density_mm2: float, y_range,
                 rng: np.random.Generator):
    """Scatterers of one layer: (x, z) (N, 2), y (N,), Gaussian amplitudes shaped by the
    echogenicity ``field`` (one for the whole cloud: structures run along y), an interface's
    brighter band and a vessel's anechoic lumen and bright wall (both along y)."""
    box_x, box_z, _ = dom.bounding_box()
    n = rng.poisson(density_mm2 * (box_x[1] - box_x[0]) * (box_z[1] - box_z[0]))
    x, z = rng.uniform(*box_x, n), rng.uniform(*box_z, n)
    y = rng.uniform(*y_range, n)
    keep = dom.inside(x, z)
    x, z, y = x[keep], z[keep], y[keep]
    amp = np.exp(field(x, z))
    if spec.interface is not None:
        amp *= np.where(np.abs(_line_distance(x, z, spec.interface)) < 0.6, 1.5, 1.0)
    if spec.vessel is not None:
        vx, vz, vr = spec.vessel
        rv = np.hypot(x - vx, z - vz)
        amp *= np.where(rv < vr, 0.03, np.where(rv < vr + 0.4, 1.8, 1.0))
    return np.stack([x, z], 1), y, amp * rng.standard_normal(len(x))


def tissue_field(spec: AxialSpec, dom: _Domain, rng: np.random.Generator):
    """The smooth log-echogenicity field of the cloud (as the in-plane set's tissue)."""
    box_x, box_z, _ = dom.bounding_box()
    return _smooth_field(rng, (box_x, box_z), 4.0, spec.inhomogeneity)


def _ellipse(centre, tangent, r, theta):
    """Points (N, 2) of the slice's cut of the cylinder at angles theta (0: +x, pi/2: +z)."""
    t = np.asarray(tangent, float)[[0, 2]]
    n = float(np.linalg.norm(t))
    e1 = t / n if n > 1e-9 else np.array([1.0, 0.0])
    e2 = np.array([-e1[1], e1[0]])
    cos_a = float(np.sqrt(max(1.0 - n * n, 1e-6)))  # alpha: shaft to slice normal
    u = np.stack([np.cos(theta), np.sin(theta)], 1)
    a1, a2 = u @ e1, u @ e2  # the circle's components along e1 (stretched) and e2
    return np.asarray(centre)[None] + r * (a1[:, None] / cos_a * e1 + a2[:, None] * e2)


def _arc(centre, tangent, r, mid, half, spacing):
    """Points every ``spacing`` mm along the ellipse over angles mid +- half."""
    n = max(int(np.ceil(2 * half * r / spacing)), 2)
    return _ellipse(centre, tangent, r, mid + np.linspace(-half, half, n))


def cross_section(spec: AxialSpec, dom: _Domain, needle: AxialNeedle, y: float, spacing: float,
                  rng: np.random.Generator):
    """The needle's reflectors in the slice at y: points (N, 2) (x, z) and amplitudes, the upper
    wall's points (for the contrast band), and the crossing (centre, tangent); empty past the
    tip."""
    c = needle.crossing(y)
    if c is None:
        return np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2)), None
    centre, tan, s = c
    r = needle.r
    beam = dom.beam_axis(np.array([centre[0]]), np.array([centre[1]]))[0]
    up = np.arctan2(-beam[1], -beam[0])  # towards the probe along the beam
    half = np.deg2rad(spec.arc_half_angle_deg)
    upper = _arc(centre, tan, r, up, half, spacing)
    parts = [upper]
    amps = [1.0 + spec.roughness * rng.standard_normal(len(upper))]
    in_bevel = s > needle.s_tip - spec.bevel_length_mm
    if not in_bevel:
        lower = _arc(centre, tan, r, up + np.pi, np.deg2rad(50.0), spacing)
        parts.append(lower)
        amps.append(spec.lower_wall_gain * (1.0 + spec.roughness * rng.standard_normal(len(lower))))
    else:  # the bevel face: a rough chord across the lumen, rising towards the tip
        h = r * (1.0 - 2.0 * (needle.s_tip - s) / spec.bevel_length_mm)
        half_w = np.sqrt(max(r * r - h * h, 0.0))
        e = np.array([-beam[1], beam[0]])
        k = max(int(np.ceil(2 * half_w / spacing)), 1)
        chord = centre + (-h) * beam + np.linspace(-half_w, half_w, k)[:, None] * e
        parts.append(chord)
        amps.append(spec.bevel_gain * spec.roughness * rng.standard_normal(len(chord)))
    # the echo ringing between the walls repeats one diameter further along the beam
    gap = 2 * r
    for k in range(1, spec.n_reverb + 1):
        parts.append(upper + k * gap * beam)
        amps.append(amps[0] * spec.reverb_gain ** k)
    p, a = np.concatenate(parts), np.concatenate(amps)
    keep = dom.inside(p[:, 0], p[:, 1])
    return p[keep], a[keep], upper, (centre, tan)


def lumen_and_shadow(spec: AxialSpec, dom: _Domain, needle: AxialNeedle, pts: np.ndarray,
                     y: np.ndarray, amp: np.ndarray) -> np.ndarray:
    """The amplitude change (N,) of tissue scatterers (x, z) ``pts`` at elevations ``y`` that the
    needle causes where it crosses their y: -amp inside the lumen, -(1 - shadow) amp in the
    column behind it (within the radius of the beam through the centre), 0 elsewhere and past
    the tip."""
    out = np.zeros(len(pts))
    if not len(pts):
        return out
    live = y <= needle.tip[1]
    s = np.interp(y, needle.pts[:, 1], needle.s)
    c3, _ = needle._curve(s)
    c = c3[:, [0, 2]]
    beam = dom.beam_axis(c[:, 0], c[:, 1])
    d = pts - c
    along = np.sum(d * beam, 1)
    perp = np.abs(d[:, 0] * beam[:, 1] - d[:, 1] * beam[:, 0])
    dist = np.hypot(d[:, 0], d[:, 1])
    lumen = live & (dist < needle.r)
    behind = live & ~lumen & (along > 0) & (perp < needle.r)
    out[lumen] = -amp[lumen]
    out[behind] = -(1.0 - spec.shadow) * amp[behind]
    return out
