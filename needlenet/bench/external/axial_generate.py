"""The external axial set: transverse slices of a needle simulated with PyMUST, written as
needlenet axial sequence files. Run ``python -m needlenet.bench.external.generate --set axial
--out DIR [--only NAME ...]``.

Per sequence and transmit (``simus``, linear in the scatterers): every tissue layer of the 3-D
cloud (:mod:`.axial`) once, the interface once (a plane along the stepping axis cuts every
slice in the same line), and the needle's cross-section in each slice; all are beamformed
(``dasmtx``) as separate columns. Slice k = the layers weighted by the elevation beam centred
on y_k + the interface + slice k's cross-section + electronic noise drawn for slice k. The
display (TGC, gain, log compression) is the in-plane set's. The needle amplitude is scaled so
that, on the reference slice (the middle of the needle's slices), the mean grey within 0.3 mm
of the upper wall is ``target_cr`` times the same pixels' mean grey without the needle.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import synth

from .axial import (
    AxialNeedle,
    cross_section,
    elevation_layers,
    layer_tissue,
    lumen_and_shadow,
    tissue_field,
)
from .axial_specs import AXIAL_PROBES, AxialSpec, elevation_fwhm_mm
from .generate import (
    _bisect,
    _grey,
    _local_contrast,
    _near,
    _tgc_gain,
    _white_level,
    common_meta,
    run_meta,
)
from .scene import _C, CONTRAST_RADIUS_MM, _Domain, _interface_line
from .specs import ProbeSetup

__all__ = ["generate_axial"]


def _simulate(spec: AxialSpec, setup: ProbeSetup, log, cell_mm2: float | None) -> dict:
    """Beamformed components (bf-grid I/Q, compounded) and the scene's geometry."""
    import pymust

    from .simulate import _cell_area_mm2, _Scanner

    lam = _C / pymust.getparam(setup.model).fc * 1e3
    dom = _Domain(setup, lam)
    sc = _Scanner(setup, dom)
    rng = np.random.default_rng(spec.seed)
    cell = _cell_area_mm2(sc, dom) if cell_mm2 is None else cell_mm2
    needle = AxialNeedle(spec) if spec.needle else None
    depth = spec.centre_mm[1] if spec.needle else 0.5 * sum(setup.z_range_mm)
    fwhm = elevation_fwhm_mm(spec.probe, depth, lam)
    yc, W, dy = elevation_layers(spec, fwhm)
    sigma = fwhm / (2 * np.sqrt(2 * np.log(2)))
    rho3 = setup.scatterers_per_cell / cell / (sigma * np.sqrt(np.pi))  # per mm^3
    field = tissue_field(spec, dom, rng)
    comps: list[tuple[str, np.ndarray, np.ndarray]] = []
    n_tissue = 0
    for j, y0 in enumerate(yc):
        p, y, a = layer_tissue(spec, dom, field, rho3 * dy, (y0 - dy / 2, y0 + dy / 2), rng)
        if needle is not None:
            a = a + lumen_and_shadow(spec, dom, needle, p, y, a)
        comps.append((f"layer{j}", p, a))
        n_tissue += len(p)
    log(f"{spec.name}: cell {cell:.4f} mm2, elevation FWHM {fwhm:.2f} mm, {len(yc)} layers, "
        f"{n_tissue} tissue scatterers")
    spacing = lam / 8
    if spec.interface is not None:
        comps.append(("interface", *_interface_line(spec, dom, spacing, rng)))
    upper, crossing = [], []
    for k in range(spec.n_frames):
        y = spec.step_mm * k
        if needle is None:
            upper.append(np.zeros((0, 2)))
            crossing.append(None)
            continue
        p, a, up, c = cross_section(spec, dom, needle, y, spacing, rng)
        comps.append((f"needle{k}", p, a))
        upper.append(up)
        crossing.append(c)
    names = [c[0] for c in comps]
    bf = noise_bf = None
    for t in range(len(sc.delays)):
        t0 = time.perf_counter()
        rfs = [sc.rf(t, p, a) if len(p) else None for _, p, a in comps]
        shape = next(r.shape for r in rfs if r is not None)
        rfs = [np.zeros(shape) if r is None else r for r in rfs]
        tissue0 = sum(W[j, 0] * rfs[j] for j in range(len(yc)) if W[j, 0] > 0)
        rms = float(np.sqrt(np.mean(tissue0 ** 2)))
        noise = rng.standard_normal((*shape, spec.n_frames)) * rms * 10 ** (-spec.snr_db / 20)
        out = sc.beamform(t, sc.iq(np.concatenate([np.stack(rfs, 2), noise], 2)))
        part, npart = out[:, :len(comps)], out[:, len(comps):]
        bf = part if bf is None else bf + part
        noise_bf = npart if noise_bf is None else noise_bf + npart
        log(f"{spec.name}: transmit {t + 1}/{len(sc.delays)} in {time.perf_counter() - t0:.0f} s"
            f" (simus {sc.seconds:.0f} s over {sc.calls} calls)")
    return dict(dom=dom, needle=needle, names=names, bf=bf, noise=noise_bf, W=W, layers_y=yc,
                fwhm=fwhm, upper=upper, crossing=crossing, cell=cell, rho3=rho3,
                n_tissue=n_tissue, simus_s=sc.seconds, simus_calls=sc.calls, wavelength_mm=lam,
                param=sc.param)


def _compose(sim: dict, spec: AxialSpec) -> dict:
    """Frames, labels and the achieved contrast."""
    dom, names, bf = sim["dom"], sim["names"], sim["bf"]
    grid = synth.Grid((dom.nz, dom.nx), tuple(dom.spacing_mm), tuple(dom.origin_mm))
    T, shape = spec.n_frames, dom.bf_x.shape
    col = {n: i for i, n in enumerate(names)}

    def field(v):
        return v.reshape(shape, order="F")

    L = sim["W"].shape[0]
    tissue = bf[:, :L] @ sim["W"]  # (n_pix, T): slice k's elevation-weighted cloud
    base = [field(tissue[:, k] + sim["noise"][:, k]) for k in range(T)]
    if "interface" in col:
        iface = field(bf[:, col["interface"]])
    zero = np.zeros(shape, complex)
    needle = [field(bf[:, col[f"needle{k}"]]) if f"needle{k}" in col else zero
              for k in range(T)]
    gain = _tgc_gain(field(tissue[:, 0]), dom)

    def env_image(iq):
        return dom.to_image(np.abs(iq) * gain)

    valid = dom.valid
    white = _white_level(env_image(base[0]), valid, spec)
    iface_scale = 0.0
    if spec.interface is not None:
        x0, z0, slope = spec.interface
        t = np.deg2rad(slope)
        line = np.array([x0, z0]) + np.arange(-200, 200, 0.05)[:, None] * np.array(
            [np.cos(t), np.sin(t)])
        line = line[dom.in_image(line[:, 0], line[:, 1])]
        band = _near(grid, line, CONTRAST_RADIUS_MM)
        base_im = _grey(env_image(base[0]), white, spec)
        iface_scale = _bisect(lambda s: _local_contrast(
            _grey(env_image(base[0] + s * iface), white, spec), base_im, band),
            1e-4, 1e4, spec.interface_cr)
        base = [b + iface_scale * iface for b in base]

    def wall_band(k):
        up = sim["upper"][k]
        up = up[dom.in_image(up[:, 0], up[:, 1])]
        return _near(grid, up, CONTRAST_RADIUS_MM) if len(up) else np.zeros(0, int)

    present = [k for k in range(T) if sim["crossing"][k] is not None]
    needle_scale, k_ref = 0.0, None
    if present:
        k_ref = present[len(present) // 2]
        ref_im = _grey(env_image(base[k_ref]), white, spec)
        band = wall_band(k_ref)
        needle_scale = _bisect(lambda s: _local_contrast(
            _grey(env_image(base[k_ref] + s * needle[k_ref]), white, spec), ref_im, band),
            1e-4, 1e4, spec.target_cr)
    images = np.zeros((T, dom.nz, dom.nx), np.uint8)
    tip = np.full((T, 2), np.nan)
    direction = np.full((T, 2), np.nan)
    visible = np.zeros(T, bool)
    local = np.full(T, np.nan)
    for k in range(T):
        images[k] = _grey(env_image(base[k] + needle_scale * needle[k]), white, spec)
        c = sim["crossing"][k]
        if c is None:
            continue
        centre, tan = c
        tip[k] = centre
        d = tan[[0, 2]]
        direction[k] = d / np.linalg.norm(d) if np.linalg.norm(d) > 1e-9 else np.nan
        visible[k] = bool(dom.in_image(np.array([centre[0]]), np.array([centre[1]]))[0])
        band = wall_band(k)
        if len(band):
            local[k] = _local_contrast(images[k], _grey(env_image(base[k]), white, spec), band)
    return dict(images=images, tip=tip, direction=direction, visible=visible, local=local,
                white_db=white, needle_scale=needle_scale, interface_scale=iface_scale,
                reference_frame=k_ref)


def generate_axial(spec: AxialSpec, out_dir: Path, log=print,
                   scatterers_per_cell: float | None = None, setup: ProbeSetup | None = None,
                   cell_mm2: float | None = None) -> Path:
    """Simulate one axial sequence and write ``out_dir/NAME.npz``. ``setup`` replaces the
    probe's window and ``cell_mm2`` the measured resolution cell (quick looks and tests)."""
    t0 = time.perf_counter()
    setup = AXIAL_PROBES[spec.probe] if setup is None else setup
    if scatterers_per_cell is not None:
        setup = replace(setup, scatterers_per_cell=scatterers_per_cell)
    sim = _simulate(spec, setup, log, cell_mm2)
    res = _compose(sim, spec)
    dom, needle, T = sim["dom"], sim["needle"], spec.n_frames
    y = spec.step_mm * np.arange(T)
    pose = np.repeat(np.eye(4)[None], T, 0)
    pose[:, 1, 3] = y  # the probe steps along its elevation axis
    meta = {
        **common_meta(spec, setup, needle.r if needle is not None else None),
        "tip_y_mm": float(needle.tip[1]) if needle is not None else None,
        "tip_3d_mm": needle.tip.tolist() if needle is not None else None,
        "target_cr": spec.target_cr if spec.needle else None,
        "needle_tissue_contrast": ([None if not np.isfinite(v) else round(float(v), 3)
                                    for v in res["local"]] if spec.needle else None),
        "contrast_reference_frame": res["reference_frame"],
        "feature": spec.feature,
        "sector": ({"apex_mm": [0.0, 0.0], "half_angle_deg": setup.sector_half_angle_deg,
                    "r_mm": list(dom.r_lim)} if dom.sector else None),
        "elevation_fwhm_mm": sim["fwhm"],
        "elevation_layers": len(sim["layers_y"]),
        "resolution_cell_mm2": sim["cell"],
        "scatterers_per_mm3": sim["rho3"],
        "n_tissue_scatterers": sim["n_tissue"],
        **run_meta(sim, res, t0),
        "frames": "slice k lies at y = k * step_mm in the world frame (the probe frame of "
                  "slice 0); probe_pose maps each slice's probe frame to it",
        "centerline_frame": "world (x, y, z) mm, the probe frame of slice 0",
        "labels": "tip_mm: where the needle axis crosses the slice (x, z), NaN past the tip; "
                  "direction: unit (x, z) part of the shaft tangent there",
        "command": f"python -m needlenet.bench.external.generate --set axial --out DIR "
                   f"--only {spec.name}",
    }
    kw = dict(images=res["images"], spacing_mm=dom.spacing_mm, origin_mm=dom.origin_mm,
              modality="axial", timestamps_s=np.arange(T) / spec.frame_rate_hz,
              dynamic_range_db=float(spec.dynamic_range_db), meta=meta, probe_pose=pose,
              tip_mm=res["tip"], direction=res["direction"], visible=res["visible"])
    if needle is not None:
        kw["centerline_mm"] = np.repeat(needle.centreline()[None], T, 0)
    out = synth.save_sequence(synth.Sequence(**kw), Path(out_dir) / f"{spec.name}.npz",
                              overwrite=True)
    log(f"{spec.name}: wrote {out} in {time.perf_counter() - t0:.0f} s (simus "
        f"{sim['simus_s']:.0f} s); needle contrast on the reference slice "
        f"{_fmt(res['local'], res['reference_frame'])}")
    return out


def _fmt(local, k) -> str:
    return "-" if k is None or not np.isfinite(local[k]) else f"{local[k]:.2f}"
