"""Compiled loops that image cached tissue cells with a 3D probe (numba).

The scatterers of a cell are moved into the probe frame and splatted in two passes: a
branch-free pass over the cell's scatterers that the compiler vectorises (beam coordinates,
lower corner and two-way phasor, with the arctangent and the sine and cosine written as
polynomials accurate to one ulp, since numba's calls into libm are not vectorised), then the
multilinear scatter. Scatterers go in the order of the direct path's loops
(:func:`synth._kernels.transform_splat_sector`, :func:`synth._kernels.transform_splat_field`),
cell after cell, into a float64 grid: the echo is theirs to float rounding.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["cells_near_sector", "cells_near_box", "splat_sector_cells", "splat_box_cells"]

# fast-math flags without reassociation: the Cody-Waite argument reduction below relies on
# the order of its subtractions
_FM = {"nsz", "contract"}

# atan: Cephes' rational approximation on [0, 0.66] after reduction (|error| <= 1 ulp)
_P0, _P1, _P2, _P3, _P4 = (-8.750608600031904122785e-1, -1.615753718733365076637e1,
                           -7.500855792314704667340e1, -1.228866684490136173410e2,
                           -6.485021904942025371773e1)
_Q0, _Q1, _Q2, _Q3, _Q4 = (2.485846490142306297962e1, 1.650270098316988542046e2,
                           4.328810604912902668951e2, 4.853903996359136964868e2,
                           1.945506571482613964425e2)
_T3P8 = 2.41421356237309504880  # tan(3 pi / 8)
_MOREBITS = 6.123233995736765886130e-17
_PIO2 = 1.57079632679489661923
_PIO4 = 0.78539816339744830962
# sin and cos on [-pi/4, pi/4] (fdlibm's kernels) after reduction by pi/2 in two parts
_S1, _S2, _S3, _S4, _S5, _S6 = (-1.66666666666666324348e-01, 8.33333333332248946124e-03,
                                -1.98412698298579493134e-04, 2.75573137070700676789e-06,
                                -2.50507602534068634195e-08, 1.58969099521155010221e-10)
_C1, _C2, _C3, _C4, _C5, _C6 = (4.16666666666666019037e-02, -1.38888888888741095749e-03,
                                2.48015872894767294178e-05, -2.75573143513906633035e-07,
                                2.08757232129817482790e-09, -1.13596475577881948265e-11)
_PIO2_1 = 1.57079632673412561417e+00  # the first 33 bits of pi / 2
_PIO2_1T = 6.07710050650619224932e-11  # pi / 2 - _PIO2_1
_INV_PIO2 = 6.36619772367581382433e-01


@numba.njit(inline="always", fastmath=_FM, error_model="numpy")
def _atan2(y, x):  # pragma: no cover - compiled
    """arctan2(y, x) for x > 0, branch-free, within one ulp of libm's: Cephes' reduction of
    y / x to [0, 0.66] written on y and x (one division)."""
    ay = abs(y)
    big = ay > _T3P8 * x
    mid = (ay > 0.66 * x) and not big
    num = -x if big else (ay - x if mid else ay)
    den = ay if big else (ay + x if mid else x)
    u = num / den
    y0 = _PIO2 if big else (_PIO4 if mid else 0.0)
    mb = _MOREBITS if big else (0.5 * _MOREBITS if mid else 0.0)
    z = u * u
    p = (((_P0 * z + _P1) * z + _P2) * z + _P3) * z + _P4
    q = ((((z + _Q0) * z + _Q1) * z + _Q2) * z + _Q3) * z + _Q4
    r = y0 + ((u * (z * p / q) + u) + mb)
    return np.copysign(r, y)


@numba.njit(inline="always", fastmath=_FM, error_model="numpy")
def _cos_sin(ph):  # pragma: no cover - compiled
    """(cos ph, sin ph) for |ph| up to ~1e6 rad, branch-free, within one ulp of libm's."""
    n = np.floor(ph * _INV_PIO2 + 0.5)
    x = (ph - n * _PIO2_1) - n * _PIO2_1T
    z = x * x
    s = x + x * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    c = 1.0 - 0.5 * z + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    q = n - 4.0 * np.floor(0.25 * n)  # quadrant 0..3
    swap = q == 1.0 or q == 3.0
    cs = s if swap else c
    sn = c if swap else s
    cs = -cs if (q == 1.0 or q == 2.0) else cs
    sn = -sn if q >= 2.0 else sn
    return cs, sn


@numba.njit(cache=True, nogil=True)
def cells_near_sector(centres, reach, R, t, origin_rpt, step_rpt, shape):  # pragma: no cover
    """Which cells (centres (C, 3), tissue frame) hold points within ``reach`` mm of their
    centre that a sector probe's splat can use: range, tilt and sector angle inside
    [origin, origin + (shape - 1) step) and z > 0 (probe frame q = R p + t). Conservative:
    a point within ``reach`` of q has its range within reach of |q|, its sector angle (the
    latitude to the plane x = 0) within asin(reach / |q|) and its tilt (the angle about the
    x axis) within asin(reach / |(q_y, q_z)|)."""
    n = centres.shape[0]
    out = np.zeros(n, np.bool_)
    r_lo, r_hi = origin_rpt[0], origin_rpt[0] + (shape[0] - 1) * step_rpt[0]
    p_lo, p_hi = origin_rpt[1], origin_rpt[1] + (shape[1] - 1) * step_rpt[1]
    s_lo, s_hi = origin_rpt[2], origin_rpt[2] + (shape[2] - 1) * step_rpt[2]
    for i in range(n):
        px, py, pz = centres[i, 0], centres[i, 1], centres[i, 2]
        qx = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
        qy = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
        qz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
        if qz + reach <= 0.0:
            continue
        r = np.sqrt(qx * qx + qy * qy + qz * qz)
        if r + reach < r_lo or r - reach >= r_hi:
            continue
        rho = np.sqrt(qy * qy + qz * qz)
        if r > reach:
            a = np.arcsin(reach / r)
            th = np.arcsin(min(max(qx / r, -1.0), 1.0))
            if th + a < s_lo or th - a >= s_hi:
                continue
        if rho > reach:
            b = np.arcsin(reach / rho)
            ph = np.arctan2(qy, qz)
            if ph + b < p_lo or ph - b >= p_hi:
                continue
        out[i] = True
    return out


@numba.njit(cache=True, nogil=True)
def cells_near_box(centres, reach, R, t, lo, hi):  # pragma: no cover - compiled
    """Which cells (centres (C, 3), tissue frame) hold points within ``reach`` mm of their
    centre that fall in the probe-frame box [lo, hi) (x, y, z order) after q = R p + t."""
    n = centres.shape[0]
    out = np.zeros(n, np.bool_)
    for i in range(n):
        px, py, pz = centres[i, 0], centres[i, 1], centres[i, 2]
        qx = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
        qy = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
        qz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
        out[i] = (qx + reach >= lo[0] and qx - reach < hi[0] and qy + reach >= lo[1]
                  and qy - reach < hi[1] and qz + reach >= lo[2] and qz - reach < hi[2])
    return out


@numba.njit(inline="always")
def _corner(a, n):  # pragma: no cover - compiled
    """floor(a) where 0 <= floor(a) < n - 1 (a lower trilinear corner), else -1."""
    f = np.floor(a)
    return f if (f >= 0.0 and f < n - 1) else -1.0


@numba.njit(inline="always")
def _scatter(base, fa, fb, fc, re, im, m, flat, sa, sb):  # pragma: no cover - compiled
    """Add the phasors (re, im) of m scatterers to the eight corners of their cells of a
    (A, B, C, 2) grid given flat (strides sa, sb, 2, 1) with trilinear weights; ``base`` is
    the flat index of the lower corner, -1 for a scatterer outside."""
    for k in range(m):
        o = base[k]
        if o < 0:
            continue
        for da in range(2):
            wa = fa[k] if da else 1.0 - fa[k]
            for db in range(2):
                wb = wa * (fb[k] if db else 1.0 - fb[k])
                oo = o + da * sa + db * sb
                w0 = wb * (1.0 - fc[k])
                w1 = wb * fc[k]
                flat[oo] += w0 * re[k]
                flat[oo + 1] += w0 * im[k]
                flat[oo + 2] += w1 * re[k]
                flat[oo + 3] += w1 * im[k]


@numba.njit(cache=True, nogil=True, fastmath=_FM, error_model="numpy")
def splat_sector_cells(xyz, amp, slots, n_per_cell, R, t, origin, step, two_k,
                       out):  # pragma: no cover - compiled
    """:func:`synth._kernels.transform_splat_sector` over the cached cells ``slots``: the
    scatterers ``xyz[:, s * n_per_cell:(s + 1) * n_per_cell]`` (positions as (3, N)) of each
    slot s, in order."""
    m = n_per_cell
    A, B, C = out.shape[0], out.shape[1], out.shape[2]
    flat = out.reshape(-1)
    base = np.empty(m, np.int64)
    fa = np.empty(m)
    fb = np.empty(m)
    fc = np.empty(m)
    bre = np.empty(m)
    bim = np.empty(m)
    i0, i1, i2 = 1.0 / step[0], 1.0 / step[1], 1.0 / step[2]
    for s in slots:
        o = s * m
        xs = xyz[0, o:o + m]
        ys = xyz[1, o:o + m]
        zs = xyz[2, o:o + m]
        am = amp[o:o + m]
        for k in range(m):  # vectorised: no branches, no calls
            px = np.float64(xs[k])
            py = np.float64(ys[k])
            pz = np.float64(zs[k])
            qx = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
            qy = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
            qz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
            rho2 = qy * qy + qz * qz
            r = np.sqrt(rho2 + qx * qx)
            ok = r > 0.0 and qz > 0.0
            # beam (theta, phi): theta = asin(x / r) = atan2(x, rho), phi = atan2(y, z)
            qz = qz if ok else 1.0  # skipped below; keeps the arctangents finite
            a = (r - origin[0]) * i0
            b = (_atan2(qy, qz) - origin[1]) * i1
            c = (_atan2(qx, np.sqrt(rho2 if ok else 1.0)) - origin[2]) * i2
            ia, ib, ic = _corner(a, A), _corner(b, B), _corner(c, C)
            inside = ok and ia >= 0.0 and ib >= 0.0 and ic >= 0.0
            ia, ib, ic = (ia, ib, ic) if inside else (0.0, 0.0, 0.0)
            base[k] = ((np.int64(ia) * B + np.int64(ib)) * C + np.int64(ic)) * 2 \
                if inside else -1
            fa[k], fb[k], fc[k] = a - ia, b - ib, c - ic
            cs, sn = _cos_sin(two_k * r)
            w = np.float64(am[k])
            bre[k] = w * cs  # amp * exp(-2j k r)
            bim[k] = -w * sn
        _scatter(base, fa, fb, fc, bre, bim, m, flat, B * C * 2, C * 2)


@numba.njit(cache=True, nogil=True, fastmath=_FM, error_model="numpy")
def splat_box_cells(xyz, amp, slots, n_per_cell, R, t, lo, hi, origin, step, two_k,
                    out):  # pragma: no cover - compiled
    """:func:`synth._kernels.transform_splat_field` over the cached cells ``slots``."""
    m = n_per_cell
    A, B, C = out.shape[0], out.shape[1], out.shape[2]
    flat = out.reshape(-1)
    base = np.empty(m, np.int64)
    fa = np.empty(m)
    fb = np.empty(m)
    fc = np.empty(m)
    bre = np.empty(m)
    bim = np.empty(m)
    i0, i1, i2 = 1.0 / step[0], 1.0 / step[1], 1.0 / step[2]
    for s in slots:
        o = s * m
        xs = xyz[0, o:o + m]
        ys = xyz[1, o:o + m]
        zs = xyz[2, o:o + m]
        am = amp[o:o + m]
        for k in range(m):  # vectorised: no branches, no calls
            px = np.float64(xs[k])
            py = np.float64(ys[k])
            pz = np.float64(zs[k])
            qx = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
            qy = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
            qz = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
            ok = (qx >= lo[0] and qy >= lo[1] and qz >= lo[2] and qx < hi[0] and qy < hi[1]
                  and qz < hi[2])
            a = (qz - origin[0]) * i0
            b = (qy - origin[1]) * i1
            c = (qx - origin[2]) * i2
            ia, ib, ic = _corner(a, A), _corner(b, B), _corner(c, C)
            inside = ok and ia >= 0.0 and ib >= 0.0 and ic >= 0.0
            ia, ib, ic = (ia, ib, ic) if inside else (0.0, 0.0, 0.0)
            base[k] = ((np.int64(ia) * B + np.int64(ib)) * C + np.int64(ic)) * 2 \
                if inside else -1
            fa[k], fb[k], fc[k] = a - ia, b - ib, c - ic
            cs, sn = _cos_sin(two_k * qz)
            w = np.float64(am[k])
            bre[k] = w * cs
            bim[k] = -w * sn
        _scatter(base, fa, fb, fc, bre, bim, m, flat, B * C * 2, C * 2)
