"""Compiled inner loops of the simulator (numba).

Splatting millions of point scatterers onto the acquisition grid is the one operation of the
convolution model that numpy cannot vectorise without materialising ``2**D`` weighted copies of
every scatterer; a compiled loop does it in one pass over the scatterers, 30x faster.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["splat_phasors_2d", "splat_phasors_3d"]


@numba.njit(cache=True, nogil=True, fastmath=True)
def splat_phasors_2d(idx, amp, phase, out):  # pragma: no cover - compiled
    """Add ``amp * exp(1j * phase)`` at fractional (row, col) ``idx`` with bilinear weights.

    ``out`` is (H, W, 2) float32 (real, imaginary); points outside are skipped.
    """
    H, W = out.shape[0], out.shape[1]
    for n in range(idx.shape[0]):
        z = idx[n, 0]
        x = idx[n, 1]
        iz = int(np.floor(z))
        ix = int(np.floor(x))
        if iz < 0 or ix < 0 or iz >= H - 1 or ix >= W - 1:
            continue
        fz = z - iz
        fx = x - ix
        re = amp[n] * np.cos(phase[n])
        im = amp[n] * np.sin(phase[n])
        w = (1.0 - fz) * (1.0 - fx)
        out[iz, ix, 0] += w * re
        out[iz, ix, 1] += w * im
        w = (1.0 - fz) * fx
        out[iz, ix + 1, 0] += w * re
        out[iz, ix + 1, 1] += w * im
        w = fz * (1.0 - fx)
        out[iz + 1, ix, 0] += w * re
        out[iz + 1, ix, 1] += w * im
        w = fz * fx
        out[iz + 1, ix + 1, 0] += w * re
        out[iz + 1, ix + 1, 1] += w * im


@numba.njit(cache=True, nogil=True, fastmath=True)
def splat_phasors_3d(idx, amp, phase, out):  # pragma: no cover - compiled
    """Trilinear version of :func:`splat_phasors_2d` for ``out`` of shape (A, B, C, 2)."""
    A, B, C = out.shape[0], out.shape[1], out.shape[2]
    for n in range(idx.shape[0]):
        a = idx[n, 0]
        b = idx[n, 1]
        c = idx[n, 2]
        ia = int(np.floor(a))
        ib = int(np.floor(b))
        ic = int(np.floor(c))
        if ia < 0 or ib < 0 or ic < 0 or ia >= A - 1 or ib >= B - 1 or ic >= C - 1:
            continue
        fa = a - ia
        fb = b - ib
        fc = c - ic
        re = amp[n] * np.cos(phase[n])
        im = amp[n] * np.sin(phase[n])
        for da in range(2):
            wa = fa if da else 1.0 - fa
            for db in range(2):
                wb = wa * (fb if db else 1.0 - fb)
                for dc in range(2):
                    w = wb * (fc if dc else 1.0 - fc)
                    out[ia + da, ib + db, ic + dc, 0] += w * re
                    out[ia + da, ib + db, ic + dc, 1] += w * im


def splat(idx: np.ndarray, amp: np.ndarray, phase: np.ndarray, shape: tuple[int, ...],
          out: np.ndarray | None = None) -> np.ndarray:
    """Multilinear splat of phasors ``amp * exp(1j * phase)`` onto a (*shape, 2) grid."""
    if out is None:
        out = np.zeros((*shape, 2), np.float32)
    idx = np.ascontiguousarray(idx, dtype=np.float64)
    amp = np.ascontiguousarray(amp, dtype=np.float32)
    phase = np.ascontiguousarray(phase, dtype=np.float64)
    if len(shape) == 2:
        splat_phasors_2d(idx, amp, phase, out)
    elif len(shape) == 3:
        splat_phasors_3d(idx, amp, phase, out)
    else:
        raise ValueError(f"splat: 2 or 3 dimensions, got shape {shape}")
    return out


@numba.njit(inline="always")
def _segment_distance2(x, y, z, a, b):  # pragma: no cover - compiled
    """Squared distance from (x, y, z) to the segment a-b."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    apx, apy, apz = x - a[0], y - a[1], z - a[2]
    L2 = abx * abx + aby * aby + abz * abz
    t = min(max((apx * abx + apy * aby + apz * abz) / max(L2, 1e-12), 0.0), 1.0)
    dx, dy, dz = apx - t * abx, apy - t * aby, apz - t * abz
    return dx * dx + dy * dy + dz * dz


@numba.njit(cache=True, nogil=True, fastmath=True, parallel=True)
def scattering_amplitude(p, smooth, smooth_origin, smooth_step, int_normals, int_offsets,
                         int_factors, int_bright, line_a, line_b, line_radius, line_gain,
                         cyst_centers, cyst_radii, cyst_factor, tube_a, tube_b, tube_radius,
                         tube_factor, tube_wall, cast_a, cast_b, cast_factor,
                         cast_half_width):  # pragma: no cover - compiled
    """The scattering map at points ``p`` (N, 3); see :class:`synth._world.ScatteringMap`.

    ``smooth`` is the smooth amplitude factor sampled on a lattice (origin, step), read by
    trilinear interpolation; a (1, 1, 1) lattice means no smooth inhomogeneity.
    """
    n = p.shape[0]
    out = np.empty(n, np.float32)
    has_smooth = smooth.shape[0] > 1
    for i in numba.prange(n):
        x = p[i, 0]
        y = p[i, 1]
        z = p[i, 2]
        a = 1.0
        if has_smooth:
            fx = (x - smooth_origin[0]) / smooth_step
            fy = (y - smooth_origin[1]) / smooth_step
            fz = (z - smooth_origin[2]) / smooth_step
            ix = min(max(int(np.floor(fx)), 0), smooth.shape[0] - 2)
            iy = min(max(int(np.floor(fy)), 0), smooth.shape[1] - 2)
            iz = min(max(int(np.floor(fz)), 0), smooth.shape[2] - 2)
            tx = fx - ix
            ty = fy - iy
            tz = fz - iz
            v = 0.0
            for dx in range(2):
                wx = tx if dx else 1.0 - tx
                for dy in range(2):
                    wy = wx * (ty if dy else 1.0 - ty)
                    v += wy * ((1.0 - tz) * smooth[ix + dx, iy + dy, iz]
                               + tz * smooth[ix + dx, iy + dy, iz + 1])
            a *= v
        for k in range(int_offsets.shape[0]):
            d = int_normals[k, 0] * x + int_normals[k, 1] * y + int_normals[k, 2] * z \
                - int_offsets[k]
            t = d / 0.3  # 0.3 mm transition between layers
            if t > 50.0:
                step = 1.0
            elif t < -50.0:
                step = 0.0
            else:
                step = 1.0 / (1.0 + np.exp(-t))
            a *= 1.0 + (int_factors[k] - 1.0) * step
            if abs(d) < 1.5:  # echogenic boundary
                a *= 1.0 + int_bright[k] * np.exp(-0.5 * (d / 0.25) ** 2)
        for k in range(line_radius.shape[0]):
            r = line_radius[k]
            d2 = _segment_distance2(x, y, z, line_a[k], line_b[k])
            if d2 < 25.0 * r * r:
                a *= 1.0 + (line_gain[k] - 1.0) * np.exp(-0.5 * d2 / (r * r))
        for k in range(cyst_radii.shape[0]):
            dx = x - cyst_centers[k, 0]
            dy = y - cyst_centers[k, 1]
            dz = z - cyst_centers[k, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            if d < cyst_radii[k] + 2.0:
                inside = 1.0 / (1.0 + np.exp((d - cyst_radii[k]) / 0.2))
                a *= 1.0 - (1.0 - cyst_factor) * inside
        for k in range(tube_radius.shape[0]):  # vessels: tubes with a sharp, echogenic wall
            r = tube_radius[k]
            d = np.sqrt(_segment_distance2(x, y, z, tube_a[k], tube_b[k]))
            if d < r + 2.0:
                inside = 1.0 / (1.0 + np.exp((d - r) / 0.1))
                a *= 1.0 - (1.0 - tube_factor[k]) * inside
                a *= 1.0 + tube_wall[k] * np.exp(-0.5 * ((d - r) / 0.15) ** 2)
        for k in range(cast_factor.shape[0]):
            # an acoustic shadow: everything deeper (+z, the beam of a probe at the identity
            # pose) than the occluding segment a-b, across its lateral extent and within
            # cast_half_width of it in elevation, keeps cast_factor of its amplitude
            x0 = min(cast_a[k, 0], cast_b[k, 0])
            x1 = max(cast_a[k, 0], cast_b[k, 0])
            if x < x0 - 1.5 or x > x1 + 1.5:
                continue
            f = 0.0 if x1 - x0 < 1e-9 else (x - cast_a[k, 0]) / (cast_b[k, 0] - cast_a[k, 0])
            f = min(max(f, 0.0), 1.0)
            zs = cast_a[k, 2] + f * (cast_b[k, 2] - cast_a[k, 2])
            ys = cast_a[k, 1] + f * (cast_b[k, 1] - cast_a[k, 1])
            lat = 1.0 / (1.0 + np.exp(-(x - x0) / 0.25)) / (1.0 + np.exp(-(x1 - x) / 0.25))
            below = 1.0 / (1.0 + np.exp(-(z - zs) / 0.2))
            el = 1.0 / (1.0 + np.exp((abs(y - ys) - cast_half_width[k]) / 0.3))
            a *= 1.0 - (1.0 - cast_factor[k]) * lat * below * el
        out[i] = a
    return out


@numba.njit(cache=True, nogil=True, fastmath=True)
def transform_splat_field(pos, amp, R, t, lo, hi, origin_zyx, step_zyx, two_k,
                          out):  # pragma: no cover - compiled
    """Move scatterers into the probe frame (q = R p + t), keep those inside [lo, hi) (x, y, z
    order) and splat ``amp * exp(-2j k z)`` trilinearly onto the (z, y, x) grid ``out``."""
    A, B, C = out.shape[0], out.shape[1], out.shape[2]
    for n in range(pos.shape[0]):
        px = pos[n, 0]
        py = pos[n, 1]
        pz = pos[n, 2]
        qx = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
        qy = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
        qz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
        if qx < lo[0] or qy < lo[1] or qz < lo[2] or qx >= hi[0] or qy >= hi[1] or qz >= hi[2]:
            continue
        a = (qz - origin_zyx[0]) / step_zyx[0]
        b = (qy - origin_zyx[1]) / step_zyx[1]
        c = (qx - origin_zyx[2]) / step_zyx[2]
        ia = int(np.floor(a))
        ib = int(np.floor(b))
        ic = int(np.floor(c))
        if ia < 0 or ib < 0 or ic < 0 or ia >= A - 1 or ib >= B - 1 or ic >= C - 1:
            continue
        fa = a - ia
        fb = b - ib
        fc = c - ic
        ph = -two_k * qz
        re = amp[n] * np.cos(ph)
        im = amp[n] * np.sin(ph)
        for da in range(2):
            wa = fa if da else 1.0 - fa
            for db in range(2):
                wb = wa * (fb if db else 1.0 - fb)
                for dc in range(2):
                    w = wb * (fc if dc else 1.0 - fc)
                    out[ia + da, ib + db, ic + dc, 0] += w * re
                    out[ia + da, ib + db, ic + dc, 1] += w * im


@numba.njit(cache=True, nogil=True, fastmath=True)
def transform_splat_plane(pos, amp, R, t, lo, hi, origin_zx, step_zx, two_k, sig_e_rows,
                          out):  # pragma: no cover - compiled
    """Image the plane y = 0 directly: move scatterers into the probe frame, weight each by the
    elevation beam profile exp(-y^2 / 2 sigma_e(z)^2) (sigma per image row, 3-sigma cut) and
    splat bilinearly onto the (z, x) grid ``out``."""
    H, W = out.shape[0], out.shape[1]
    for n in range(pos.shape[0]):
        px = pos[n, 0]
        py = pos[n, 1]
        pz = pos[n, 2]
        qx = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
        qy = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
        qz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
        if qx < lo[0] or qy < lo[1] or qz < lo[2] or qx >= hi[0] or qy >= hi[1] or qz >= hi[2]:
            continue
        z = (qz - origin_zx[0]) / step_zx[0]
        x = (qx - origin_zx[1]) / step_zx[1]
        row = min(max(int(z + 0.5), 0), sig_e_rows.shape[0] - 1)
        se = sig_e_rows[row]
        if abs(qy) > 3.0 * se:
            continue
        iz = int(np.floor(z))
        ix = int(np.floor(x))
        if iz < 0 or ix < 0 or iz >= H - 1 or ix >= W - 1:
            continue
        fz = z - iz
        fx = x - ix
        w_e = np.exp(-0.5 * (qy / se) ** 2)
        ph = -two_k * qz
        re = w_e * amp[n] * np.cos(ph)
        im = w_e * amp[n] * np.sin(ph)
        w = (1.0 - fz) * (1.0 - fx)
        out[iz, ix, 0] += w * re
        out[iz, ix, 1] += w * im
        w = (1.0 - fz) * fx
        out[iz, ix + 1, 0] += w * re
        out[iz, ix + 1, 1] += w * im
        w = fz * (1.0 - fx)
        out[iz + 1, ix, 0] += w * re
        out[iz + 1, ix, 1] += w * im
        w = fz * fx
        out[iz + 1, ix + 1, 0] += w * re
        out[iz + 1, ix + 1, 1] += w * im


@numba.njit(cache=True, nogil=True, fastmath=True)
def transform_splat_sector(pos, amp, R, t, origin_rpt, step_rpt, two_k,
                           out):  # pragma: no cover - compiled
    """Splat scatterers onto a sector probe's (range, tilt, sector-angle) beam grid; beam
    (theta, phi) points along (sin theta, cos theta sin phi, cos theta cos phi)."""
    A, B, C = out.shape[0], out.shape[1], out.shape[2]
    for n in range(pos.shape[0]):
        px = pos[n, 0]
        py = pos[n, 1]
        pz = pos[n, 2]
        qx = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
        qy = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
        qz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
        r = np.sqrt(qx * qx + qy * qy + qz * qz)
        if r <= 0.0 or qz <= 0.0:
            continue
        a = (r - origin_rpt[0]) / step_rpt[0]
        b = (np.arctan2(qy, qz) - origin_rpt[1]) / step_rpt[1]
        c = (np.arcsin(min(max(qx / r, -1.0), 1.0)) - origin_rpt[2]) / step_rpt[2]
        ia = int(np.floor(a))
        ib = int(np.floor(b))
        ic = int(np.floor(c))
        if ia < 0 or ib < 0 or ic < 0 or ia >= A - 1 or ib >= B - 1 or ic >= C - 1:
            continue
        fa = a - ia
        fb = b - ib
        fc = c - ic
        ph = -two_k * r
        re = amp[n] * np.cos(ph)
        im = amp[n] * np.sin(ph)
        for da in range(2):
            wa = fa if da else 1.0 - fa
            for db in range(2):
                wb = wa * (fb if db else 1.0 - fb)
                for dc in range(2):
                    w = wb * (fc if dc else 1.0 - fc)
                    out[ia + da, ib + db, ic + dc, 0] += w * re
                    out[ia + da, ib + db, ic + dc, 1] += w * im


@numba.njit(inline="always")
def _splitmix64(x):  # pragma: no cover - compiled
    x = (x + np.uint64(0x9E3779B97F4A7C15)) & np.uint64(0xFFFFFFFFFFFFFFFF)
    z = x
    z = ((z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)) & np.uint64(
        0xFFFFFFFFFFFFFFFF)
    z = ((z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)) & np.uint64(
        0xFFFFFFFFFFFFFFFF)
    return z ^ (z >> np.uint64(31))


@numba.njit(inline="always")
def _unit(h):  # pragma: no cover - compiled
    # the top 53 bits as a double in [0, 1)
    return float(h >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, nogil=True, parallel=True)
def cell_scatterers(cells, n_per_cell, cell_mm, seed, pos, amp):  # pragma: no cover - compiled
    """Scatterers of integer cells (C, 3): uniform positions and N(0, 1) amplitudes.

    A counter-based generator (SplitMix64 of seed, cell and scatterer index): a cell always
    holds the same scatterers, whichever region asked for it and in whatever order.
    """
    for c in numba.prange(cells.shape[0]):
        key = _splitmix64(np.uint64(seed))
        for d in range(3):
            key = _splitmix64(key ^ np.uint64(cells[c, d] + 1048576))
        for k in range(n_per_cell):
            h1 = _splitmix64(key ^ np.uint64(4 * k + 1))
            h2 = _splitmix64(h1 ^ np.uint64(4 * k + 2))
            h3 = _splitmix64(h2 ^ np.uint64(4 * k + 3))
            h4 = _splitmix64(h3 ^ np.uint64(4 * k + 4))
            h5 = _splitmix64(h4 ^ np.uint64(4 * k + 5))
            i = c * n_per_cell + k
            pos[i, 0] = (cells[c, 0] + _unit(h1)) * cell_mm
            pos[i, 1] = (cells[c, 1] + _unit(h2)) * cell_mm
            pos[i, 2] = (cells[c, 2] + _unit(h3)) * cell_mm
            u1 = max(_unit(h4), 1e-300)
            u2 = _unit(h5)
            amp[i] = np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)  # Box-Muller


@numba.njit(cache=True, nogil=True, fastmath=True, parallel=True)
def keep_plane(pos, R, t, lo, hi, origin_z, step_z, sig_e_rows):  # pragma: no cover
    """Scatterers a plane probe can see: inside the box and within 3 sigma of the elevation
    beam at their depth."""
    out = np.zeros(pos.shape[0], np.bool_)
    for n in numba.prange(pos.shape[0]):
        qx = R[0, 0] * pos[n, 0] + R[0, 1] * pos[n, 1] + R[0, 2] * pos[n, 2] + t[0]
        qy = R[1, 0] * pos[n, 0] + R[1, 1] * pos[n, 1] + R[1, 2] * pos[n, 2] + t[1]
        qz = R[2, 0] * pos[n, 0] + R[2, 1] * pos[n, 1] + R[2, 2] * pos[n, 2] + t[2]
        if qx < lo[0] or qy < lo[1] or qz < lo[2] or qx >= hi[0] or qy >= hi[1] or qz >= hi[2]:
            continue
        row = min(max(int((qz - origin_z) / step_z + 0.5), 0), sig_e_rows.shape[0] - 1)
        out[n] = abs(qy) <= 3.0 * sig_e_rows[row]
    return out


@numba.njit(cache=True, nogil=True, fastmath=True, parallel=True)
def keep_box(pos, R, t, lo, hi):  # pragma: no cover - compiled
    out = np.zeros(pos.shape[0], np.bool_)
    for n in numba.prange(pos.shape[0]):
        qx = R[0, 0] * pos[n, 0] + R[0, 1] * pos[n, 1] + R[0, 2] * pos[n, 2] + t[0]
        qy = R[1, 0] * pos[n, 0] + R[1, 1] * pos[n, 1] + R[1, 2] * pos[n, 2] + t[1]
        qz = R[2, 0] * pos[n, 0] + R[2, 1] * pos[n, 1] + R[2, 2] * pos[n, 2] + t[2]
        out[n] = not (qx < lo[0] or qy < lo[1] or qz < lo[2] or qx >= hi[0] or qy >= hi[1]
                      or qz >= hi[2])
    return out


@numba.njit(cache=True, nogil=True, fastmath=True, parallel=True)
def keep_sector(pos, R, t, origin_rpt, step_rpt, shape):  # pragma: no cover - compiled
    out = np.zeros(pos.shape[0], np.bool_)
    for n in numba.prange(pos.shape[0]):
        qx = R[0, 0] * pos[n, 0] + R[0, 1] * pos[n, 1] + R[0, 2] * pos[n, 2] + t[0]
        qy = R[1, 0] * pos[n, 0] + R[1, 1] * pos[n, 1] + R[1, 2] * pos[n, 2] + t[1]
        qz = R[2, 0] * pos[n, 0] + R[2, 1] * pos[n, 1] + R[2, 2] * pos[n, 2] + t[2]
        r = np.sqrt(qx * qx + qy * qy + qz * qz)
        if r <= 0.0 or qz <= 0.0:
            continue
        a = (r - origin_rpt[0]) / step_rpt[0]
        b = (np.arctan2(qy, qz) - origin_rpt[1]) / step_rpt[1]
        c = (np.arcsin(min(max(qx / r, -1.0), 1.0)) - origin_rpt[2]) / step_rpt[2]
        out[n] = (a >= -1.0 and b >= -1.0 and c >= -1.0 and a < shape[0] and b < shape[1]
                  and c < shape[2])
    return out


@numba.njit(cache=True, nogil=True)
def scan_convert_trilinear(flat, out_index, base, frac, s0, s1, out):  # pragma: no cover
    """out[out_index[i]] = the trilinear interpolation of the beam data ``flat`` at lower
    corner ``base[i]`` (flat index; strides s0, s1, 1) and offsets ``frac[i]`` (float32).

    Weights and sum in float32, corner after corner in (z, y, x) binary order: the same
    arithmetic as summing ``data[corner] * weight`` corner by corner in numpy.
    """
    one = np.float32(1.0)
    for i in range(out_index.shape[0]):
        b = base[i]
        f0 = frac[i, 0]
        f1 = frac[i, 1]
        f2 = frac[i, 2]
        acc = np.float32(0.0)
        for dz in range(2):
            wz = f0 if dz else one - f0
            for dy in range(2):
                wy = wz * (f1 if dy else one - f1)
                for dx in range(2):
                    w = wy * (f2 if dx else one - f2)
                    acc += np.float32(flat[b + dz * s0 + dy * s1 + dx]) * w
        out[out_index[i]] = acc
