"""PyMUST's part: the probe, its transmits and receive beamforming, and the RF of every
scatterer set of a sequence (``simus`` per transmit, summed by linearity)."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from .scene import (
    _C,
    _bevel,
    _Domain,
    _interface_line,
    _Needle,
    _needle_piece,
    _tissue,
)
from .specs import PROBES, ProbeSetup, SequenceSpec


class _Scanner:
    """simus + rf2iq + dasmtx for one probe; every call shares one frequency grid."""

    def __init__(self, setup: ProbeSetup, dom: _Domain):
        import pymust

        self.pm = pymust
        self.setup, self.dom = setup, dom
        p = pymust.getparam(setup.model)
        p.fs = 4 * p.fc
        p.attenuation = setup.attenuation_db_cm_mhz
        p.fnumber = None  # dasmtx: the f-number from the elements' directivity
        self.param = p
        self.opt = pymust.utils.Options()
        self.opt.dBThresh = setup.db_thresh
        self.opt.ParPool = False
        self.opt.WaitBar = False
        if setup.element_splitting is not None:
            self.opt.ElementSplitting = setup.element_splitting
        self.delays = []
        for tilt in setup.tilts_deg:
            if setup.diverging_width_deg is None:
                d = pymust.txdelay(p, np.deg2rad(tilt))
            else:
                d = pymust.txdelay(p, np.deg2rad(tilt), np.deg2rad(setup.diverging_width_deg))
            self.delays.append(np.asarray(d, float).reshape(1, -1))
        self.corners = dom.far_corners() * 1e-3
        self.seconds = 0.0
        self.calls = 0
        self._das = {}

    def rf(self, k: int, pts_mm: np.ndarray, amp: np.ndarray, chunk: int = 20000) -> np.ndarray:
        """RF (n_t, n_elements) of scatterers ``pts_mm`` (N, 2) for transmit k."""
        out = None
        n = max(len(pts_mm), 1)
        for i in range(0, n, chunk):
            p = pts_mm[i:i + chunk] * 1e-3
            a = amp[i:i + chunk]
            x = np.concatenate([self.corners[:, 0], p[:, 0]])
            z = np.concatenate([self.corners[:, 1], p[:, 1]])
            rc = np.concatenate([np.zeros(2), a])
            self.param.TXdelay = self.delays[k]
            t = time.perf_counter()
            rf = self.pm.simus(x, z, rc, self.delays[k], self.param, self.opt)[0]
            self.seconds += time.perf_counter() - t
            self.calls += 1
            out = rf if out is None else out + rf
        return out

    def iq(self, rf: np.ndarray) -> np.ndarray:
        """RF (n_t, n_el, K) -> I/Q of the same shape (down-mixing and a fixed low-pass)."""
        p = self.param
        return self.pm.rf2iq(rf, p.fs, p.fc, p.bandwidth)

    def beamform(self, k: int, iq: np.ndarray) -> np.ndarray:
        """I/Q (n_t, n_el, K) of transmit k -> beamformed (n_pix, K), pixels in bf-grid order."""
        n_t, n_el, n_k = iq.shape
        key = (k, n_t)
        if key not in self._das:
            self._das = {}  # one transmit's matrix at a time
            self.param.TXdelay = self.delays[k]
            self._das[key] = self.pm.dasmtx(
                1j * np.array([n_t, n_el]), self.dom.bf_x * 1e-3, self.dom.bf_z * 1e-3,
                self.delays[k], self.param, "linear")
        cols = iq.transpose(1, 0, 2).reshape(n_el * n_t, n_k)  # each column in Fortran order
        return self._das[key] @ cols


def _cell_area_mm2(scanner: _Scanner, dom: _Domain) -> float:
    """Area (mm^2) of the -6 dB region of the compounded point-spread function at mid-depth."""
    setup = scanner.setup
    zc = 0.5 * sum(setup.z_range_mm)
    box = 6.0 if dom.sector else 3.0  # half-width of the window around the point (mm)
    s = 0.04 if dom.sector else 0.02  # its pixel (mm)
    zz, xx = np.meshgrid(np.arange(zc - box, zc + box, s), np.arange(-box, box, s), indexing="ij")
    das = scanner.pm.dasmtx
    acc = 0.0
    for k in range(len(scanner.delays)):
        rf = scanner.rf(k, np.array([[0.0, zc]]), np.ones(1))
        iq = scanner.iq(rf)
        scanner.param.TXdelay = scanner.delays[k]
        m = das(1j * np.array(iq.shape), xx * 1e-3, zz * 1e-3, scanner.delays[k], scanner.param,
                "linear")
        acc = acc + m @ iq.reshape(-1, order="F")
    env = np.abs(acc)
    return float(np.count_nonzero(env >= 0.5 * env.max()) * s * s)


def _simulate(spec: SequenceSpec, log, scatterers_per_cell: float | None = None) -> dict:
    """All beamformed components of a sequence (compounded I/Q on the bf grid)."""
    setup = PROBES[spec.probe]
    if scatterers_per_cell is not None:
        setup = replace(setup, scatterers_per_cell=scatterers_per_cell)
    import pymust

    lam_mm = _C / pymust.getparam(setup.model).fc * 1e3
    dom = _Domain(setup, lam_mm)
    sc = _Scanner(setup, dom)
    rng = np.random.default_rng(spec.seed)
    cell = _cell_area_mm2(sc, dom)
    density = setup.scatterers_per_cell / cell
    tx, tz, ta = _tissue(spec, dom, density, rng)
    log(f"{spec.name}: cell {cell:.4f} mm2, {density:.0f} scatterers/mm2, {len(tx)} tissue "
        "scatterers")
    spacing = lam_mm / 8
    comps: list[tuple[str, np.ndarray, np.ndarray]] = [("tissue", np.stack([tx, tz], 1), ta)]
    if spec.interface is not None:
        comps.append(("interface", *_interface_line(spec, dom, spacing, rng)))
    needle = _Needle(spec) if spec.needle else None
    if needle is not None:
        # piece i: the shaft gained up to frame i (piece 0 from the skin line)
        bounds = np.concatenate([[0.0], needle.lengths])
        for i in range(spec.n_frames):
            comps.append((f"piece{i}", *_needle_piece(spec, needle, dom, bounds[i],
                                                      bounds[i + 1], spacing, rng)))
        for i, s in enumerate(needle.lengths):
            comps.append((f"bevel{i}", *_bevel(spec, needle, dom, s, spacing, rng)))
    n_needle_sc = sum(len(c[1]) for c in comps if c[0].startswith(("piece", "bevel")))
    log(f"{spec.name}: {n_needle_sc} needle scatterers, {len(comps)} components")
    names = [c[0] for c in comps]
    bf = None
    noise_bf = None
    for k in range(len(sc.delays)):
        t0 = time.perf_counter()
        rfs = [sc.rf(k, p, a) if len(p) else None for _, p, a in comps]
        shape = next(r.shape for r in rfs if r is not None)
        rfs = [np.zeros(shape) if r is None else r for r in rfs]
        tissue_rms = float(np.sqrt(np.mean(rfs[0] ** 2)))
        noise = rng.standard_normal((*shape, spec.n_frames)) * tissue_rms * 10 ** (
            -spec.snr_db / 20)
        stack = np.concatenate([np.stack(rfs, axis=2), noise], axis=2)
        out = sc.beamform(k, sc.iq(stack))
        part, npart = out[:, :len(comps)], out[:, len(comps):]
        bf = part if bf is None else bf + part
        noise_bf = npart if noise_bf is None else noise_bf + npart
        log(f"{spec.name}: transmit {k + 1}/{len(sc.delays)} in {time.perf_counter() - t0:.0f} s"
            f" (simus {sc.seconds:.0f} s over {sc.calls} calls)")
    shape = dom.bf_x.shape
    comp = {n: bf[:, i].reshape(shape, order="F") for i, n in enumerate(names)}
    noise_frames = [noise_bf[:, t].reshape(shape, order="F") for t in range(spec.n_frames)]
    return dict(dom=dom, needle=needle, comp=comp, noise=noise_frames, cell=cell,
                density=density, n_tissue=len(tx), n_needle=n_needle_sc, simus_s=sc.seconds,
                simus_calls=sc.calls, wavelength_mm=lam_mm, param=sc.param)


# -- display and labels ------------------------------------------------------------------------

