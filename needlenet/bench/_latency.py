"""``needlenet bench latency``: per-frame time of every tracker with both feature kinds.

Each tracker runs over a seeded synth sequence at its paper's frame size (Mathiassen's
500 x 384 in-plane frames at 0.1 mm, Carriere's 128 x 128 axial slices, Zhao's 128^3 volumes),
and the default in-plane tracker also on 1200 x 960 frames at 0.05 mm (a screen capture's);
the time is the tracker's own per-frame latency (features, back end and bookkeeping, measured
inside ``Tracker.update`` with ``time.perf_counter``), excluding the simulator. Detection (the
frames up to the first one reported ``tracking``: the whole-image search, model warm-up, and
for Chatelain's tracker the first change between two volumes) is reported separately from the
steady state. Headline: ``latency_p99_ms``.
"""

from __future__ import annotations

import numpy as np

import synth

from ..trackers import make_tracker
from ._trackers import SEED0, _feature_kinds, _tier

INPLANE_ALL = ("line", "df", "om", "om+f", "kf", "kf+f", "pf", "pf+f", "kfv", "kfv+f", "pfv",
               "pfv+f")


def _cases(tier: str) -> list[tuple]:
    """(tracker, methods, scenario, generate kwargs)."""
    inplane_methods = INPLANE_ALL if tier == "full" else ("line", "om", "kf+f", "pf+f")
    return [
        ("inplane", inplane_methods, "inplane",
         {"frames": 60 if tier == "full" else 30, "angle_deg": 35.0, "speed_mm_s": 10.0,
          "background": "inhomogeneous"}),
        # a screen capture's size: 1200 x 960 pixels at 0.05 mm (the default tracker only)
        ("inplane", ("line",), "inplane",
         {"frames": 40 if tier == "full" else 20, "angle_deg": 35.0, "speed_mm_s": 10.0,
          "background": "inhomogeneous", "spacing_mm": 0.05, "width_mm": 48.0,
          "depth_mm": 60.0}),
        ("axial", ("carriere",), "axial",
         {"insertion_mm": 60.0 if tier == "full" else 30.0, "background": "inhomogeneous"}),
        ("volume", ("ransac", "roi-rk", "chatelain"), "volume",
         {"frames": 12 if tier == "full" else 6, "cr": 3.0,
          "output_size": 128 if tier == "full" else 96}),
    ]


def run(quick: bool = False, seed: int = 0, log=print, rows=None, tier=None) -> dict:
    tier = _tier(quick, tier)
    rows = [] if rows is None else rows
    for tracker, methods, scenario, kw in _cases(tier):
        sd = SEED0 + seed + 500
        seq = synth.generate(scenario, seed=sd, **kw)
        shape = list(seq.images.shape[1:])
        for kind in _feature_kinds(tracker, log):
            for m in methods:
                extra = {"expected_angle_deg": 35.0} if tracker == "inplane" and m != "line" else {}
                rng_kw = {"rng": 0} if tracker == "volume" else {"seed": 0}
                tr = make_tracker(tracker, m, kind, **rng_kw, **extra)
                est = tr.run(seq)
                lat = np.array([e.latency_ms for e in est], float)
                detect, steady = split_detection(est, lat)
                row = {
                    "suite": "latency", "tracker": tracker, "method": m, "features": kind,
                    "shape": shape, "frame": "x".join(map(str, shape)),
                    "spacing_mm": [float(v) for v in seq.spacing_mm],
                    "sequences": 1, "frames": int(seq.n_frames), "seeds": [sd],
                    "first_frame_ms": float(lat[0]),
                    "detection_ms": float(detect.max()), "detection_frames": int(detect.size),
                    "latency_median_ms": float(np.median(steady)),
                    "latency_p99_ms": float(np.percentile(steady, 99)),
                    "frames_per_s": float(1000.0 / steady.mean()),
                }
                rows.append(row)
                log(f"  {tracker:7s} {m:9s} {kind:9s} {'x'.join(map(str, shape)):>11s}: "
                    f"median {row['latency_median_ms']:6.2f} ms, p99 "
                    f"{row['latency_p99_ms']:6.2f} ms, {row['frames_per_s']:6.0f} frames/s")
    return {"rows": rows}


def split_detection(est, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The latencies of the frames up to and including the first one reported ``tracking``
    (detection: whole-frame search, model warm-up, and for Chatelain's tracker the change
    between two volumes) and of the frames after it (steady state). Without a tracking frame
    the first frame is the detection and the rest the steady state."""
    tracking = [i for i, e in enumerate(est) if e.status.value == "tracking"]
    n = tracking[0] + 1 if tracking else 1
    n = min(n, max(lat.size - 1, 1))  # keep at least one steady frame
    return lat[:n], (lat[n:] if lat.size > n else lat)


def markdown(result: dict, machine: dict) -> str:
    lines = [f"Machine: {machine['cpu']}, {machine['cores']} cores", "",
             "Per-frame latency of the tracker (features + back end; the simulator excluded): "
             "detection is the longest frame up to the first one reported tracking (its "
             "frames counted), the steady state the frames after it.", "",
             "| tracker | method | features | frame | detection (ms) | detection frames | "
             "median (ms) | p99 (ms) | frames/s |", "|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        lines.append(f"| {r['tracker']} | {r['method']} | {r['features']} | "
                     f"{'x'.join(map(str, r['shape']))} | {r['detection_ms']:.1f} | "
                     f"{r['detection_frames']} | "
                     f"{r['latency_median_ms']:.2f} | {r['latency_p99_ms']:.2f} | "
                     f"{r['frames_per_s']:.0f} |")
    return "\n".join(lines)
