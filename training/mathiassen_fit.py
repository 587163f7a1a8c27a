"""Fit the weights w of Mathiassen 2017's tip function h(x) = w^T E(x) (eq. 6).

Run ``python -m training.mathiassen_fit`` to rewrite
``needlenet/data/mathiassen_weights.json`` (a few minutes of CPU, deterministic: the same
command gives the same file).

What it does, following sections II-E and III-A:

1. Training data as the paper's training experiment (Table I, data set 1): six insertions, one
   per combination of 35/45 degrees and 5/10/15 mm/s, from 11 to 46 mm of needle (513 frames
   in the paper, 520 here), on synth sequences with seeds 1000-1005 and an inhomogeneous
   background.
2. On every frame the axis is estimated as the original method does it (Algorithm 2, +-5
   degrees around the insertion angle, no feedback) and the five features are computed along
   it. The search finds the needle's upper-wall echo; the median distance from that line to
   the true tip across the needle is stored as ``axis_offset_mm`` (the runtime adds it to
   report the centre line). Only frames whose estimated axis passes within 3 mm of the true
   tip (|p_p - p_hat_p| < 3 mm, section III-A) are kept.
3. The weights minimise eq. (24), sum_i |p_i - p_hat_i| with p_hat_i the point of the axis at
   the maximum of h. The paper uses a genetic algorithm; eq. (24) is piecewise constant in w,
   so we do the same: a seeded (mu + lambda) evolution strategy on the unit sphere (only the
   direction of w matters for the argmax), started from the linear least-squares fit of h to a
   Gaussian bump at the true tip (the closed-form problem, kept in the file as
   ``weights_lstsq``). The median distance along the axis from the maximum of h to the true
   tip is stored as ``tip_offset_mm`` (the edges the features respond to lie a little beyond
   the tip), and added at run time like ``axis_offset_mm``; ``train_tip_error_mm`` reports
   eq. (24) before and the tip errors after both calibrations.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from needlenet.features import (
    MathiassenParams,
    estimate_axis,
    tip_features,
    weights_path,
)

__all__ = ["FitConfig", "fit", "training_data", "main"]

COMMAND = "python -m training.mathiassen_fit"
FEATURE_NAMES = ["E1 grayscale", "E2 difference image (delta frames)", "E3 K^SQ",
                 "E4 K^G''", "E5 K^SQ shifted n below the axis"]


@dataclasses.dataclass(frozen=True)
class FitConfig:
    """What :func:`fit` trains on and how. The defaults reproduce the shipped file."""

    seeds: tuple[int, ...] = (1000, 1001, 1002, 1003, 1004, 1005)
    # (angle_deg, speed_mm_s), one per seed, as the paper's six training insertions
    combos: tuple[tuple[float, float], ...] = ((35.0, 5.0), (35.0, 10.0), (35.0, 15.0),
                                               (45.0, 5.0), (45.0, 10.0), (45.0, 15.0))
    background: str = "inhomogeneous"
    frames: int | None = None  # None: the scenario's 11 -> 46 mm insertion
    axis_tolerance_mm: float = 3.0  # section III-A
    lstsq_sigma_mm: float = 0.5  # width of the target bump of the least-squares start
    population: int = 48
    generations: int = 120
    mutation: float = 0.15
    rng_seed: int = 0


def training_data(config: FitConfig, params: MathiassenParams | None = None,
                  verbose: bool = False) -> dict:
    """Features along the estimated axis of every training frame, with the truth.

    Returns ``E`` (n_frames, 5, n_max) padded with NaN, ``x_true`` (n_frames,) the true tip
    projected on the estimated axis (mm from the ROI corner), ``perp`` (n_frames,) its distance
    from the estimated line echo along v_p, and ``x_mm`` (n_max,) the sample positions.
    """
    import synth

    p = MathiassenParams() if params is None else params
    if len(config.seeds) != len(config.combos):
        raise ValueError("FitConfig: one (angle, speed) combination per seed")
    feats, x_true, perp, step = [], [], [], None
    for seed, (angle, speed) in zip(config.seeds, config.combos, strict=True):
        t0 = time.perf_counter()
        seq = synth.generate("inplane", seed=seed, frames=config.frames, angle_deg=angle,
                             speed_mm_s=speed, background=config.background)
        grid = seq.grid()
        images = seq.images.astype(np.float32) / np.float32(255.0)
        for k in range(seq.n_frames):
            axis = estimate_axis(images[k], grid, p, theta_centre_deg=angle)
            prev = images[k - min(k, p.delta_frames)] if k > 0 else None
            f = tip_features(images[k], prev, grid, axis, p)
            rel = seq.tip_mm[k] - axis.anchor_mm
            feats.append(f.E)
            x_true.append(float(rel @ axis.direction))
            perp.append(float(rel @ axis.normal - axis.p_p_mm))
            step = float(f.x_mm[1] - f.x_mm[0])
        if verbose:
            print(f"seed {seed}: {angle:g} deg, {speed:g} mm/s, {seq.n_frames} frames "
                  f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    n_max = max(e.shape[1] for e in feats)
    E = np.full((len(feats), feats[0].shape[0], n_max), np.nan)
    for i, e in enumerate(feats):
        E[i, :, :e.shape[1]] = e
    return {"E": E, "x_true": np.array(x_true), "perp": np.array(perp),
            "x_mm": step * np.arange(n_max)}


def _tip_errors(W: np.ndarray, E: np.ndarray, x_mm: np.ndarray, x_true: np.ndarray,
                perp: np.ndarray) -> np.ndarray:
    """|p_i - p_hat_i| of eq. (24) for every weight vector (rows of W) and frame: (P, F)."""
    h = np.einsum("pf,nfx->pnx", W, np.nan_to_num(E, nan=0.0))
    h = np.where(np.isnan(E[:, 0])[None], -np.inf, h)
    x_hat = x_mm[np.argmax(h, axis=2)]  # p_hat: the maximum of h(x)
    return np.hypot(x_true[None] - x_hat, perp[None])


def _tip_positions(w: np.ndarray, E: np.ndarray, x_mm: np.ndarray) -> np.ndarray:
    h = np.einsum("f,nfx->nx", w, np.nan_to_num(E, nan=0.0))
    return x_mm[np.argmax(np.where(np.isnan(E[:, 0]), -np.inf, h), axis=1)]


def _lstsq_weights(E: np.ndarray, x_mm: np.ndarray, x_true: np.ndarray, sigma: float
                   ) -> np.ndarray:
    """Least squares of h(x) + c onto exp(-(x - x_true)^2 / 2 sigma^2) over all samples."""
    valid = ~np.isnan(E[:, 0])
    A = np.moveaxis(E, 1, 2)[valid]  # (samples, 5)
    target = np.exp(-0.5 * ((x_mm[None, :] - x_true[:, None]) / sigma) ** 2)[valid]
    A = np.hstack([A, np.ones((A.shape[0], 1))])
    w, *_ = np.linalg.lstsq(A, target, rcond=None)
    return w[:-1]


def _unit(w: np.ndarray) -> np.ndarray:
    return w / np.linalg.norm(w, axis=-1, keepdims=True)


def _evolve(E, x_mm, x_true, perp, w0, config: FitConfig) -> tuple[np.ndarray, float]:
    """(mu + lambda) evolution strategy minimising eq. (24) on the unit sphere."""
    rng = np.random.default_rng(config.rng_seed)
    n_f = E.shape[1]
    P = config.population
    start = np.vstack([w0, np.eye(n_f), -np.eye(n_f),
                       w0 + config.mutation * rng.standard_normal((P - 1 - 2 * n_f, n_f))])
    pop = _unit(start)
    cost = _tip_errors(pop, E, x_mm, x_true, perp).sum(axis=1)
    for _ in range(config.generations):
        parents = pop[np.argsort(cost)[: P // 4]]
        pick = rng.integers(0, len(parents), (P, 2))
        mix = rng.random((P, 1))
        children = mix * parents[pick[:, 0]] + (1 - mix) * parents[pick[:, 1]]  # crossover
        children = _unit(children + config.mutation * rng.standard_normal(children.shape))
        child_cost = _tip_errors(children, E, x_mm, x_true, perp).sum(axis=1)
        allw = np.vstack([pop, children])
        allc = np.concatenate([cost, child_cost])
        keep = np.argsort(allc, kind="stable")[:P]  # elitist survivor selection
        pop, cost = allw[keep], allc[keep]
    return pop[0], float(cost[0])


def fit(config: FitConfig | None = None, params: MathiassenParams | None = None,
        verbose: bool = False) -> dict:
    """Fit the weights; returns the JSON document (not written)."""
    cfg = FitConfig() if config is None else config
    p = MathiassenParams() if params is None else params
    data = training_data(cfg, p, verbose)
    E, x_true, perp, x_mm = data["E"], data["x_true"], data["perp"], data["x_mm"]
    near = np.abs(perp) < cfg.axis_tolerance_mm
    offset = float(np.median(perp[near])) if near.any() else 0.0
    keep = np.abs(perp - offset) < cfg.axis_tolerance_mm  # section III-A
    if keep.sum() < 10:
        raise RuntimeError(f"only {int(keep.sum())} training frames have an axis within "
                           f"{cfg.axis_tolerance_mm} mm of the truth")
    E, x_true, perp_c = E[keep], x_true[keep], perp[keep] - offset
    scale = np.nanstd(np.moveaxis(E, 1, 2).reshape(-1, E.shape[1]), axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    Es = E / scale[None, :, None]  # standardised features: the search sees a round problem
    w_ls = _unit(_lstsq_weights(Es, x_mm, x_true, cfg.lstsq_sigma_mm))
    w_ga, cost = _evolve(Es, x_mm, x_true, perp_c, w_ls, cfg)
    # the features' edges lie a little beyond the tip (the echo's blur): the median residual
    # along the axis is stored and added to the maximum of h at run time
    x_hat = _tip_positions(w_ga, Es, x_mm)
    tip_offset = float(np.median(x_true - x_hat))
    err_ga = np.hypot(x_true - x_hat - tip_offset, perp_c)
    x_ls = _tip_positions(w_ls, Es, x_mm)
    err_ls = np.hypot(x_true - x_ls - np.median(x_true - x_ls), perp_c)
    raw = _unit(w_ga / scale)
    raw_ls = _unit(w_ls / scale)
    return {
        "weights": raw.round(10).tolist(),
        "weights_lstsq": raw_ls.round(10).tolist(),
        "features": FEATURE_NAMES,
        "axis_offset_mm": round(offset, 6),
        "tip_offset_mm": round(tip_offset, 6),
        "criterion": "Mathiassen 2017 eq. (24): sum_i |p_i - p_hat_i|, (mu+lambda) evolution "
                     "strategy started from the least-squares fit",
        "command": COMMAND,
        "seeds": list(cfg.seeds),
        "scenario": "inplane",
        "combos_angle_deg_speed_mm_s": [list(c) for c in cfg.combos],
        "background": cfg.background,
        "frames_total": int(len(data["x_true"])),
        "frames_used": int(keep.sum()),
        "train_tip_error_mm": {
            "lstsq_median": round(float(np.median(err_ls)), 4),
            "lstsq_p95": round(float(np.percentile(err_ls, 95)), 4),
            "eq24_sum": round(cost, 4),
            "median": round(float(np.median(err_ga)), 4),
            "p95": round(float(np.percentile(err_ga, 95)), 4),
        },
        "fit_config": dataclasses.asdict(cfg),
        "params": dataclasses.asdict(p),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog=COMMAND, description=__doc__.split("\n\n")[0])
    ap.add_argument("--output", type=Path, default=None,
                    help="where to write the JSON (default: the package's data file)")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    out = weights_path() if args.output is None else args.output
    t0 = time.perf_counter()
    doc = fit(verbose=not args.quiet)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=1) + "\n")
    if not args.quiet:
        print(f"wrote {out} in {time.perf_counter() - t0:.0f} s: weights {doc['weights']}, "
              f"train tip error {doc['train_tip_error_mm']}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
