"""Probe geometries: where the beams go and how the acquisition grid maps to the image grid.

The probe frame has x lateral, y elevation, z depth (into the tissue), origin at the centre of
the transducer face. ``probe_pose`` (4x4) maps probe coordinates to world coordinates.

- :class:`PlaneProbe`: a linear array imaging one plane (``inplane``, or ``axial`` when the
  plane is held across the insertion direction, as the TRUS probe of Carriere 2016).
- :class:`SectorProbe`: the motorised 3D probe of Zhao 2013 (55 planes x 64 beams x 160
  samples, sector 34.5 degrees, tilt 38 degrees), scan-converted to a Cartesian grid.
- :class:`MatrixProbe`: a Cartesian 3D matrix probe (beams parallel to z).

Each probe gives its acquisition ("beam") grid, maps probe-frame points to fractional beam
indices, gives the beam direction at any point, and scan-converts beam data to its image grid.
It also carries the per-geometry steps of image formation that the scanner asks it for:
which scatterers it can see and how they are splatted onto its beam grid (directly, or from
the cached cells of a moving 3D probe), the range of a point along its beam, which points lie
inside its beams, the mask of the image its beams cover, and the 8-bit image it shows.
:class:`_BeamProbe` holds the defaults of a Cartesian probe (beams parallel to z, the beam
grid the image grid); the plane and sector probes override what differs.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ._cell_kernels import cells_near_box, cells_near_sector, splat_box_cells, splat_sector_cells
from ._geometry import Grid
from ._kernels import (
    keep_box,
    keep_plane,
    keep_sector,
    scan_convert_trilinear,
    transform_splat_field,
    transform_splat_plane,
    transform_splat_sector,
)

__all__ = ["PlaneProbe", "SectorProbe", "MatrixProbe", "Probe"]


def _pair(v, name: str) -> tuple[float, float]:
    if np.isscalar(v):
        v = (float(v), float(v))
    v = tuple(float(a) for a in v)
    if len(v) != 2 or any((not np.isfinite(a)) or a <= 0 for a in v):
        raise ValueError(f"{name} must be a positive number or pair, got {v}")
    return v


class _BeamProbe:
    """What every probe answers, with the defaults of a Cartesian probe: beams parallel to z,
    the beam grid the image grid, scatterers kept and splatted in a probe-frame box.

    Rigid transforms come as ``R`` (3, 3) and ``t`` (3,), contiguous float64: a tissue point
    ``p`` lies at ``R p + t`` in the probe frame. ``lo``, ``hi`` bound the probe-frame box
    (x, y, z) that reaches the image.
    """

    #: the tissue echo of a probe translated laterally or in elevation can be sampled from a
    #: cached 3D field of it (a plane probe: its PSF and phase depend on depth only)
    field_sliceable = False

    @property
    def beam_grid(self) -> Grid:
        return self.grid

    def beam_direction(self, p: np.ndarray) -> np.ndarray:
        out = np.zeros_like(p)
        out[:, 2] = 1.0
        return out

    def range_of_rows(self) -> np.ndarray:
        return self.beam_grid.axis_coords(0)

    def range_mm(self, p: np.ndarray) -> np.ndarray:
        """Distance of probe-frame points (N, 3) from the probe's origin, shape (N,)."""
        return np.linalg.norm(p, axis=1)

    def in_beams(self, p: np.ndarray) -> np.ndarray:
        """Which probe-frame points (N, 3) the beams reach beyond the image grid's own bounds:
        all of them."""
        return np.ones(len(p), bool)

    def inside_mask(self) -> np.ndarray | None:
        """The image voxels the beams cover; None when they cover the whole grid."""
        return None

    def scan_convert(self, img: np.ndarray) -> np.ndarray:
        return img

    def to_image(self, beam_image: np.ndarray) -> np.ndarray:
        """The displayed image of log-compressed beam data: scan-converted."""
        return self.scan_convert(beam_image)

    def keep_scatterers(self, pos, R, t, lo, hi, sigma_elevation_rows) -> np.ndarray:
        """Which tissue scatterers (N, 3) can reach the image, shape (N,) bool."""
        return keep_box(pos, R, t, lo, hi)

    def splat_scatterers(self, pos, amp, R, t, lo, hi, two_k, sigma_elevation_rows,
                         out) -> None:
        """Add the echo phasors ``amp * exp(-2j k z)`` of tissue scatterers to the beam-grid
        IQ ``out`` (splatted multilinearly, in the beam grid's (row, ...) order)."""
        bg = self.beam_grid
        transform_splat_field(pos, amp, R, t, lo, hi, np.asarray(bg.origin_mm),
                              np.asarray(bg.spacing_mm), two_k, out)

    def cells_near(self, centres, reach, R, t, lo, hi) -> np.ndarray:
        """Which tissue cells (centres (C, 3)) hold points within ``reach`` mm of their centre
        that can reach the image, shape (C,) bool."""
        return cells_near_box(centres, reach, R, t, np.asarray(lo, float),
                              np.asarray(hi, float))

    def splat_cells(self, xyz, amp, slots, n_per_cell, R, t, lo, hi, two_k, out) -> None:
        """:meth:`splat_scatterers` over the cached cells ``slots`` of a
        :class:`synth._cell_cache.CellCache` (positions ``xyz`` as (3, N))."""
        bg = self.beam_grid
        splat_box_cells(xyz, amp, slots, n_per_cell, R, t, np.asarray(lo, float),
                        np.asarray(hi, float), np.asarray(bg.origin_mm, float),
                        np.asarray(bg.spacing_mm, float), two_k, out)



@dataclass(frozen=True)
class PlaneProbe(_BeamProbe):
    """A linear array imaging the plane y = 0 of the probe frame.

    ``spacing_mm`` is (depth, lateral) pixel spacing. The image covers lateral
    ``[-width/2, width/2)`` and depth ``[depth_start, depth_start + depth)``.
    """

    width_mm: float = 38.4
    depth_mm: float = 50.0
    spacing_mm: tuple[float, float] | float = 0.1
    depth_start_mm: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "spacing_mm", _pair(self.spacing_mm, "PlaneProbe.spacing_mm"))
        for name in ("width_mm", "depth_mm"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"PlaneProbe.{name} must be positive, got {v}")
        if self.depth_start_mm < 0:
            raise ValueError(f"PlaneProbe.depth_start_mm must be >= 0, got {self.depth_start_mm}")

    ndim = 2
    field_sliceable = True

    @cached_property
    def grid(self) -> Grid:
        dz, dx = self.spacing_mm
        nz = int(round(self.depth_mm / dz))
        nx = int(round(self.width_mm / dx))
        return Grid((nz, nx), (dz, dx), (self.depth_start_mm, -self.width_mm / 2.0))

    def to_beam_index(self, p: np.ndarray) -> np.ndarray:
        """Probe-frame points (N, 3) -> fractional (z, x) indices (N, 2)."""
        g = self.grid
        return np.stack(
            [(p[:, 2] - g.origin_mm[0]) / g.spacing_mm[0],
             (p[:, 0] - g.origin_mm[1]) / g.spacing_mm[1]], axis=1)

    def range_mm(self, p: np.ndarray) -> np.ndarray:
        """Depth z of probe-frame points (N, 3), shape (N,)."""
        return p[:, 2]

    def pixel_size_mm(self) -> tuple[np.ndarray, ...]:
        """Physical size of a beam-grid step per axis, per depth row."""
        dz, dx = self.spacing_mm
        n = self.grid.shape[0]
        return np.full(n, dz), np.full(n, dx)

    def keep_scatterers(self, pos, R, t, lo, hi, sigma_elevation_rows) -> np.ndarray:
        """Inside the box and within 3 sigma of the elevation beam at their depth."""
        bg = self.beam_grid
        return keep_plane(pos, R, t, lo, hi, bg.origin_mm[0], bg.spacing_mm[0],
                          sigma_elevation_rows)

    def splat_scatterers(self, pos, amp, R, t, lo, hi, two_k, sigma_elevation_rows,
                         out) -> None:
        """Image the plane y = 0: each scatterer weighted by the elevation beam profile."""
        bg = self.beam_grid
        transform_splat_plane(pos, amp, R, t, lo, hi, np.asarray(bg.origin_mm),
                              np.asarray(bg.spacing_mm), two_k, sigma_elevation_rows, out)

    def region_box(self, margin_mm: float, elevation_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Probe-frame box (lo, hi) holding every scatterer that can reach the image."""
        g = self.grid
        z0, x0 = g.origin_mm
        z1 = z0 + g.shape[0] * g.spacing_mm[0]
        x1 = x0 + g.shape[1] * g.spacing_mm[1]
        lo = np.array([x0 - margin_mm, -elevation_mm, max(z0 - margin_mm, 0.0)])
        hi = np.array([x1 + margin_mm, elevation_mm, z1 + margin_mm])
        return lo, hi


@dataclass(frozen=True)
class MatrixProbe(_BeamProbe):
    """A Cartesian 3D probe: beams parallel to z on a regular (z, y, x) grid."""

    shape: tuple[int, int, int] = (128, 128, 128)
    spacing_mm: tuple[float, float, float] = (0.4, 0.4, 0.4)
    depth_start_mm: float = 2.0

    ndim = 3

    def __post_init__(self) -> None:
        if len(self.shape) != 3 or len(self.spacing_mm) != 3:
            raise ValueError("MatrixProbe.shape and spacing_mm need 3 entries (z, y, x)")

    @cached_property
    def grid(self) -> Grid:
        nz, ny, nx = self.shape
        dz, dy, dx = self.spacing_mm
        return Grid(self.shape, self.spacing_mm,
                    (self.depth_start_mm, -ny * dy / 2.0, -nx * dx / 2.0))

    def to_beam_index(self, p: np.ndarray) -> np.ndarray:
        return self.grid.points_to_index(p)

    def pixel_size_mm(self) -> tuple[np.ndarray, ...]:
        n = self.shape[0]
        return tuple(np.full(n, s) for s in self.spacing_mm)

    def region_box(self, margin_mm: float, elevation_mm: float = 0.0):
        g = self.grid
        lo_i = np.zeros(3)
        hi_i = np.asarray(g.shape, float)
        lo = g.index_to_points(lo_i) - margin_mm
        hi = g.index_to_points(hi_i) + margin_mm
        lo[2] = max(lo[2], 0.0)
        return lo, hi


@dataclass(frozen=True)
class SectorProbe(_BeamProbe):
    """Zhao 2013's motorised 3D probe: 55 planes x 64 beams x 160 samples.

    Beams leave a common apex at the origin of the probe frame; beam (theta, phi) points along
    ``(sin theta, cos theta sin phi, cos theta cos phi)``: theta spans the sector angle within
    a plane, phi the tilt of the plane swept by the motor. Samples are spaced by
    ``sample_spacing_mm`` (0.308 mm: an envelope sampled at 2.5 MHz, as in Zhao's simulation)
    from ``start_depth_mm``. The beam grid is in (range, plane, beam) order, like the image's
    (depth, elevation, lateral), and is scan-converted to a Cartesian grid of
    ``output_shape`` by trilinear interpolation.
    """

    n_planes: int = 55
    n_beams: int = 64
    n_samples: int = 160
    sector_deg: float = 34.5
    tilt_deg: float = 38.0
    sample_spacing_mm: float = 0.308
    start_depth_mm: float = 5.0
    output_shape: tuple[int, int, int] = (128, 128, 128)

    ndim = 3

    @cached_property
    def beam_grid(self) -> Grid:
        return Grid(
            (self.n_samples, self.n_planes, self.n_beams),
            (self.sample_spacing_mm, np.deg2rad(self.tilt_deg) / (self.n_planes - 1),
             np.deg2rad(self.sector_deg) / (self.n_beams - 1)),
            (self.start_depth_mm, -np.deg2rad(self.tilt_deg) / 2, -np.deg2rad(self.sector_deg) / 2),
        )

    @property
    def r_max(self) -> float:
        return self.start_depth_mm + (self.n_samples - 1) * self.sample_spacing_mm

    @cached_property
    def grid(self) -> Grid:
        th = np.deg2rad(self.sector_deg) / 2
        ph = np.deg2rad(self.tilt_deg) / 2
        r0, r1 = self.start_depth_mm, self.r_max
        x_half = r1 * np.sin(th)
        y_half = r1 * np.sin(ph)
        z0 = r0 * np.cos(th) * np.cos(ph)
        nz, ny, nx = self.output_shape
        dz = (r1 - z0) / (nz - 1)
        dy = 2 * y_half / (ny - 1)
        dx = 2 * x_half / (nx - 1)
        return Grid(self.output_shape, (dz, dy, dx), (z0, -y_half, -x_half))

    def to_beam_index(self, p: np.ndarray) -> np.ndarray:
        r = np.linalg.norm(p, axis=1)
        theta = np.arcsin(np.clip(p[:, 0] / np.maximum(r, 1e-9), -1, 1))
        phi = np.arctan2(p[:, 1], p[:, 2])
        g = self.beam_grid
        return np.stack([(r - g.origin_mm[0]) / g.spacing_mm[0],
                         (phi - g.origin_mm[1]) / g.spacing_mm[1],
                         (theta - g.origin_mm[2]) / g.spacing_mm[2]], axis=1)

    def beam_direction(self, p: np.ndarray) -> np.ndarray:
        return p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-9)

    def in_beams(self, p: np.ndarray) -> np.ndarray:
        """Which probe-frame points (N, 3) lie inside the beam grid (range, tilt, angle)."""
        bi = self.to_beam_index(p)
        return np.all((bi >= 0) & (bi <= np.asarray(self.beam_grid.shape) - 1), axis=1)

    def pixel_size_mm(self) -> tuple[np.ndarray, ...]:
        g = self.beam_grid
        r = self.range_of_rows()
        return np.full(len(r), g.spacing_mm[0]), r * g.spacing_mm[1], r * g.spacing_mm[2]

    @cached_property
    def _scan_table(self):
        """For every output voxel inside the sector: its flat index, the flat beam index of
        its lower trilinear corner (int32) and its fractional offsets (float32, (N, 3));
        16 bytes a voxel."""
        g = self.grid
        zz, yy, xx = np.meshgrid(*[g.axis_coords(a) for a in range(3)], indexing="ij")
        pts = np.stack([xx.ravel(), yy.ravel(), zz.ravel()], axis=1)
        idx = self.to_beam_index(pts)
        shape = np.asarray(self.beam_grid.shape)
        inside = np.all((idx >= 0) & (idx <= shape - 1), axis=1)
        out_index = np.flatnonzero(inside)
        idx = idx[inside]
        i0 = np.minimum(np.floor(idx).astype(np.int64), shape - 2)
        f = np.ascontiguousarray((idx - i0).astype(np.float32))
        strides = np.array([shape[1] * shape[2], shape[2], 1])
        base = (i0 @ strides).astype(np.int32)
        return out_index, base, f, strides

    def scan_convert(self, beam_data: np.ndarray) -> np.ndarray:
        """Trilinear scan conversion of beam-space data to the Cartesian grid (0 outside)."""
        out_index, base, f, strides = self._scan_table
        flat = beam_data.reshape(-1)
        if flat.dtype not in (np.uint8, np.float32):
            flat = flat.astype(np.float32)
        out = np.zeros(int(np.prod(self.output_shape)), np.float32)
        scan_convert_trilinear(np.ascontiguousarray(flat), out_index, base, f,
                               int(strides[0]), int(strides[1]), out)
        return out.reshape(self.output_shape)

    def to_image(self, beam_image: np.ndarray) -> np.ndarray:
        """The scan-converted volume rounded to 8 bits."""
        return np.clip(np.rint(self.scan_convert(beam_image)), 0, 255).astype(np.uint8)

    def inside_mask(self) -> np.ndarray:
        """The output voxels inside the sector."""
        out_index = self._scan_table[0]
        m = np.zeros(int(np.prod(self.output_shape)), bool)
        m[out_index] = True
        return m.reshape(self.output_shape)

    def keep_scatterers(self, pos, R, t, lo, hi, sigma_elevation_rows) -> np.ndarray:
        """Inside the beam grid (range, tilt and sector angle)."""
        bg = self.beam_grid
        return keep_sector(pos, R, t, np.asarray(bg.origin_mm), np.asarray(bg.spacing_mm),
                           np.asarray(bg.shape, np.float64))

    def splat_scatterers(self, pos, amp, R, t, lo, hi, two_k, sigma_elevation_rows,
                         out) -> None:
        """Splat onto the (range, tilt, sector-angle) beam grid."""
        bg = self.beam_grid
        transform_splat_sector(pos, amp, R, t, np.asarray(bg.origin_mm),
                               np.asarray(bg.spacing_mm), two_k, out)

    def cells_near(self, centres, reach, R, t, lo, hi) -> np.ndarray:
        """Cells that can reach the beam grid (range, tilt and sector angle)."""
        bg = self.beam_grid
        return cells_near_sector(centres, reach, R, t, np.asarray(bg.origin_mm, float),
                                 np.asarray(bg.spacing_mm, float),
                                 np.asarray(bg.shape, np.float64))

    def splat_cells(self, xyz, amp, slots, n_per_cell, R, t, lo, hi, two_k, out) -> None:
        """Splat the cached cells onto the (range, tilt, sector-angle) beam grid."""
        bg = self.beam_grid
        splat_sector_cells(xyz, amp, slots, n_per_cell, R, t, np.asarray(bg.origin_mm, float),
                           np.asarray(bg.spacing_mm, float), two_k, out)

    def region_box(self, margin_mm: float, elevation_mm: float = 0.0):
        g = self.grid
        lo = g.index_to_points(np.zeros(3)) - margin_mm
        hi = g.index_to_points(np.asarray(g.shape, float) - 1) + margin_mm
        lo[2] = max(lo[2] - self.start_depth_mm, 0.0)
        return lo, hi


Probe = PlaneProbe | SectorProbe | MatrixProbe
