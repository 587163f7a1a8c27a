"""``needlenet bench honesty``: does an in-plane tracker say when the needle has gone, and
does it pick the needle up again when it comes back?

Protocol: a 140-frame synth insertion at 5 mm/s whose frames 55-84 are replaced by
the same world's frames without the needle (the needle leaves the plane and returns; the
tissue, its lines and interfaces stay). 5 mm/s keeps the tip in view after the gap, so the
return can be scored on every world. Each tracker runs with no angle and no entry side given,
as ``needlenet track`` runs it.

Per method and features, over the worlds:

- ``false_tracking``: needle-free frames (55-84) reported ``tracking``, and their share;
- ``reacquired``: worlds on which the tip is reported within ``WITHIN_MM`` of the truth within
  ``REACQUIRE_FRAMES`` frames of the needle's return; ``reacquire_frames`` per world (the
  number of frames after the return until the first such frame; None: not within the run);
- ``held_before``: worlds on which the needle was held before the gap (at least half of frames
  30-54 within ``WITHIN_MM``): a tracker that never held the needle cannot re-acquire it, and
  the table says which failures are of that kind;
- ``within_before`` / ``within_after``: needle frames within ``WITHIN_MM`` before / after the gap;
- ``recording_false_tracking``: frames reported ``tracking`` on recordings that hold no needle
  from their first frame (synth worlds ``FREE_WORLDS``, ``FREE_FRAMES`` frames each, the
  default inhomogeneous tissue with its needle-like lines): the gap protocol's needle was
  tracked before the gap, and a tracker may hold back from tissue only then;
- ``breathing_false_tracking``: the same on those worlds' recordings with the tissue moving
  as a patient's breathing moves it under a probe held still (rigid, ``BREATHING_MM``
  amplitude, periods 3-5 s: synth's ``tissue_motion_mm``), so that no frame repeats the one
  before it.

Headline: ``false_tracking_fraction`` (lower is better).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._trackers import _feature_kinds, _tier

FRAMES = 140
GAP = (55, 85)  # needle-free frames [55, 85)
SPEED_MM_S = 5.0
WITHIN_MM = 2.0
REACQUIRE_FRAMES = 10
# consecutive worlds, none left out
SEEDS = {"demo": (11,), "quick": (11, 12, 13), "full": tuple(range(11, 19))}
FREE_FRAMES = 30
BREATHING_MM = 1.0
FREE_WORLDS = {"demo": (100,), "quick": tuple(range(100, 110)), "full": tuple(range(100, 130))}
QUICK_METHODS = ("line", "kf+f", "df")


def protocol_sequence(world: int):
    """World ``world``'s insertion with frames ``GAP`` taken from the same world without the
    needle (labelled not visible, no tip)."""
    import synth

    seq = synth.generate("inplane", seed=world, frames=FRAMES, speed_mm_s=SPEED_MM_S)
    free = synth.generate("inplane", seed=world, frames=FRAMES, speed_mm_s=SPEED_MM_S,
                          needle_free=True)
    a, b = GAP
    images = seq.images.copy()
    images[a:b] = free.images[a:b]
    visible = np.ones(FRAMES, bool) if seq.visible is None else np.asarray(seq.visible, bool)
    visible = visible.copy()
    visible[a:b] = False
    tip = np.asarray(seq.tip_mm, float).copy()
    tip[a:b] = np.nan
    return dataclasses.replace(seq, images=images, visible=visible, tip_mm=tip)


def world_metrics(estimates: list, seq) -> dict:
    """The protocol's figures for one world's run."""
    tracking = np.array([e.status == "tracking" for e in estimates])
    err = np.full(len(estimates), np.inf)
    for i, (e, t) in enumerate(zip(estimates, seq.tip_mm, strict=True)):
        if tracking[i] and e.tip_mm is not None and np.all(np.isfinite(t)):
            err[i] = float(np.linalg.norm(np.asarray(e.tip_mm, float) - t))
    a, b = GAP
    good = err <= WITHIN_MM
    after = np.flatnonzero(good[b:])
    held = good[30:a]
    return {"false_tracking": int(tracking[a:b].sum()), "needle_free_frames": b - a,
            "reacquire_frames": int(after[0]) if after.size else None,
            "held_before": bool(held.mean() >= 0.5),
            "within_before": int(good[:a].sum()), "within_after": int(good[b:].sum()),
            "needle_frames_before": a, "needle_frames_after": len(estimates) - b}


def _methods(tier: str) -> tuple[str, ...]:
    from ..trackers import tracker_methods

    return QUICK_METHODS if tier != "full" else tracker_methods("inplane")


def run(quick: bool = False, seed: int = 0, log=print, rows=None, tier=None) -> dict:
    from ..trackers import make_tracker

    tier = _tier(quick, tier)
    rows = [] if rows is None else rows
    kinds = _feature_kinds("inplane", log)
    worlds = SEEDS[tier]
    seqs = {}
    for w in worlds:
        log(f"  honesty: world {w} ({FRAMES} frames, needle-free {GAP[0]}-{GAP[1] - 1})")
        seqs[w] = protocol_sequence(w)
    free = {w: free_recording(w) for w in FREE_WORLDS[tier]}
    breathing = {w: free_recording(w, BREATHING_MM) for w in FREE_WORLDS[tier]}
    log(f"  honesty: {len(free)} recordings without a needle ({FREE_FRAMES} frames each), "
        "still and breathing")
    for method in _methods(tier):
        for kind in kinds:
            per_world = []
            for w in worlds:
                tracker = make_tracker("inplane", method, kind, seed=seed + w)
                per_world.append({"world": w, **world_metrics(tracker.run(seqs[w]), seqs[w])})
            rows.append(_row(method, kind, per_world, tier))
            r = rows[-1]
            r["recording_worlds"] = list(free)
            r["recording_false_tracking"] = sum(
                tracking_frames(make_tracker("inplane", method, kind, seed=seed + w).run(f))
                for w, f in free.items())
            r["recording_frames"] = FREE_FRAMES * len(free)
            r["breathing_false_tracking"] = sum(
                tracking_frames(make_tracker("inplane", method, kind, seed=seed + w).run(f))
                for w, f in breathing.items())
            log(f"  honesty {method} {kind}: needle-free tracking {r['false_tracking']}/"
                f"{r['needle_free_frames']}, re-acquired {r['reacquired']}/{len(worlds)}, "
                f"needle-free recordings {r['recording_false_tracking']}/"
                f"{r['recording_frames']}, breathing {r['breathing_false_tracking']}/"
                f"{r['recording_frames']}")
    return {"rows": rows}


def free_recording(world: int, breathing_mm: float = 0.0):
    """World ``world`` without a needle, ``FREE_FRAMES`` frames from its first; its tissue
    moving by ``breathing_mm`` (synth's breathing-like ``tissue_motion_mm``)."""
    import synth

    return synth.generate("inplane", seed=world, frames=FREE_FRAMES, needle_free=True,
                          tissue_motion_mm=breathing_mm)


def tracking_frames(estimates: list) -> int:
    """Frames reported ``tracking``."""
    return sum(e.status == "tracking" for e in estimates)


def _row(method: str, kind: str, per_world: list[dict], tier: str) -> dict:
    false = sum(p["false_tracking"] for p in per_world)
    free = sum(p["needle_free_frames"] for p in per_world)
    frames = [p["reacquire_frames"] for p in per_world]
    return {
        "tracker": "inplane", "method": method, "features": kind, "tier": tier,
        "worlds": [p["world"] for p in per_world],
        "false_tracking": false, "needle_free_frames": free,
        "false_tracking_fraction": false / free if free else None,
        "reacquire_frames": frames,
        "reacquired": sum(f is not None and f < REACQUIRE_FRAMES for f in frames),
        "held_before": [p["held_before"] for p in per_world],
        "within_before": sum(p["within_before"] for p in per_world),
        "within_after": sum(p["within_after"] for p in per_world),
        "needle_frames_before": sum(p["needle_frames_before"] for p in per_world),
        "needle_frames_after": sum(p["needle_frames_after"] for p in per_world),
    }


def markdown(result: dict, machine: dict) -> str:
    rows = result["rows"]
    worlds = rows[0]["worlds"] if rows else []
    lines = [f"Machine: {machine['cpu']}, {machine['cores']} cores", "",
             f"Needle-free protocol: synth worlds {', '.join(map(str, worlds))}, "
             f"{FRAMES} frames at {SPEED_MM_S:g} mm/s, frames {GAP[0]}-{GAP[1] - 1} without the "
             f"needle; no angle or entry side given. Re-acquired: the tip within {WITHIN_MM:g} "
             f"mm within {REACQUIRE_FRAMES} frames of the return. Frames to re-acquire per "
             "world (`-`: not within the run; `*`: the needle was not held before the gap "
             "either). Needle-free recordings: synth worlds "
             f"{_span(rows[0].get('recording_worlds', [])) if rows else '-'} without a "
             f"needle from the first frame ({FREE_FRAMES} frames each), frames `tracking`, the "
             f"tissue still and breathing ({BREATHING_MM:g} mm).", "",
             "| method | features | needle-free `tracking` | re-acquired | frames to re-acquire "
             "| within 2 mm before / after | needle-free recordings `tracking` | breathing |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        per = ", ".join(("-" if f is None else str(f)) + ("" if h else "*")
                        for f, h in zip(r["reacquire_frames"], r["held_before"], strict=True))
        lines.append(
            f"| {r['method']} | {r['features']} | {r['false_tracking']} / "
            f"{r['needle_free_frames']} ({100 * r['false_tracking_fraction']:.1f}%) | "
            f"{r['reacquired']} / {len(r['worlds'])} | {per} | {r['within_before']} / "
            f"{r['needle_frames_before']}, {r['within_after']} / {r['needle_frames_after']} | "
            f"{r.get('recording_false_tracking', '-')} / {r.get('recording_frames', '-')} | "
            f"{r.get('breathing_false_tracking', '-')} / {r.get('recording_frames', '-')} |")
    return "\n".join(lines)


def _span(worlds) -> str:
    worlds = list(worlds)
    if len(worlds) > 2 and worlds == list(range(worlds[0], worlds[-1] + 1)):
        return f"{worlds[0]}-{worlds[-1]}"
    return ", ".join(map(str, worlds)) or "-"
