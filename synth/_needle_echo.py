"""The needle's echo on the beam grid: the specular wall with its reverberations and bevel,
optionally a diffuse share and the streak of unfocused imaging past the tip, and the shadow it
casts on the tissue behind it (the scanner's physics of the needle, see :mod:`._scanner`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._blur import SPLAT_VAR as _SPLAT_VAR
from ._blur import blur_axis as _blur_axis
from ._blur import blur_const as _blur_const
from ._kernels import splat

__all__ = ["NeedleEcho", "needle_iq"]


@dataclass
class NeedleEcho:
    """The needle's IQ and the shadow it casts, on the crop ``region`` of the beam grid; the
    IQ may stop above the crop's last row (it is zero below)."""

    iq: np.ndarray
    shadow: np.ndarray
    region: tuple[slice, ...]


def needle_iq(scanner, pts: np.ndarray, tan: np.ndarray, step_mm: float,
              spec=None) -> NeedleEcho | None:
    """Normalised needle IQ and the tissue's shadow multiplier, in a crop of the beam grid.

    ``pts`` and ``tan`` are centreline samples and unit tangents in the probe frame; ``spec``
    the echo's :class:`~._world.NeedleSpec` (default: the world's needle; a
    :class:`~._world.SpecularLine`'s for a specular boundary).
    """
    probe, p = scanner.probe, scanner.params
    spec = scanner.world.needle if spec is None else spec
    shape = scanner._shape
    if len(pts) == 0:
        return None
    r = spec.radius_mm
    # only the part of the shaft that can reach the image (PSF, reverberation and
    # shadow margins included) is rendered: a long needle costs no more than the image
    idx = probe.to_beam_index(pts)
    margin = 8.0 + (spec.reverb_count + 2) * (spec.reverb_spacing_mm or r) / min(
        float(np.min(s)) for s in scanner._px)
    near = np.all((idx >= -margin) & (idx <= np.asarray(shape) - 1 + margin), axis=1)
    if not np.any(near):
        return None
    keep_tip = bool(near[-1])
    sample_index = np.flatnonzero(near)  # samples are step_mm apart from the entry
    pts, tan = pts[near], tan[near]
    b = probe.beam_direction(pts)
    bu = np.einsum("nd,nd->n", b, tan)
    nb = b - bu[:, None] * tan
    nbn = np.linalg.norm(nb, axis=1)
    ok = nbn > 1e-6
    nb[ok] /= nbn[ok, None]
    wall = pts - r * nb  # the wall that faces the transducer
    # Specular incidence angle: between the beam and the wall normal (-nb).
    psi = np.arcsin(np.clip(np.abs(bu), 0.0, 1.0))
    spec_w = spec.diffuse_floor + (1.0 - spec.diffuse_floor) * np.exp(
        -0.5 * (np.rad2deg(psi) / spec.specular_width_deg) ** 2)
    spec_w[~ok] = spec.diffuse_floor
    depth = probe.range_mm(pts)
    sig_px = [np.interp(depth, scanner._rows_mm, s) for s in scanner._sig_px]
    px = [np.interp(depth, scanner._rows_mm, s) for s in scanner._px]
    # Strength per sample: 1 mm of shaft gathered in one resolution cell peaks at `echo`;
    # a = q * (2 pi)^(D/2) * prod(sigma_px) undoes the kernel normalisation.
    eff = [np.sqrt(np.maximum(s**2, _SPLAT_VAR)) for s in sig_px]
    norm = (2.0 * np.pi) ** (len(eff) / 2.0) * np.prod(np.stack(eff), axis=0)
    strength = spec.echo * step_mm * spec_w * norm
    if probe.ndim == 2:
        y = np.abs(pts[:, 1])
        sig_e = p.sigma_elevation_mm(pts[:, 2])
        w_e = np.exp(-0.5 * (np.maximum(y - r, 0.0) / sig_e) ** 2)
        strength = strength * w_e
    else:
        w_e = np.ones(len(pts))
    # reverberations between the walls: echoes about a radius apart (the lumen of a
    # hollow needle is ~3/4 of its diameter), the comet tail below real shafts
    spacing = spec.reverb_spacing_mm or r
    f_diff = float(spec.diffuse_fraction)
    coherent = strength * np.sqrt(1.0 - f_diff) if f_diff > 0 else strength
    k = np.arange(spec.reverb_count + 1)
    rev_pts = (wall[None, :, :] + (k[:, None, None] * spacing) * b[None]).reshape(-1, 3)
    rev_amp = ((spec.reverb_decay ** k)[:, None] * coherent[None, :]).reshape(-1)
    # the bevel: a bright echo at the tip
    tip_amp = spec.tip_gain * spec.echo * norm[-1] * w_e[-1] if keep_tip else 0.0
    streak_pts, streak_amp = _streak(spec, wall, tan, coherent, psi, step_mm, keep_tip)
    all_pts = np.concatenate([rev_pts, wall[-1:], streak_pts])
    all_amp = np.concatenate([rev_amp, [tip_amp], streak_amp]).astype(np.float32)
    all_phase = np.zeros(len(all_amp))
    if f_diff > 0:
        # diffuse scatterers across the shaft (wall to far wall) with fixed random phases:
        # n samples of random phase sum to sqrt(n) times one, so each is scaled by the
        # square root of the samples in the PSF's extent along the shaft (same mean
        # intensity as the coherent echo it replaces)
        u = np.random.default_rng(spec.diffuse_seed).random(
            2 * (int(sample_index[-1]) + 1)).reshape(-1, 2)[sample_index]
        sig_mm = [sp * e for sp, e in zip(px, eff, strict=True)]
        t_img = tan[:, [2, 0]] if probe.ndim == 2 else tan[:, [2, 1, 0]]  # array order
        along = np.sqrt(sum((sg * t_img[:, a]) ** 2 for a, sg in enumerate(sig_mm)))
        n_cell = 2.0 * np.sqrt(np.pi) * along / step_mm
        d_amp = strength * np.sqrt(f_diff * np.maximum(n_cell, 1.0))
        d_pts = wall + (2.0 * r * u[:, :1]) * nb
        all_pts = np.concatenate([all_pts, d_pts])
        all_amp = np.concatenate([all_amp, d_amp.astype(np.float32)])
        all_phase = np.concatenate([all_phase, 2.0 * np.pi * u[:, 1]])
    keep = all_amp > 1e-6
    sp_idx = probe.to_beam_index(all_pts[keep])
    occ_idx = probe.to_beam_index(pts + r * b)  # behind the shaft: the shadow starts here
    # Work in a crop around the needle (down to the last row: the shadow reaches it).
    pad = [int(np.ceil(3.0 * float(np.max(s)))) + 2 for s in scanner._sig_px]
    both = np.concatenate([sp_idx, occ_idx])
    # per column: numpy reduces an (N, 2) array over axis 0 ~30x slower than its columns
    lo = np.maximum(np.floor([c.min() for c in both.T]).astype(int) - pad, 0)
    hi = np.minimum(np.ceil([c.max() for c in both.T]).astype(int) + np.asarray(pad) + 1,
                    shape)
    hi[0] = shape[0]
    if np.any(hi - lo < 2):
        return None
    crop = tuple(int(v) for v in hi - lo)
    sl = tuple(slice(int(a), int(b)) for a, b in zip(lo, hi, strict=True))
    # the echo is zero from its last splatted row plus the PSF's pad down: only the
    # shadow reaches the crop's last row
    iq_rows = crop[0]
    if len(sp_idx):
        # at least one row: the echo may lie wholly above the crop (a boundary above the
        # skin line) while what it shadows is in it
        iq_rows = max(int(min(np.ceil(sp_idx[:, 0].max()) + pad[0] + 1, hi[0])) - int(lo[0]),
                      1)
    # the specular echo is coherent along the shaft: zero phase (no speckle on the needle)
    iq = splat(sp_idx - lo, all_amp[keep], all_phase[keep], (iq_rows,) + crop[1:])
    for axis, s in enumerate(scanner._sig_px):
        iq = _blur_axis(iq, axis, s[sl[0]])  # the widths of the whole crop's rows
    att = p.two_way_attenuation(scanner._rows_mm[sl[0]][:iq_rows]) ** (1.0 - p.tgc_compensation)
    iq *= att.astype(np.float32).reshape((-1,) + (1,) * len(crop))
    # Shadow: tissue behind (deeper along the beam than) the shaft loses amplitude.
    occ = np.zeros(crop, np.float32)
    i0 = np.rint(occ_idx).astype(np.int64) - lo
    inb = np.all((i0 >= 0) & (i0 < np.asarray(crop)), axis=1)
    if np.any(inb):
        np.maximum.at(occ, tuple(i0[inb].T), w_e[inb].astype(np.float32))
        # only the rows the shaft crosses are blurred and accumulated (the blur runs
        # across the beams); the rows below it take the last one's shadow
        first, last = int(i0[inb, 0].min()), int(i0[inb, 0].max()) + 1
        # the shadow is as wide as the shaft across the beams
        occ2 = np.repeat(occ[first:last, ..., None], 2, -1)
        for axis in range(1, len(crop)):
            half = max(r / float(np.median(px[axis])), 0.5)
            occ2 = _blur_const(occ2, axis, half) * np.float32(np.sqrt(2 * np.pi) * half)
        acc = np.clip(occ2[..., 0], 0.0, 1.0)
        for i in range(1, len(acc)):  # row by row: numpy's accumulate over axis 0 walks
            np.maximum(acc[i - 1], acc[i], out=acc[i])  # the columns, 3-4x slower
        occ[first:last] = acc
        occ[last:] = acc[-1]
    shadow = 1.0 - (1.0 - spec.shadow_factor) * occ
    return NeedleEcho(iq=iq, shadow=shadow, region=sl)


def _streak(spec, wall: np.ndarray, tan: np.ndarray, coherent: np.ndarray, psi: np.ndarray,
            step_mm: float, keep_tip: bool) -> tuple[np.ndarray, np.ndarray]:
    """The coherent streak of unfocused imaging past the tip (:class:`NeedleSpec`'s
    ``streak_db``): points every ``step_mm`` along the tip's tangent from the tip's wall,
    until 40 dB below its start or 15 mm, and their amplitudes; empty without a streak."""
    if spec.streak_db is None or not keep_tip or len(wall) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    start_db = spec.streak_db + spec.streak_db_per_deg * float(np.rad2deg(psi[-1]))
    length = min(15.0, 40.0 / max(spec.streak_fade_db_per_mm, 1e-6))
    s = step_mm * np.arange(1, int(length / step_mm) + 1)
    amp = coherent[-1] * 10.0 ** ((start_db - spec.streak_fade_db_per_mm * s) / 20.0)
    return wall[-1] + s[:, None] * tan[-1], amp

