"""The external in-plane test set: needle sequences simulated with PyMUST, not with synth.

Run ``python -m needlenet.bench.external.generate --out DIR [--only NAME ...]``; it writes one
sequence file per entry of :data:`SPECS` (``DIR/NAME.npz``); ``--set axial`` writes the axial
set instead (:mod:`.axial_generate`), ``--set volume`` the volume set (:mod:`.volume_generate`).
PyMUST (``pip install 'needlenet[external]'``) is imported by the generator only; the runtime
never needs it.

Image formation, per sequence and per transmit (PyMUST ``simus``, 2D, a linear model with single
scattering, so the RF of a sum of scatterer sets is the sum of their RFs):

- the tissue RF is simulated once (the echogenicity map, a vessel and the diffuse band of an
  interface are amplitudes of the tissue scatterers);
- the needle is cut into the length it gains between frames; each piece (two walls of the
  gauge's diameter, dense equal-phase scatterers with a little roughness, and reverberation
  copies below them) is simulated once, and the bevel at the tip once per frame;
- frame t's RF = tissue + interface line + the pieces inserted by frame t + the bevel at t
  + electronic noise drawn for frame t; frames are beamformed (``dasmtx``) and compounded.

Every simus call also holds two zero-amplitude scatterers at the far corners of the simulated
domain, so all calls share one frequency grid and one RF length and the sum is exact. The
needle and interface amplitudes are scaled after beamforming so that, on the 8-bit image, the
mean grey within 0.3 mm of the reflector's probe-facing surface is the spec's multiple of the
same pixels' mean grey without it (the needle on the last frame). Each file also carries Zhao
2013's eq. (9) contrast per frame (``contrast_ratio``, as ``synth.contrast_ratio``).

Frames are 8-bit: a fixed depth gain (TGC) flattens the tissue's median envelope, the display
gain puts the tissue's mean grey at the spec's value, then grey = 255 * ((dB + DR) / DR) ** gamma.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
from scipy import ndimage

import synth

from .scene import CONTRAST_RADIUS_MM
from .simulate import _simulate
from .specs import PROBES, SETS, SPECS, ProbeSetup, SequenceSpec

__all__ = ["PROBES", "SPECS", "ProbeSetup", "SequenceSpec", "generate", "main"]


def _grey(env: np.ndarray, white_db: float, spec: SequenceSpec) -> np.ndarray:
    db = 20 * np.log10(np.maximum(env, 1e-30)) - white_db
    u = np.clip((db + spec.dynamic_range_db) / spec.dynamic_range_db, 0.0, 1.0) ** spec.gamma
    return np.round(255 * u).astype(np.uint8)


def _bisect(f, lo, hi, target, n=30):
    """The smallest x in [lo, hi] with f(x) = target (log-spaced search): f is scanned on a
    coarse grid for its first crossing, which is then bisected; where f never reaches the
    target, the x of its largest value."""
    xs = np.geomspace(lo, hi, 33)
    fs = np.array([f(x) for x in xs])
    above = np.flatnonzero(fs >= target)
    if len(above) == 0:  # out of reach: the first x within 95% of the largest value
        return float(xs[np.flatnonzero(fs >= 0.95 * np.nanmax(fs))[0]])
    if above[0] == 0:
        return float(xs[0])
    a, b = np.log(xs[above[0] - 1]), np.log(xs[above[0]])
    for _ in range(n):
        m = 0.5 * (a + b)
        if f(np.exp(m)) < target:
            a = m
        else:
            b = m
    return float(np.exp(0.5 * (a + b)))


def _near(grid, pts: np.ndarray, radius_mm: float) -> np.ndarray:
    """Flat indices of the pixels within ``radius_mm`` of a polyline."""
    return synth.tube_indices(grid, pts, radius_mm)


def _local_contrast(image: np.ndarray, without: np.ndarray, idx: np.ndarray) -> float:
    """Mean grey over ``idx`` of ``image`` over that of the same frame without the object.

    ``idx`` holds the pixels within CONTRAST_RADIUS_MM of the surface that faces the probe (the
    needle's upper wall, the interface line), over the part in view.
    """
    bg = without.reshape(-1)[idx].astype(float).mean()
    return float(image.reshape(-1)[idx].astype(float).mean() / max(bg, 1e-9))


def _tgc_gain(tissue_iq: np.ndarray, dom) -> np.ndarray:
    """TGC: a fixed gain per depth (per radius for sectors) that flattens the tissue's median
    envelope; (n_rows, 1) on the beamforming grid."""
    prof = np.median(np.abs(tissue_iq), axis=1)
    step = np.diff(dom.bf_z[:, 0])[0] if not dom.sector else dom.r[1] - dom.r[0]
    prof = ndimage.gaussian_filter1d(prof, sigma=1.0 / step, mode="nearest")
    return (1.0 / np.maximum(prof, prof.max() * 1e-6))[:, None]


def _white_level(base_env: np.ndarray, valid: np.ndarray, spec) -> float:
    """The display gain (dB of white) that puts the tissue's mean grey at
    ``spec.tissue_grey`` (mean grey falls as white rises)."""

    def mean_grey(white_db):
        return float(_grey(base_env, white_db, spec)[valid].mean())

    ref = 20 * np.log10(np.percentile(base_env[valid], 50))
    lo, hi = ref - 10.0, ref + spec.dynamic_range_db + 30.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if mean_grey(mid) > spec.tissue_grey:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _compose(sim: dict, spec: SequenceSpec):
    """Frames, labels and the achieved contrast of a simulated sequence."""
    dom, comp, needle = sim["dom"], sim["comp"], sim["needle"]
    grid = synth.Grid((dom.nz, dom.nx), tuple(dom.spacing_mm), tuple(dom.origin_mm))
    T = spec.n_frames
    gain = _tgc_gain(comp["tissue"], dom)

    def env_image(iq):
        return dom.to_image(np.abs(iq) * gain)

    valid = dom.valid
    base = comp["tissue"] + sim["noise"][0]
    base_env = env_image(base)
    white = _white_level(base_env, valid, spec)

    iface_scale = 0.0
    if spec.interface is not None:
        x0, z0, slope = spec.interface
        t = np.deg2rad(slope)
        u = np.array([np.cos(t), np.sin(t)])
        line = np.array([x0, z0]) + np.arange(-200, 200, 0.05)[:, None] * u
        line = line[dom.in_image(line[:, 0], line[:, 1])]

        near_line = _near(grid, line, CONTRAST_RADIUS_MM)

        def iface_cr(scale):
            im = _grey(env_image(base + scale * comp["interface"]), white, spec)
            return _local_contrast(im, base_im, near_line)

        base_im = _grey(base_env, white, spec)
        iface_scale = _bisect(iface_cr, 1e-4, 1e4, spec.interface_cr)
        base = base + iface_scale * comp["interface"]

    pieces = np.zeros((T, *base.shape), complex)
    needle_scale = 0.0
    if needle is not None:
        acc = np.zeros(base.shape, complex)
        for i in range(T):
            acc = acc + comp[f"piece{i}"]
            pieces[i] = acc + comp[f"bevel{i}"]

    def shaft_pts(i, offset_mm=0.0):
        s = np.arange(0.0, needle.lengths[i], 0.05)
        p = needle.axis(s) + offset_mm * needle.n_up
        return p[dom.in_image(p[:, 0], p[:, 1])]

    def wall_near(i):
        return _near(grid, shaft_pts(i, needle.r), CONTRAST_RADIUS_MM)

    if needle is not None:
        last = base - sim["noise"][0] + sim["noise"][T - 1]

        last_im = _grey(env_image(last), white, spec)
        near_last = wall_near(T - 1)

        def needle_cr(scale):
            im = _grey(env_image(last + scale * pieces[T - 1]), white, spec)
            return _local_contrast(im, last_im, near_last)

        needle_scale = _bisect(needle_cr, 1e-4, 1e4, spec.target_cr)

    images = np.zeros((T, dom.nz, dom.nx), np.uint8)
    tip = np.full((T, 2), np.nan)
    direction = np.full((T, 2), np.nan)
    entry = np.zeros((T, 2))
    visible = np.zeros(T, bool)
    cr = np.full(T, np.nan)
    local = np.full(T, np.nan)
    centerline = np.zeros((T, 32, 2))
    shaft_in_view = np.zeros(T)
    static = base - sim["noise"][0]
    for i in range(T):
        bare = static + sim["noise"][i]
        images[i] = _grey(env_image(bare + needle_scale * pieces[i]), white, spec)
        if needle is None:
            continue
        s = needle.lengths[i]
        tip[i] = needle.axis(s)
        direction[i] = needle.d
        entry[i] = needle.entry
        centerline[i] = needle.axis(np.linspace(0.0, s, 32))
        pts = shaft_pts(i)
        shaft_in_view[i] = 0.05 * len(pts)
        visible[i] = bool(dom.in_image(*tip[i])) and shaft_in_view[i] >= 3.0
        cr[i] = synth.contrast_ratio(images[i], grid, pts, needle.r, valid=valid)
        local[i] = _local_contrast(images[i], _grey(env_image(bare), white, spec), wall_near(i))
    return dict(images=images, tip=tip, direction=direction, entry=entry, visible=visible,
                cr=cr, local=local, centerline=centerline, white_db=white,
                needle_scale=needle_scale, interface_scale=iface_scale, grid=grid,
                shaft_in_view=shaft_in_view)



def common_meta(spec, setup: ProbeSetup, needle_radius_mm: float | None) -> dict:
    """The ``meta`` entries every sequence of an external set carries (in-plane, axial or
    volume): where it comes from, its spec, probe and needle."""
    return {
        "source": "pymust",
        "pymust_version": _version("pymust"),
        "scenario": spec.name,
        "seed": spec.seed,
        "needle": spec.needle,
        "probe": spec.probe,
        "probe_setup": asdict(setup),
        "spec": asdict(spec),
        "gauge": spec.gauge if spec.needle else None,
        "needle_radius_mm": needle_radius_mm,
    }

def run_meta(sim: dict, res: dict, t0: float) -> dict:
    """The ``meta`` entries of how an axial or volume sequence was made: the transmit's
    wavelength and centre frequency, the display's white level, the needle's and interface's
    echo scales, and the time taken (``t0``: ``time.perf_counter()`` at the start)."""
    return {
        "wavelength_mm": sim["wavelength_mm"],
        "fc_hz": float(sim["param"].fc),
        "display_white_db": res["white_db"],
        "needle_scale": res["needle_scale"],
        "interface_scale": res["interface_scale"],
        "simus_s": round(sim["simus_s"], 1),
        "simus_calls": sim["simus_calls"],
        "generation_s": round(time.perf_counter() - t0, 1),
    }


def generate(spec: SequenceSpec, out_dir: Path, log=print,
             scatterers_per_cell: float | None = None) -> Path:
    """Simulate one sequence and write ``out_dir/NAME.npz``."""
    t0 = time.perf_counter()
    sim = _simulate(spec, log, scatterers_per_cell)
    res = _compose(sim, spec)
    setup = PROBES[spec.probe]
    dom = sim["dom"]
    meta = {
        **common_meta(spec, setup, sim["needle"].r if spec.needle else None),
        "side": spec.side if spec.needle else None,
        "angle_deg": spec.angle_deg if spec.needle else None,
        "target_cr": spec.target_cr if spec.needle else None,
        "needle_tissue_contrast": ([round(float(v), 3) for v in res["local"]]
                                   if spec.needle else None),
        "contrast_ratio_eq9": "per-frame key contrast_ratio: Zhao 2013 eq. 9 (synth)",
        "feature": spec.feature,
        "sector": ({"apex_mm": [0.0, 0.0], "half_angle_deg": setup.sector_half_angle_deg,
                    "r_mm": list(dom.r_lim)} if dom.sector else None),
        "resolution_cell_mm2": sim["cell"],
        "scatterers_per_mm2": sim["density"],
        "n_tissue_scatterers": sim["n_tissue"],
        "n_needle_scatterers": sim["n_needle"],
        "wavelength_mm": sim["wavelength_mm"],
        "fc_hz": float(sim["param"].fc),
        "fs_hz": float(sim["param"].fs),
        "display_white_db": res["white_db"],
        "needle_scale": res["needle_scale"],
        "interface_scale": res["interface_scale"],
        "shaft_in_view_mm": [round(float(v), 2) for v in res["shaft_in_view"]],
        "simus_s": round(sim["simus_s"], 1),
        "simus_calls": sim["simus_calls"],
        "generation_s": round(time.perf_counter() - t0, 1),
        "centerline_frame": "image (x, z) mm, from the skin crossing to the tip",
        "command": f"python -m needlenet.bench.external.generate --out DIR --only {spec.name}",
    }
    T = spec.n_frames
    kw = dict(images=res["images"], spacing_mm=dom.spacing_mm, origin_mm=dom.origin_mm,
              modality="inplane", timestamps_s=np.arange(T) / spec.frame_rate_hz,
              dynamic_range_db=float(spec.dynamic_range_db), meta=meta,
              tip_mm=res["tip"], direction=res["direction"], visible=res["visible"],
              contrast_ratio=res["cr"])
    if spec.needle:
        kw.update(entry_mm=res["entry"], centerline_mm=res["centerline"])
    seq = synth.Sequence(**kw)
    out = synth.save_sequence(seq, Path(out_dir) / f"{spec.name}.npz", overwrite=True)
    log(f"{spec.name}: wrote {out} in {time.perf_counter() - t0:.0f} s "
        f"(simus {sim['simus_s']:.0f} s); needle contrast {res['local'][-1]:.2f}, "
        f"Zhao CR {res['cr'][-1]:.2f}")
    return out


def _version(pkg: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(pkg)
    except PackageNotFoundError:
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m needlenet.bench.external.generate",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path, help="directory for the .npz files")
    ap.add_argument("--set", choices=sorted(SETS) + ["axial", "axial-validation", "volume",
                                                     "volume-validation"],
                    default="test",
                    help="the test set (needlenet/data/external), the validation set for "
                         "choosing between models, the axial test set "
                         "(needlenet/data/external_axial) or its validation set "
                         "(needlenet/data/validation_axial), the volume test set "
                         "(needlenet/data/external_volume) or its validation set "
                         "(needlenet/data/validation_volume) (default: test)")
    ap.add_argument("--only", nargs="+", metavar="NAME", help="generate these sequences only")
    ap.add_argument("--frames", type=int, help="override the frame count (quick looks only)")
    ap.add_argument("--scatterers-per-cell", type=float,
                    help="override the speckle density (quick looks only)")
    args = ap.parse_args(argv)
    try:
        import pymust  # noqa: F401
    except ImportError:
        print("the generator needs PyMUST: pip install 'needlenet[external]'", file=sys.stderr)
        return 2
    if args.set in ("axial", "axial-validation"):
        from .axial_generate import generate_axial
        from .axial_specs import AXIAL_SPECS, AXIAL_VALIDATION_SPECS

        chosen = AXIAL_SPECS if args.set == "axial" else AXIAL_VALIDATION_SPECS
        make = generate_axial
    elif args.set in ("volume", "volume-validation"):
        from .volume_generate import generate_volume
        from .volume_specs import VOLUME_SETS

        chosen, make = VOLUME_SETS[args.set], generate_volume
    else:
        chosen, make = SETS[args.set], generate
    names = {s.name for s in chosen}
    if args.only:
        unknown = sorted(set(args.only) - names)
        if unknown:
            ap.error(f"unknown sequence(s) {unknown}; known: {sorted(names)}")
    args.out.mkdir(parents=True, exist_ok=True)
    specs = [s for s in chosen if not args.only or s.name in args.only]
    t0 = time.perf_counter()
    for spec in specs:
        if args.frames:
            key = "n_volumes" if args.set.startswith("volume") else "n_frames"
            spec = replace(spec, **{key: args.frames})
        make(spec, args.out, log=lambda m: print(m, flush=True),
             scatterers_per_cell=args.scatterers_per_cell)
    print(f"done: {len(specs)} sequences in {time.perf_counter() - t0:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
