"""``needlenet bench synth``: simulator speed and speckle statistics.

Speed is measured after a warm-up (numba compiles its kernels once per install). For each
scenario we report the world set-up time (scatterers, the tissue field of a moving probe)
separately from the per-frame time, which includes the needle echo, shadow, electronic noise,
log compression and the exact labels of every frame.
"""

from __future__ import annotations

import numpy as np

import synth

# name, scenario, overrides, frames (quick, full), unit
CASES = [
    # Mathiassen's insertions run from 11 to 46 mm: 70 frames at 10 mm/s and 20 frames/s
    ("inplane 256x256 @0.2 mm, static probe", "inplane",
     {"spacing_mm": 0.2, "width_mm": 51.2, "depth_mm": 51.2, "speed_mm_s": 10.0}, (40, 70)),
    ("inplane 500x384 @0.1 mm (Mathiassen)", "inplane", {"speed_mm_s": 10.0}, (20, 70)),
    ("axial 128x128 @0.3 mm, probe stepped 0.5 mm", "axial", {}, (100, 200)),
    ("servo 128x128 @0.3 mm, probe following the tip", "servo", {"start_sample": 200},
     (100, 500)),
    ("volume 128^3 (Zhao sector), static probe", "volume", {"alpha_deg": 30.0}, (6, 20)),
    ("volume 128^3, moving phantom (Chatelain)", "volume-motion", {"output_size": 128}, (6, 20)),
]


def _speckle_rows(seed: int) -> list[dict]:
    p = synth.ImagingParams(noise_db=-200.0)
    z0 = p.tx_focus_mm
    probe = synth.PlaneProbe(width_mm=24, depth_mm=8, spacing_mm=(0.025, 0.05),
                             depth_start_mm=z0 - 4)
    world = synth.World(synth.Tissue(p.scatterer_density(probe.range_of_rows()), seed), None)
    iq = synth.Scanner(probe, p, world).tissue_iq(np.eye(4))
    env = np.hypot(iq[..., 0], iq[..., 1])[20:-20, 20:-20]
    img = synth.log_compress(env, p)
    ax, lat = synth.speckle_fwhm(env, probe.grid.spacing_mm)
    fa, fl, _ = p.psf_fwhm_mm(z0)
    return [
        {"metric": "envelope SNR (mean/std)", "value": synth.envelope_snr(env),
         "target": "1.91 +- 0.1"},
        {"metric": "log-compressed std (dB)", "value": synth.log_std_db(img, p.dynamic_range_db),
         "target": "5.57 +- 0.3"},
        {"metric": "axial speckle FWHM / PSF FWHM", "value": ax / fa, "target": "1 +- 0.2"},
        {"metric": "lateral speckle FWHM / PSF FWHM", "value": lat / fl, "target": "1 +- 0.2"},
        {"metric": "scatterers per resolution cell", "value": p.scatterers_per_cell,
         "target": ">= 10"},
    ]


def run(quick: bool = False, seed: int = 0, log=print, rows=None, tier=None) -> dict:
    quick = quick or (tier is not None and tier != "full")
    # warm-up: compile the kernels and touch every code path once
    synth.generate("inplane", seed=seed, frames=2, width_mm=8.0, depth_mm=8.0,
                   start_length_mm=12.0)
    synth.generate("volume", seed=seed, frames=1, output_size=32)
    synth.generate("volume-motion", seed=seed, frames=2, output_size=32,
                   scatterers_per_cell=1.0)  # the cell cache of a moving 3D probe
    rows = [] if rows is None else rows
    for name, scenario, kw, frames in CASES:
        n = frames[0] if quick else frames[1]
        t: dict = {}
        seq = synth.generate(scenario, seed=seed, timings=t, frames=n, **kw)
        fs = np.asarray(t["frame_s"])
        setup = t["prepare_s"] + fs[0]
        rest = fs[1:] if len(fs) > 1 else fs
        row = {
            "suite": "synth", "case": name, "scenario": scenario, "frames": int(seq.n_frames),
            "shape": list(seq.images.shape[1:]), "seed": seed,
            "setup_s": float(setup), "median_ms": float(np.median(rest) * 1e3),
            "p99_ms": float(np.percentile(rest, 99) * 1e3),
            "frames_per_s": float(len(rest) / rest.sum()),
        }
        rows.append(row)
        log(f"{name:50s} setup {row['setup_s']:6.2f} s   {row['frames_per_s']:7.1f} frames/s "
            f"(median {row['median_ms']:.2f} ms, p99 {row['p99_ms']:.2f} ms)")
    speckle = _speckle_rows(seed)
    for r in speckle:
        log(f"{r['metric']:50s} {r['value']:.3f}   (target {r['target']})")
    return {"rows": rows, "speckle": speckle}


def markdown(result: dict, machine: dict) -> str:
    lines = [f"Machine: {machine['cpu']}, {machine['cores']} cores, Python {machine['python']}",
             "", "| case | frame | world set-up (s) | frames/s | median ms | p99 ms |",
             "|---|---|---|---|---|---|"]
    for r in result["rows"]:
        shape = "x".join(str(s) for s in r["shape"])
        lines.append(f"| {r['case']} | {shape} | {r['setup_s']:.2f} | {r['frames_per_s']:.1f} | "
                     f"{r['median_ms']:.2f} | {r['p99_ms']:.2f} |")
    lines += ["", "| speckle check | measured | target |", "|---|---|---|"]
    for r in result["speckle"]:
        lines.append(f"| {r['metric']} | {r['value']:.3f} | {r['target']} |")
    return "\n".join(lines)
