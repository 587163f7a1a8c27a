"""The external volume sets: volumes swept slice by slice with PyMUST and written as needlenet
volume sequence files. Run ``python -m needlenet.bench.external.generate --set volume --out
DIR [--only NAME ...]`` (``--set volume-validation`` for the validation set).

Per sequence and transmit (``simus``, linear in the scatterers; the scene in :mod:`.volume`):
every tissue layer of every depth band once, added into each slice's RF with its elevation
weight; the interface once (a plane along y cuts every slice in the same line); then, slice by
slice, the pieces of shaft the needle gains between volumes, the bevel at each volume's tip
and the tissue each piece hollows and shadows, each projected onto the slice with its
elevation weights; electronic noise drawn per slice and volume. All are beamformed (``dasmtx``)
as separate columns and compounded over the transmits. Slice k of volume t = the tissue + the
interface + the noise (k, t) + the hollowing and shadowing of the pieces up to t + the needle's
echo: its pieces up to t and the bevel at t. Receive apertures are Hann-weighted
(:func:`hann_receive`); the in-plane and axial sets' are rectangular.

Display (shared with the in-plane and axial sets, :mod:`.generate`): a fixed depth gain (TGC)
from the middle slice's tissue, the display gain that puts the tissue's mean grey at the
spec's value, log compression over the spec's dynamic range and grey map. The envelope is
averaged over each 0.5 mm voxel's beamformed pixels (a scan converter's anti-aliasing) before
the log. The interface is scaled so that the voxels within ``INTERFACE_BAND_MM`` of its plane
are ``interface_cr`` times as bright as without it; the needle's echo so that, on the last
volume, the voxels within ``CONTRAST_BAND_MM`` of its wall facing the probe are ``target_cr``
times as bright as the same voxels without the needle (the in-plane and axial sets' contrast;
every volume's is in ``meta["needle_tissue_contrast"]``). Zhao 2013's eq. (9) contrast
(``synth.contrast_ratio``: voxels within a radius of the axis over the rest of the five-radius
cylinder) is written per volume as ``contrast_ratio``; on 0.5 mm voxels, where the echo, its
reverberations and the beam's blur fill much of that cylinder, it stays below 2 however bright
the needle is, so it is reported, not targeted.
"""

from __future__ import annotations

import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

import synth

from .generate import (
    _bisect,
    _grey,
    _local_contrast,
    _tgc_gain,
    _white_level,
    common_meta,
    run_meta,
)
from .scene import _C, _Domain, _interface_line, _line_distance
from .volume import (
    VolumeNeedle,
    elevation_bands,
    elevation_weights,
    in_view,
    smooth_field_3d,
    tissue_band,
)
from .volume_specs import VOLUME_PROBES, VolumeProbe, VolumeSpec, fine_setup

__all__ = ["CONTRAST_BAND_MM", "INTERFACE_BAND_MM", "generate_volume", "hann_receive"]

# the needle's and the interface's contrasts are measured over the voxels this close to the
# needle's wall facing the probe, or to the interface's plane (one voxel either side)
CONTRAST_BAND_MM = 0.5
INTERFACE_BAND_MM = 0.5


def _scene(spec: VolumeSpec, vp: VolumeProbe, dom: _Domain, lam: float, cell: float,
           rng: np.random.Generator) -> dict:
    """Every scatterer set of the sequence, 2-D (x, z) for simus, with the slices that see it.

    ``layers``: (weights (K,), points, amplitudes) per tissue layer; ``slices[k]``: the
    components of slice k as (kind, index, points, amplitudes), kind ``"hollow"`` (the tissue
    piece ``index`` hollows and shadows), ``"piece"`` (shaft) or ``"bevel"`` (at volume
    ``index``'s tip)."""
    setup = dom.setup
    K, T = vp.n_slices, spec.n_volumes
    box_x, box_z, _ = dom.bounding_box()
    y = vp.slice_y_mm
    field = smooth_field_3d(rng, (box_x, (y[0] - 15.0, y[-1] + 15.0), box_z), 4.0,
                            spec.inhomogeneity)
    needle = VolumeNeedle(spec, vp, dom) if spec.needle else None
    slices: list[list] = [[] for _ in range(K)]
    layers, hollow, n_tissue, n_hollow = [], [], 0, 0
    bands = elevation_bands(vp, dom, lam)
    for band in bands:
        rho3 = setup.scatterers_per_cell / cell / (band.sigma_mm * np.sqrt(np.pi))
        p, a, layer = tissue_band(spec, dom, band, rho3, field, rng)
        n_tissue += len(p)
        for j in range(len(band.layer_y_mm)):
            m = layer == j
            if m.any() and band.weights[j].any():
                layers.append((band.weights[j], p[m][:, [0, 2]], a[m]))
        if needle is None:
            continue
        piece, factor = needle.tissue_effect(p)
        m = piece >= 0
        n_hollow += int(m.sum())
        hollow.append((piece[m], p[m][:, [0, 2]], factor[m] * a[m],
                       band.weights[layer[m]]))  # (N, K): the layer's weight, as the tissue's
    if hollow:  # one component per piece and slice, over all bands
        piece, p, a, w = (np.concatenate(v) for v in zip(*hollow, strict=True))
        for i in range(T):
            m = piece == i
            for k in np.flatnonzero(w[m].any(0)):
                on = m & (w[:, k] > 0)
                slices[k].append(("hollow", i, p[on], a[on] * w[on, k]))
    spacing = lam / 8
    n_needle = 0
    if needle is not None:
        bounds = np.concatenate([[needle.s_back], needle.s_tips])
        parts = [("piece", i, *needle.walls(bounds[i], bounds[i + 1], spacing, rng))
                 for i in range(T)]
        parts += [("bevel", t, *needle.bevel(s, spacing, rng))
                  for t, s in enumerate(needle.s_tips)]
        for kind, i, p, a in parts:
            keep = dom.inside(p[:, 0], p[:, 2])
            p, a = p[keep], a[keep]
            w = elevation_weights(vp, dom, p, lam)
            for k in np.flatnonzero(w.any(0)):
                on = w[:, k] > 0
                slices[k].append((kind, i, p[on][:, [0, 2]], a[on] * w[on, k]))
                n_needle += int(on.sum())
    iface = _interface_line(spec, dom, spacing, rng) if spec.interface is not None else None
    return dict(layers=layers, slices=slices, iface=iface, needle=needle, bands=bands,
                n_tissue=n_tissue, n_hollow=n_hollow, n_needle=n_needle)


def hann_receive(das, element_x_mm: np.ndarray, pixel_x_mm: np.ndarray, n_t: int,
                 pitch_mm: float):
    """A DAS matrix (pixels x elements * n_t samples, as ``dasmtx`` makes it) with each
    pixel's receive aperture (the elements the f-number gives it) weighted by a Hann window
    cos^2(pi/2 |x_e - x_p| / (a + pitch / 2)), a the pixel's farthest element used: a
    rectangular aperture's -13 dB sidelobes put arcs of a bright needle's echo above the
    tissue across the slice."""
    m = das.tocsr(copy=True)
    counts = np.diff(m.indptr)
    rows = np.repeat(np.arange(m.shape[0]), counts)
    dx = np.abs(element_x_mm[m.indices // n_t] - pixel_x_mm[rows])
    half = np.zeros(m.shape[0])
    used = counts > 0
    half[used] = np.maximum.reduceat(dx, m.indptr[:-1][used])
    m.data = m.data * np.cos(0.5 * np.pi * dx / (half[rows] + 0.5 * pitch_mm)) ** 2
    return m


def _scanner(setup, dom: _Domain):
    """The in-plane sets' scanner (:mod:`.simulate`) beamforming with :func:`hann_receive`."""
    from .simulate import _Scanner

    class _HannScanner(_Scanner):
        def beamform(self, k: int, iq: np.ndarray) -> np.ndarray:
            n_t = iq.shape[0]
            if (k, n_t) not in self._das:  # build the matrix, then weight it once
                super().beamform(k, iq[..., :1])
                xe = np.ravel(self.param.getElementPositions()[0]) * 1e3
                self._das[(k, n_t)] = hann_receive(
                    self._das[(k, n_t)], xe, self.dom.bf_x.reshape(-1, order="F"), n_t,
                    float(self.param.pitch) * 1e3)
            return super().beamform(k, iq)

    return _HannScanner(setup, dom)


def _simulate(spec: VolumeSpec, vp: VolumeProbe, log, cell_mm2: float | None) -> dict:
    """Beamformed components (bf-grid I/Q, compounded; complex64) and the scene."""
    import pymust

    from .simulate import _cell_area_mm2

    setup = fine_setup(vp)
    lam = _C / pymust.getparam(setup.model).fc * 1e3
    dom = _Domain(setup, lam)
    sc = _scanner(setup, dom)
    rng = np.random.default_rng(spec.seed)
    cell = _cell_area_mm2(sc, dom) if cell_mm2 is None else cell_mm2
    scene = _scene(spec, vp, dom, lam, cell, rng)
    K, T = vp.n_slices, spec.n_volumes
    log(f"{spec.name}: cell {cell:.4f} mm2, {len(scene['bands'])} depth bands, "
        f"{len(scene['layers'])} tissue layers, {scene['n_tissue']} tissue scatterers, "
        f"{scene['n_hollow']} hollowed or shadowed, {scene['n_needle']} needle scatterer-slices")
    npix = dom.bf_x.size
    tissue = np.zeros((K, npix), np.complex64)
    noise = np.zeros((K, T, npix), np.complex64)  # electronic noise of slice k in volume t
    hollow = np.zeros((K, T, npix), np.complex64)  # the tissue hollowed and shadowed up to t
    echo = np.zeros((K, T, npix), np.complex64)  # the needle's pieces up to t + bevel at t
    iface = np.zeros(npix, np.complex64)
    has_echo = np.zeros((K, T), bool)
    for tx in range(len(sc.delays)):
        t0 = time.perf_counter()
        with np.errstate(invalid="ignore"):  # zero amplitudes: simus normalises 0 by 0
            shape = sc.rf(tx, np.zeros((0, 2)), np.zeros(0)).shape  # the RF length of all

        def rf(p, a, tx=tx, shape=shape):
            out = sc.rf(tx, p, a)
            if out.shape != shape:
                raise RuntimeError(f"simus returned RF of shape {out.shape}, expected {shape}: "
                                   "a scatterer lies beyond the domain's far corners")
            return out

        rf_slices = np.zeros((K, *shape))
        for w, p, a in scene["layers"]:
            ks = np.flatnonzero(w)
            rf_slices[ks] += w[ks, None, None] * rf(p, a)[None]
        rms = float(np.sqrt(np.mean(rf_slices[K // 2] ** 2)))
        noise_sd = rms * 10 ** (-spec.snr_db / 20)
        iface_rf = rf(*scene["iface"]) if scene["iface"] is not None else None
        for k in range(K):
            cols, tags = [rf_slices[k]], [("tissue", 0)]
            drawn = rng.standard_normal((*shape, T)) * noise_sd
            cols += [drawn[..., t] for t in range(T)]
            tags += [("noise", t) for t in range(T)]
            for kind, i, p, a in scene["slices"][k]:
                cols.append(rf(p, a))
                tags.append((kind, i))
            if k == 0 and iface_rf is not None:
                cols.append(iface_rf)
                tags.append(("iface", 0))
            bf = sc.beamform(tx, sc.iq(np.stack(cols, 2))).astype(np.complex64)
            for c, (kind, i) in enumerate(tags):
                if kind == "tissue":
                    tissue[k] += bf[:, c]
                elif kind == "noise":
                    noise[k, i] += bf[:, c]
                elif kind == "hollow":
                    hollow[k, i:] += bf[:, c]
                elif kind == "piece":
                    echo[k, i:] += bf[:, c]
                    has_echo[k, i:] = True
                elif kind == "bevel":
                    echo[k, i] += bf[:, c]
                    has_echo[k, i] = True
                else:
                    iface += bf[:, c]
        log(f"{spec.name}: transmit {tx + 1}/{len(sc.delays)} in "
            f"{time.perf_counter() - t0:.0f} s (simus {sc.seconds:.0f} s over {sc.calls} calls)")
    return dict(dom=dom, scene=scene, tissue=tissue, noise=noise, hollow=hollow, echo=echo,
                iface=iface,
                has_echo=has_echo, cell=cell, wavelength_mm=lam, param=sc.param,
                simus_s=sc.seconds, simus_calls=sc.calls, setup=setup)


class _Display:
    """Beamformed I/Q of a slice -> envelope on the slice's voxels (depth gain, scan
    conversion, the mean over each voxel's pixels) -> 8-bit volumes."""

    def __init__(self, sim: dict, vp: VolumeProbe, spec: VolumeSpec):
        self.dom, self.vp, self.spec = sim["dom"], vp, spec
        self.f = vp.fine_factor
        self.gain = _tgc_gain(self._field(sim["tissue"][vp.n_slices // 2]), self.dom)
        nz, _, nx = vp.shape
        v = self.dom.valid.reshape(nz, self.f, nx, self.f).sum((1, 3)).astype(float)
        self.count = v
        self.valid2 = v >= 0.5 * self.f ** 2  # a voxel at least half inside the sector
        self.valid = np.repeat(self.valid2[:, None, :], vp.n_slices, axis=1)
        self.white = 0.0

    def _field(self, v):
        return v.reshape(self.dom.bf_x.shape, order="F")

    def envelope(self, iq: np.ndarray) -> np.ndarray:
        """One slice's I/Q (bf-grid order) -> envelope (nz, nx) on its voxels."""
        env = self.dom.to_image(np.abs(self._field(iq)) * self.gain)
        nz, _, nx = self.vp.shape
        s = np.where(self.dom.valid, env, 0.0).reshape(nz, self.f, nx, self.f).sum((1, 3))
        return np.where(self.valid2, s / np.maximum(self.count, 1), 0.0)

    def volume_env(self, slices) -> np.ndarray:
        """Envelope volume (nz, K, nx) of K slices' I/Q."""
        return np.stack([self.envelope(s) for s in slices], axis=1)

    def grey(self, env: np.ndarray) -> np.ndarray:
        return _grey(env, self.white, self.spec)


def _compose(sim: dict, spec: VolumeSpec, vp: VolumeProbe) -> dict:
    """Volumes, labels and the achieved contrasts."""
    T = spec.n_volumes
    disp = _Display(sim, vp, spec)
    grid = synth.Grid(vp.shape, tuple(vp.spacing_mm), tuple(vp.origin_mm))
    tissue, noise, hollow, echo = sim["tissue"], sim["noise"], sim["hollow"], sim["echo"]
    base0 = tissue + noise[:, 0]
    env0 = disp.volume_env(base0)
    disp.white = _white_level(env0, disp.valid, spec)
    iface_scale = 0.0
    if spec.interface is not None:
        z, _, x = np.meshgrid(*(grid.axis_coords(a) for a in range(3)), indexing="ij")
        near = np.abs(_line_distance(x, z, spec.interface)) <= INTERFACE_BAND_MM
        band = np.flatnonzero(near & disp.valid)
        plain = disp.grey(env0)
        iface_scale = _bisect(lambda s: _local_contrast(
            disp.grey(disp.volume_env(base0 + s * sim["iface"])), plain, band),
            1e-4, 1e4, spec.interface_cr)
    bare = tissue[:, None] + iface_scale * sim["iface"] + noise  # (K, T, npix): no needle
    base = bare + hollow  # the needle's lumen and shadow, not its echo
    needle = sim["scene"]["needle"]
    needle_scale = 0.0
    cr, local = np.full(T, np.nan), np.full(T, np.nan)
    if needle is not None:
        r = needle.r
        axis_pts = [needle.centreline(t, 400) for t in range(T)]
        shown = disp.valid.reshape(-1)
        wall = [synth.tube_indices(grid, needle.near_wall(t), CONTRAST_BAND_MM)
                for t in range(T)]
        wall = [w[shown[w]] for w in wall]
        t_ref = T - 1
        ks = np.flatnonzero(sim["has_echo"][:, t_ref])
        env_ref = disp.volume_env(base[:, t_ref])
        bare_ref = disp.grey(disp.volume_env(bare[:, t_ref]))

        def contrast_at(s):
            env = env_ref.copy()
            env[:, ks] = disp.volume_env(base[ks, t_ref] + s * echo[ks, t_ref])
            return _local_contrast(disp.grey(env), bare_ref, wall[t_ref])

        needle_scale = _bisect(contrast_at, 1e-4, 1e4, spec.target_cr)
    images = np.zeros((T, *vp.shape), np.uint8)
    for t in range(T):
        images[t] = disp.grey(disp.volume_env(base[:, t] + needle_scale * echo[:, t]))
        if needle is not None:
            cr[t] = synth.contrast_ratio(images[t], grid, axis_pts[t], r, disp.valid)
            local[t] = _local_contrast(images[t], disp.grey(disp.volume_env(bare[:, t])),
                                       wall[t])
    return dict(images=images, cr=cr, local=local, grid=grid, valid=disp.valid,
                white_db=disp.white, needle_scale=needle_scale, interface_scale=iface_scale)


def _labels(needle: VolumeNeedle | None, vp: VolumeProbe, dom: _Domain, grid, valid,
            T: int) -> dict:
    """The volume labels, as synth's volume sequences carry them (probe frame, x, y, z)."""
    if needle is None:  # no needle: no tip, entry or direction to give
        return {"visible": np.zeros(T, bool)}
    tips = needle.tips
    idx = np.rint(grid.points_to_index(tips)).astype(int)
    inside = np.all((idx >= 0) & (idx < np.array(grid.shape)), axis=1)
    shown = np.zeros(T, bool)
    shown[inside] = valid[tuple(idx[inside].T)]
    return {"tip_mm": tips, "entry_mm": np.repeat(needle.entry[None], T, 0),
            "direction": np.repeat(needle.u[None], T, 0),
            "visible": in_view(vp, dom, tips) & shown,
            "centerline_mm": np.stack([needle.centreline(t) for t in range(T)])}


def generate_volume(spec: VolumeSpec, out_dir: Path, log=print,
                    scatterers_per_cell: float | None = None, vp: VolumeProbe | None = None,
                    cell_mm2: float | None = None) -> Path:
    """Simulate one volume sequence and write ``out_dir/NAME.npz``. ``vp`` replaces the
    probe's volume and ``cell_mm2`` the measured resolution cell (quick looks and tests)."""
    t0 = time.perf_counter()
    vp = VOLUME_PROBES[spec.probe] if vp is None else vp
    if scatterers_per_cell is not None:
        vp = replace(vp, setup=replace(vp.setup, scatterers_per_cell=scatterers_per_cell))
    sim = _simulate(spec, vp, log, cell_mm2)
    res = _compose(sim, spec, vp)
    needle, T = sim["scene"]["needle"], spec.n_volumes
    labels = _labels(needle, vp, sim["dom"], res["grid"], res["valid"], T)
    meta = {
        **common_meta(spec, sim["setup"], needle.r if needle is not None else None),
        "volume_probe": {k: v for k, v in asdict(vp).items() if k != "setup"},
        "alpha_deg": spec.alpha_deg if spec.needle else None,
        "beta_deg": spec.beta_deg if spec.needle else None,
        "target_cr": spec.target_cr if spec.needle else None,
        "needle_tissue_contrast": ([round(float(v), 3) for v in res["local"]]
                                   if spec.needle else None),
        "contrast_ratio_eq9": "per-volume key contrast_ratio: Zhao 2013 eq. 9 (synth)",
        "feature": spec.feature,
        "sector": ({"apex_mm": [0.0, 0.0], "half_angle_deg": vp.setup.sector_half_angle_deg,
                    "r_mm": list(sim["dom"].r_lim), "plane": "x-z, every slice"}
                   if sim["dom"].sector else None),
        "elevation_bands": [{"depth_mm": list(b.depth_mm), "fwhm_mm": round(
            b.sigma_mm * 2 * np.sqrt(2 * np.log(2)), 3), "layers": len(b.layer_y_mm)}
            for b in sim["scene"]["bands"]],
        "resolution_cell_mm2": sim["cell"],
        "n_tissue_scatterers": sim["scene"]["n_tissue"],
        **run_meta(sim, res, t0),
        "centerline_frame": "probe",
        "centerline_coords": "x,y,z",
        "frames": "the probe frame (x lateral, y elevation: the sweep axis, z depth; mm), "
                  "y = 0 on the middle slice; the probe stands still (probe_pose identity)",
        "labels": "tip_mm: the needle's tip; entry_mm: where its axis enters the volume; "
                  "direction: unit shaft direction towards the tip; centerline_mm: 64 points "
                  "from the entry to the tip; visible: the tip lies in the volume",
        "command": f"python -m needlenet.bench.external.generate --set "
                   f"{_set_of(spec)} --out DIR --only {spec.name}",
    }
    kw = dict(images=res["images"], spacing_mm=vp.spacing_mm, origin_mm=vp.origin_mm,
              modality="volume", timestamps_s=np.arange(T) / spec.volume_rate_hz,
              dynamic_range_db=float(spec.dynamic_range_db), meta=meta,
              probe_pose=np.repeat(np.eye(4)[None], T, 0), **labels)
    if needle is not None:
        kw["contrast_ratio"] = res["cr"]
    out = synth.save_sequence(synth.Sequence(**kw), Path(out_dir) / f"{spec.name}.npz",
                              overwrite=True)
    log(f"{spec.name}: wrote {out} in {time.perf_counter() - t0:.0f} s (simus "
        f"{sim['simus_s']:.0f} s); needle contrast per volume "
        f"{np.round(res['local'], 2).tolist() if needle is not None else '-'}, Zhao eq. 9 "
        f"{np.round(res['cr'], 2).tolist() if needle is not None else '-'}")
    return out


def _set_of(spec: VolumeSpec) -> str:
    from .volume_specs import VOLUME_VALIDATION_SPECS

    return "volume-validation" if spec in VOLUME_VALIDATION_SPECS else "volume"
