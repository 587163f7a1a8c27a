"""``needlenet bench models``: the shipped learned models on held-out synth data, and their
onnxruntime latency.

Held-out data: the papers' protocol scenarios (``inplane``, ``axial``, ``volume``) with seeds
never used in training (training draws seeds below 10,000,000; these start at 20,000,000),
inhomogeneous backgrounds and a contrast ratio of 2.0 (Zhao eq. 9). The imaging is the
scenario's own, which the training stream only saw as one draw among many.

Metrics per frame, on the frame's grid, through the runtime path the trackers use:
- shaft AUC: positives within one needle radius of the labelled needle (its centre line, or for
  a ``target_reference = "wall"`` model the wall facing the probe), negatives farther than
  three radii (pixels in between are ambiguous and left out);
- tip: the maximum of the tip map against the labelled tip, on frames where the tip is visible
  (for a model that marks the wall facing the probe, ``target_reference = "wall"``, against the
  tip of that wall: the labelled tip moved by the needle's radius across the shaft).

For volumes two more tips on the same frames, to read the tip map against: the image's own
tip given the true axis (:func:`axis_changepoint_tip`, a bound, not a tracker), and the tip
the ``ransac`` volume tracker measures on the volume alone with the model's maps (what a user
of the model gets from one volume).
"""

from __future__ import annotations

import math
import time

import numpy as np

import synth

from ..eval import roc_auc
from ..features import (
    FeatureSource,
    Frame,
    LearnedFeatures,
    Likelihood,
    shipped_model_path,
    wall_offsets,
)
from ..trackers.volume import VolumeTracker

HELD_OUT_SEED = 20_000_000
CASES = {
    "inplane": ("inplane", {"spacing_mm": 0.2, "width_mm": 38.4, "depth_mm": 50.0,
                            "imaging_overrides": {"tissue_gray": 50.0}}),  # CR 2 fits 8 bits
    "axial": ("axial", {"insertion_mm": 40.0}),
    "volume": ("volume", {"output_size": 96}),
}
LATENCY_SIZES = {
    "inplane": [(256, 256)],
    "axial": [(128, 128)],
    "volume": [(32, 32, 64), (128, 128, 128)],
}


def _distances(seq, i, grid, wall: bool = False):
    """Distance of every grid point to frame i's needle: its centre line, or (``wall``) the
    wall facing the probe, where a ``target_reference = "wall"`` model marks it."""
    cl = np.asarray(seq.centerline_mm[i], float)
    if wall:
        cl = cl + wall_offsets(cl, float(seq.meta["needle"]["radius_mm"]))
    d = synth.distance_to_polyline(_grid_points(grid), cl)
    return d.reshape(grid.shape)


def _grid_points(grid) -> np.ndarray:
    """Every grid point (N, 3) in mm, point order (x, y, z); y = 0 on a 2D (x, z) grid."""
    axes = np.meshgrid(*[grid.axis_coords(a) for a in range(grid.ndim)], indexing="ij")
    if grid.ndim == 2:
        return np.stack([axes[1].ravel(), np.zeros(axes[0].size), axes[0].ravel()], -1)
    return np.stack([axes[2].ravel(), axes[1].ravel(), axes[0].ravel()], -1)


def map_peak(m: np.ndarray, half: int = 3) -> np.ndarray:
    """Sub-pixel index of a map's maximum: the centroid of the map above half its maximum in
    a (2 half + 1)^D window around the arg-max (the model's stride-2 output, linearly
    upsampled, is otherwise quantised to its own grid)."""
    idx = np.array(np.unravel_index(int(np.argmax(m)), m.shape))
    lo = np.maximum(idx - half, 0)
    hi = np.minimum(idx + half + 1, m.shape)
    win = m[tuple(slice(a, b) for a, b in zip(lo, hi, strict=True))].astype(float)
    w = np.maximum(win - 0.5 * float(m.flat[np.ravel_multi_index(tuple(idx), m.shape)]), 0.0)
    if w.sum() <= 0:
        return idx.astype(float)
    grids = np.meshgrid(*[np.arange(a, b) for a, b in zip(lo, hi, strict=True)], indexing="ij")
    return np.array([(g * w).sum() / w.sum() for g in grids])


def axis_changepoint_tip(image: np.ndarray, grid, centerline: np.ndarray, radius_mm: float,
                         window_mm: float = 4.0, bin_mm: float = 0.25,
                         ring_mm: tuple[float, float] | None = (2.0, 3.0)) -> np.ndarray:
    """The tip found on the image alone, given the needle's true axis: the change point of the
    mean intensity along the axis (the position that maximises the mean of the voxels within
    a radius of the axis over ``window_mm`` behind it minus the mean over ``window_mm`` ahead),
    of the needle's excess over the tissue around it when ``ring_mm`` (inner, outer radius)
    is given: the means of the voxels in that ring over the same windows are subtracted, as
    the volume tracker does (``VolumeTrackerParams.image_tip_background_mm``).

    Not a tracker (it is told the axis): a bound on what the image holds at the tip, to read
    a tip map's accuracy against. Only the line through ``centerline``'s ends is used:
    candidates lie up to ``2 window_mm + 12`` mm either side of its last point along it.
    Voxels outside the sector (zero) are left out. Returns the tip (x, y, z) in mm."""
    cl = np.asarray(centerline, float)
    tip = cl[-1]
    u = cl[-1] - cl[0]
    u = u / np.linalg.norm(u)
    pts = _grid_points(grid) - tip
    s = pts @ u
    perp2 = (pts * pts).sum(1) - s * s
    img = np.asarray(image, float).ravel()
    reach = 3 * window_mm + 12.0
    edges = np.arange(-reach, reach + bin_mm, bin_mm)
    w = int(round(window_mm / bin_mm))
    c = np.arange(w, len(edges) - w)  # candidate boundaries (bin index)

    def windows(mask):  # means over the windows behind and ahead of each boundary, counts
        b = np.clip(np.digitize(s[mask], edges) - 1, 0, len(edges) - 1)
        csum = np.concatenate([[0.0], np.cumsum(np.bincount(b, img[mask], len(edges)))])
        ccnt = np.concatenate([[0.0], np.cumsum(np.bincount(b, None, len(edges)))])
        nb, na = ccnt[c] - ccnt[c - w], ccnt[c + w] - ccnt[c]
        return ((csum[c] - csum[c - w]) / np.maximum(nb, 1),
                (csum[c + w] - csum[c]) / np.maximum(na, 1), (nb >= 5) & (na >= 5))

    near = (img > 0) & (np.abs(s) < reach)
    behind, ahead, ok = windows(near & (perp2 <= radius_mm ** 2))
    if ring_mm is not None:
        ring_behind, ring_ahead, ring_ok = windows(
            near & (perp2 >= ring_mm[0] ** 2) & (perp2 <= ring_mm[1] ** 2))
        behind, ahead, ok = behind - ring_behind, ahead - ring_ahead, ok & ring_ok
    if not ok.any():
        return tip + np.nan
    step = np.where(ok, behind - ahead, -np.inf)
    return tip + edges[c[int(np.argmax(step))]] * u


def evaluate_model(modality: str, source: LearnedFeatures, n_sequences: int, frames: int,
                   cr: float = 2.0, log=print) -> dict:
    scenario, kw = CASES[modality]
    aucs, tips, lat, bound, tracked = [], [], [], [], []
    for k in range(n_sequences):
        seq = synth.generate(scenario, seed=HELD_OUT_SEED + k, frames=frames, cr=cr,
                             background="inhomogeneous", **kw)
        g = seq.grid()
        r = float(seq.meta["needle"]["radius_mm"])
        for i in range(seq.n_frames):
            t0 = time.perf_counter()
            lk = source.likelihood(Frame(seq.images[i], g))
            lat.append((time.perf_counter() - t0) * 1e3)
            d = _distances(seq, i, g, wall=source.target_reference == "wall")
            valid = np.ones(g.shape, bool)
            if seq.ndim == 3:
                valid = seq.images[i] > 0  # inside the sector
            aucs.append(roc_auc(lk.shaft[(d <= r) & valid], lk.shaft[(d > 3 * r) & valid]))
            tip_visible = bool(seq.visible[i]) and (
                seq.ndim == 3 or modality == "axial"
                or abs(seq.tip_3d_mm[i][1]) <= r)
            if modality == "axial":
                # in a transverse slice the tip channel marks the needle's tip only when the
                # slice is at it; the tracked point is the cross-section (shaft channel)
                tip_visible = False
            if tip_visible and lk.tip is not None:
                peak = map_peak(lk.tip)
                true_tip = np.asarray(seq.tip_mm[i], float)
                if source.target_reference == "wall":
                    # the map marks the tip of the wall facing the probe (the bevel's echo),
                    # a radius from the centre line; the trackers add the radius back
                    off = wall_offsets(seq.centerline_mm[i], r)[-1]
                    true_tip = true_tip + off[[0, 2]]
                tips.append(float(np.linalg.norm(g.index_to_points(peak) - true_tip)))
                if seq.ndim == 3:
                    est = axis_changepoint_tip(seq.images[i], g, seq.centerline_mm[i], r)
                    bound.append(float(np.linalg.norm(est - true_tip)))
                    # what a user gets from the map: the tracker's one-volume measurement
                    # (whole-volume RANSAC on the map, axis and tip placed on the image)
                    details = VolumeTracker("ransac", features=_Cached(lk), rng=0).update(
                        Frame(seq.images[i], g)).details
                    m = None if details is None else details.measured_tip_mm
                    tracked.append(math.inf if m is None
                                   else float(np.linalg.norm(np.asarray(m) - true_tip)))
        log(f"  {modality} held-out sequence {k}: AUC so far {np.nanmean(aucs):.4f}")
    tips_a = np.asarray(tips)
    return {
        "model": modality, "sequences": n_sequences, "frames": len(aucs), "cr": cr,
        "seeds": [HELD_OUT_SEED, HELD_OUT_SEED + n_sequences - 1],
        "shaft_auc_mean": float(np.nanmean(aucs)), "shaft_auc_min": float(np.nanmin(aucs)),
        "tip_frames": int(tips_a.size),
        "tip_within_1mm": float((tips_a <= 1.0).mean()) if tips_a.size else float("nan"),
        "tip_error_median_mm": float(np.median(tips_a)) if tips_a.size else float("nan"),
        "feature_source_median_ms": float(np.median(lat)),
        # volumes: the image's own tip, given the true axis (axis_changepoint_tip)
        "known_axis_tip_within_1mm": float((np.asarray(bound) <= 1.0).mean()) if bound
        else None,
        # volumes: the ransac tracker's tip measured on one volume with this model
        "tracker_tip_within_1mm": float((np.asarray(tracked) <= 1.0).mean()) if tracked
        else None,
        "tracker_tip_error_median_mm": float(np.median(tracked)) if tracked else None,
    }


class _Cached(FeatureSource):
    """The likelihood already computed for a frame, handed to a tracker as its source."""

    kind = "learned"
    name = "cached"

    def __init__(self, likelihood: Likelihood):
        self._likelihood = likelihood

    def likelihood(self, frame: Frame, roi=None) -> Likelihood:
        return self._likelihood


def onnx_latency(source: LearnedFeatures, shape, threads: int, repeats: int = 30) -> dict:
    x = np.random.default_rng(0).normal(size=(1, 1, *shape)).astype(np.float32)
    sess = source.sessions.session_for(shape)  # the session the trackers run it on
    for _ in range(3):
        sess.run(None, {"image": x})
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sess.run(None, {"image": x})
        times.append((time.perf_counter() - t0) * 1e3)
    return {"shape": list(shape), "threads": threads, "median_ms": float(np.median(times)),
            "p99_ms": float(np.percentile(times, 99))}


def run(quick: bool = False, seed: int = 0, log=print, rows=None, tier=None) -> dict:
    quick = quick or (tier is not None and tier != "full")
    rows = [] if rows is None else rows
    lat_rows = []
    for modality in ("inplane", "axial", "volume"):
        try:
            path = shipped_model_path(modality)
        except ValueError as exc:
            log(f"{modality}: {exc}")
            continue
        src = LearnedFeatures(path, modality, threads=2)
        n, frames = (2, 8) if quick else (6, 20)
        if modality == "volume":
            n, frames = (1, 4) if quick else (4, 10)
        rows.append(evaluate_model(modality, src, n, frames, log=log))
        for shape in LATENCY_SIZES[modality]:
            r = onnx_latency(src, shape, 2)
            r["model"] = modality
            lat_rows.append(r)
            log(f"  {modality} onnxruntime {shape}: {r['median_ms']:.2f} ms (p99 "
                f"{r['p99_ms']:.2f})")
    return {"rows": rows, "latency": lat_rows}


def markdown(result: dict, machine: dict) -> str:
    lines = [f"Machine: {machine['cpu']}, {machine['cores']} cores", "",
             "| model | held-out frames (CR 2.0) | shaft AUC | tip within 1 mm | "
             "median tip error (mm) |", "|---|---|---|---|---|"]
    for r in result["rows"]:
        lines.append(f"| {r['model']} | {r['frames']} | {r['shaft_auc_mean']:.4f} | "
                     f"{r['tip_within_1mm']:.3f} ({r['tip_frames']} frames) | "
                     f"{r['tip_error_median_mm']:.2f} |")
    bounds = [r for r in result["rows"] if r.get("known_axis_tip_within_1mm") is not None]
    for r in bounds:
        lines += ["", f"{r['model']}: the image itself, given the true axis (change point of "
                  f"the needle's excess over the tissue 2-3 mm around it): tip within 1 mm in "
                  f"{100 * r['known_axis_tip_within_1mm']:.1f}% of the same frames"]
        if r.get("tracker_tip_within_1mm") is not None:
            lines += ["", f"{r['model']}: the ransac tracker's tip measured on each volume "
                      f"with this model (axis and tip placed on the image): within 1 mm in "
                      f"{100 * r['tracker_tip_within_1mm']:.1f}% of the same frames, median "
                      f"{r['tracker_tip_error_median_mm']:.2f} mm"]
    lines += ["", "| model | input | onnxruntime median ms (2 threads) | p99 ms |",
              "|---|---|---|---|"]
    for r in result["latency"]:
        lines.append(f"| {r['model']} | {'x'.join(map(str, r['shape']))} | "
                     f"{r['median_ms']:.2f} | {r['p99_ms']:.2f} |")
    return "\n".join(lines)
