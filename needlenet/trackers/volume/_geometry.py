"""Geometry on a volume's grid: the feature map and the imaged sector, millimetres to voxels,
the ROI/VOI shapes (Zhao 2013 eq. (1)'s cylinder, a ball), lines around an axis, and the
distance to the sector's boundary.

Everything is in millimetres in the probe frame, point order (x, y, z), through the frame's
:class:`synth.Grid` (voxels are anisotropic). Scan-converted sector volumes are exactly 0
outside the sector: those voxels are not tissue and never become candidates or thresholds.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from ...features import FeatureSource, Frame, Likelihood

__all__ = ["RING_MIN_SAMPLES", "Volume", "ball", "boundary_distance", "cross_section",
           "cylinder", "first_run_out", "perpendiculars", "profile", "ring_section",
           "run_out_distance", "section_mean", "voxel_count"]

# A ray has left the sector where it stays outside for this long (sector_run_out).
RUN_OUT_MM = 1.0
# The tissue around the needle: lines on a ring around the axis, this many angles at each of
# three radii (ring_section); a position counts where this many are in the sector.
RING_ANGLES = 12
RING_MIN_SAMPLES = 6
# Offsets, perpendicular to the axis and in units of a radius, of the lines over which the
# profile along the axis is taken: the axis itself and six lines around it.
PROFILE_OFFSETS = np.array(
    [[0.0, 0.0]] + [[math.cos(a), math.sin(a)] for a in np.arange(6) * math.pi / 3]
)
# Directions of the rays along which the distance to the sector's boundary is measured
# (boundary_distance): the 26 neighbours of a voxel.
RAYS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                 if (i, j, k) != (0, 0, 0)], float)
RAYS /= np.linalg.norm(RAYS, axis=1, keepdims=True)


class Volume:
    """One volume with what every method needs: the feature map, the sector, mm conversions.

    The maps are ``likelihood``'s, or, when it is None, ``features``' for the frame, computed
    when first read (the whole volume) or when a method asks for those of its region
    (:meth:`load_maps`)."""

    def __init__(self, frame: Frame, likelihood: Likelihood | None, learned: bool,
                 features: FeatureSource | None = None):
        self.image = np.asarray(frame.image)
        self.grid = frame.grid
        self.spacing = np.asarray(self.grid.spacing_mm, float)  # array order
        self.origin = np.asarray(self.grid.origin_mm, float)
        self.shape = np.asarray(self.grid.shape)
        self.learned = learned
        self.sector = self.image > 0  # scan-converted volumes are 0 outside the sector
        self._frame, self._features = frame, features
        self._maps: tuple[np.ndarray, np.ndarray | None] | None = None
        self.whole = False  # the maps cover the whole volume
        if likelihood is not None:
            self._set_maps(likelihood, whole=True)

    def _set_maps(self, likelihood: Likelihood, whole: bool) -> None:
        values = np.asarray(likelihood.shaft, dtype=np.float32)
        # a learned source's tip channel (None for classical features)
        tip = getattr(likelihood, "tip", None)
        tip = (np.asarray(tip, dtype=np.float32)
               if self.learned and tip is not None and np.shape(tip) == values.shape else None)
        self._maps, self.whole = (values, tip), whole

    def load_maps(self, region: np.ndarray | None = None) -> None:
        """The feature source's maps of the whole volume, or (``region``: flat indices) valid
        on those voxels and 0 away from them: a learned source runs its network only there
        (:meth:`LearnedFeatures.region_likelihood`), a classical one may give the whole."""
        f = self._features
        lk = f.likelihood(self._frame) if region is None else f.likelihood(self._frame,
                                                                          roi=region)
        self._set_maps(lk, whole=region is None)

    @property
    def values(self) -> np.ndarray:
        """The feature map (shaft likelihood with learned features), float32."""
        if self._maps is None:
            self.load_maps()
        return self._maps[0]

    @property
    def tip(self) -> np.ndarray | None:
        """A learned source's tip map, or None."""
        if self._maps is None:
            self.load_maps()
        return self._maps[1]

    def points(self, flat_index: np.ndarray) -> np.ndarray:
        """Voxel centres (N, 3) in mm, point order, of flat indices."""
        idx = np.stack(np.unravel_index(flat_index, self.grid.shape), axis=-1)
        return (self.origin + idx * self.spacing)[:, ::-1]

    def to_index(self, points_mm: np.ndarray) -> np.ndarray:
        """Fractional array indices (..., 3) of points (..., 3) in mm, point order."""
        return (np.asarray(points_mm, float)[..., ::-1] - self.origin) / self.spacing

    def sample(self, array: np.ndarray, points_mm: np.ndarray, order: int = 1,
               output=None) -> np.ndarray:
        """Values of ``array`` at points (..., 3) in mm; 0 outside the volume. ``output``: the
        values' dtype (e.g. float32 for a uint8 image, interpolated without rounding and
        without converting the whole array first); the array's own when None."""
        pts = np.asarray(points_mm, float)
        idx = self.to_index(pts.reshape(-1, 3))
        out = ndimage.map_coordinates(array, idx.T, output=output, order=order,
                                      mode="constant", cval=0.0)
        return out.reshape(pts.shape[:-1])


def voxel_count(volume_mm3: float, vol: Volume, minimum: int) -> int:
    """Number of voxels that make up ``volume_mm3`` (at least ``minimum``)."""
    return max(int(minimum), round(volume_mm3 / float(np.prod(vol.spacing))))


def cylinder(vol: Volume, point_mm, direction, radius_mm: float,
             t_range: tuple[float, float] = (-math.inf, math.inf)) -> np.ndarray:
    """Flat indices of the sector voxels within ``radius_mm`` of a line (Zhao eq. (1)).

    The line is ``point + t * direction`` (mm, point order), restricted to ``t_range``. The
    volume is walked one slice at a time along the axis the line crosses fastest; in each
    slice only a window around the crossing, the bounding box of the cylinder's elliptic
    section, is tested, so the cost is that of the cylinder, not of the volume.
    """
    p = np.asarray(point_mm, float)[::-1]  # array order
    u = np.asarray(direction, float)[::-1]
    u = u / np.linalg.norm(u)
    sp, org, shape = vol.spacing, vol.origin, vol.shape
    a = int(np.argmax(np.abs(u)))
    b, c = (ax for ax in range(3) if ax != a)
    coord_a = org[a] + np.arange(shape[a]) * sp[a]
    t = (coord_a - p[a]) / u[a]
    lo, hi = t_range
    slack = 2.0 * radius_mm  # a slice holds points whose t differs from its crossing by < sqrt(2) R
    k = np.flatnonzero((t >= lo - slack) & (t <= hi + slack))
    if k.size == 0:
        return np.zeros(0, np.int64)
    centre = p + t[k, None] * u  # (K, 3) crossing points
    # Half-widths of the section along b and c: R sqrt(u_a^2 + u_x^2) / |u_a|.
    half = radius_mm * np.sqrt(u[a] ** 2 + u[[b, c]] ** 2) / abs(u[a])
    wb, wc = (np.ceil(half / sp[[b, c]]).astype(int) + 1)
    ib = np.rint((centre[:, b] - org[b]) / sp[b]).astype(np.int64)[:, None, None] + \
        np.arange(-wb, wb + 1)[None, :, None]
    ic = np.rint((centre[:, c] - org[c]) / sp[c]).astype(np.int64)[:, None, None] + \
        np.arange(-wc, wc + 1)[None, None, :]
    ia = k[:, None, None]
    ib, ic, ia = np.broadcast_arrays(ib, ic, ia)
    d_a = org[a] + ia * sp[a] - p[a]
    d_b = org[b] + ib * sp[b] - p[b]
    d_c = org[c] + ic * sp[c] - p[c]
    tt = d_a * u[a] + d_b * u[b] + d_c * u[c]
    dist2 = d_a**2 + d_b**2 + d_c**2 - tt**2
    keep = ((dist2 <= radius_mm**2) & (tt >= lo) & (tt <= hi)
            & (ib >= 0) & (ib < shape[b]) & (ic >= 0) & (ic < shape[c]))
    index = np.zeros((3, int(keep.sum())), np.int64)
    index[a], index[b], index[c] = ia[keep], ib[keep], ic[keep]
    flat = np.ravel_multi_index(tuple(index), vol.grid.shape)
    return flat[vol.sector.reshape(-1)[flat]]


def ball(vol: Volume, centre_mm, radius_mm: float) -> np.ndarray:
    """Flat indices (ascending) of the sector voxels within ``radius_mm`` of a point."""
    c = vol.to_index(np.asarray(centre_mm, float))
    half = radius_mm / vol.spacing
    lo = np.maximum(np.floor(c - half), 0).astype(int)
    hi = np.minimum(np.ceil(c + half) + 1, vol.shape).astype(int)
    if np.any(hi <= lo):
        return np.zeros(0, np.int64)
    d = [((np.arange(lo[i], hi[i]) - c[i]) * vol.spacing[i]) ** 2 for i in range(3)]
    box = tuple(slice(a, b) for a, b in zip(lo, hi, strict=True))
    inside = np.zeros(vol.grid.shape, bool)  # marked in place: no index arrays of the box
    np.less_equal((d[0][:, None] + d[1][None, :])[:, :, None] + d[2][None, None, :],
                  radius_mm**2, out=inside[box])
    inside[box] &= vol.sector[box]
    return np.flatnonzero(inside)


# --------------------------------------------------------------------------------------------
# Lines around an axis
# --------------------------------------------------------------------------------------------


def perpendiculars(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``u`` and to each other."""
    helper = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def cross_section(model, a_values: np.ndarray, radius_mm: float) -> np.ndarray:
    """Points (7, K, 3) of the axis and of six lines ``radius_mm`` around it at ``a_values``."""
    e1, e2 = perpendiculars(model.principal_direction)
    offsets = radius_mm * (PROFILE_OFFSETS[:, :1] * e1 + PROFILE_OFFSETS[:, 1:] * e2)
    return model.points_at(a_values)[None, :, :] + offsets[:, None, :]


def profile(vol: Volume, model, a_values: np.ndarray, radius_mm: float,
            array: np.ndarray | None = None) -> np.ndarray:
    """Feature (or ``array``, e.g. a tip map) along the axis: the maximum over the centre
    line and six parallel lines.

    A maximum over the needle's cross-section: the needle is there if any of its voxels is
    bright, which keeps the profile above the threshold where single needle voxels are dark
    (Zhao's needle voxels are drawn independently) or the axis is a fraction of a voxel off.
    """
    pts = cross_section(model, a_values, radius_mm)
    return vol.sample(vol.values if array is None else array, pts).max(axis=0)


def ring_section(model, a_values: np.ndarray, radii_mm: tuple[float, float]) -> np.ndarray:
    """Points (L, K, 3) of lines parallel to the axis on a ring around it: ``RING_ANGLES``
    lines at each of three radii from ``radii_mm[0]`` to ``radii_mm[1]``."""
    e1, e2 = perpendiculars(model.principal_direction)
    ang = np.arange(RING_ANGLES) * (2.0 * math.pi / RING_ANGLES)
    r = np.linspace(radii_mm[0], radii_mm[1], 3)
    rr, aa = (x.ravel() for x in np.meshgrid(r, ang, indexing="ij"))
    offsets = (rr * np.cos(aa))[:, None] * e1 + (rr * np.sin(aa))[:, None] * e2
    return model.points_at(a_values)[None, :, :] + offsets[:, None, :]


def section_mean(vol: Volume, pts: np.ndarray, min_samples: int):
    """The image's mean over the lines ``pts`` (L, K, 3) at each of the K positions, over the
    samples inside the sector, and where at least ``min_samples`` of them are."""
    values = vol.sample(vol.image, pts, output=np.float32)
    inside = vol.sample(vol.sector.view(np.uint8), pts, order=0) > 0
    n_in = inside.sum(0)
    valid = n_in >= min_samples
    return np.where(valid, np.where(inside, values, 0.0).sum(0) / np.maximum(n_in, 1), 0.0), valid


# --------------------------------------------------------------------------------------------
# The sector's boundary
# --------------------------------------------------------------------------------------------


def first_run_out(inside: np.ndarray, n: int) -> np.ndarray:
    """Per ray (rows of ``inside``, (..., S) samples along each): the index of the first
    sample from which the ray stays outside the sector for ``n`` samples (samples past the
    end count as outside, so a ray still inside at its end gives ``S``)."""
    inside = np.asarray(inside, bool)
    S = inside.shape[-1]
    out = np.concatenate([(~inside).astype(np.int32),
                          np.ones(inside.shape[:-1] + (n,), np.int32)], axis=-1)
    c = np.concatenate([np.zeros(inside.shape[:-1] + (1,), np.int64),
                        np.cumsum(out, axis=-1)], axis=-1)
    run = (c[..., n:n + S] - c[..., :S]) == n  # samples i .. i + n - 1 all outside
    return np.where(run.any(axis=-1), np.argmax(run, axis=-1), S)


def _ray_step(vol: Volume) -> float:
    """Sample spacing along the rays that look for the sector's boundary (mm)."""
    return 0.25 * float(vol.spacing.min())


def _sector_run_out(vol: Volume, pts: np.ndarray) -> np.ndarray:
    """Per ray of samples ``pts`` (..., S, 3) spaced :func:`_ray_step` apart: the index of the
    sample where it leaves the sector for good, staying outside for ``RUN_OUT_MM``
    (:func:`first_run_out`; ``S`` when it does not).

    Not the first zero voxel: scan-converted volumes are 0 outside the sector, but dark
    speckle inside it is 0 too, and a first-zero test ends the sector at the first of them."""
    inside = vol.sample(vol.sector.view(np.uint8), pts, order=0) > 0
    return first_run_out(inside, max(int(round(RUN_OUT_MM / _ray_step(vol))), 1))


def run_out_distance(vol: Volume, point, u, max_mm: float) -> float:
    """Distance from ``point`` along ``u`` to the sector's boundary (:func:`_sector_run_out`;
    outside the array counts as outside); ``max_mm`` when it is not within that distance."""
    step = _ray_step(vol)
    s = np.arange(1, int((max_mm + RUN_OUT_MM) / step) + 1) * step
    first = int(_sector_run_out(vol, point + s[:, None] * u))
    return float(min(s[first], max_mm)) if first < s.size else max_mm


def boundary_distance(vol: Volume, point: np.ndarray, reach_mm: float) -> float:
    """Distance from a point to the sector's boundary along the nearest of a fan of rays
    (``RAYS``), looked for up to ``reach_mm`` (and a step)."""
    step = _ray_step(vol)
    s = np.arange(0, int(reach_mm / step) + 2) * step
    first_out = _sector_run_out(vol, point + s[None, :, None] * RAYS[:, None, :])
    return float(s[np.minimum(first_out, len(s) - 1)].min())
