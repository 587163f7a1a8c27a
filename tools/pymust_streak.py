"""The streak of a specular needle past its tip in PyMUST's images (docs/notes/inplane.md).

The external generator's needle model alone (tissue density near zero, one frame; the tip at
x = 0, 14 mm deep), beamformed and compounded as the generator does; prints the envelope along
the axis (its maximum within 1 mm across) relative to the shaft's median 3-8 mm before the tip.
Needs PyMUST (``pip install 'needlenet[external]'``); about a minute per angle on 2 cores.

    python tools/pymust_streak.py 8            # L11-5v, 8 degrees
    python tools/pymust_streak.py 30 P4-2v
"""

from __future__ import annotations

import sys

import numpy as np

from needlenet.bench.external.simulate import _simulate
from needlenet.bench.external.specs import SequenceSpec


def streak_profile(angle_deg: float, probe: str = "L11-5v", depth_mm: float = 14.0):
    """(distances past the tip (mm), dB re the shaft) along the needle's axis."""
    a = np.deg2rad(angle_deg)
    entry_x = -depth_mm / np.tan(a)
    spec = SequenceSpec(f"streak{angle_deg:g}", probe, 7, side="left", entry_x_mm=entry_x,
                        angle_deg=angle_deg, start_mm=depth_mm / np.sin(a), step_mm=1.0,
                        n_frames=1, n_reverb=3)
    sim = _simulate(spec, lambda *args: None, scatterers_per_cell=0.02)
    iq = sum(v for k, v in sim["comp"].items() if k.startswith(("piece", "bevel")))
    env = np.abs(iq)
    x, z = sim["dom"].bf_x, sim["dom"].bf_z
    d = np.array([np.cos(a), np.sin(a)])
    tip = np.array([entry_x, 0.0]) + spec.start_mm * d
    u = (x - tip[0]) * d[0] + (z - tip[1]) * d[1]  # along the axis, 0 at the tip
    v = -(x - tip[0]) * d[1] + (z - tip[1]) * d[0]  # across it
    band = np.abs(v) < 1.0

    def peak(at: float) -> float:
        sel = band & (np.abs(u - at) < 0.25)
        return float(env[sel].max()) if sel.any() else np.nan

    ref = np.nanmedian([peak(s) for s in np.arange(-8.0, -3.0, 0.5)])
    past = np.arange(-3.0, 8.01, 0.5)
    return past, np.array([20 * np.log10(peak(s) / ref) for s in past])


def main(argv: list[str]) -> int:
    angle = float(argv[0])
    probe = argv[1] if len(argv) > 1 else "L11-5v"
    past, db = streak_profile(angle, probe)
    print(f"{probe}, {angle:g} degrees: dB re the shaft at mm past the tip")
    print("  ".join(f"{s:+.1f}:{v:.0f}" for s, v in zip(past, db, strict=True)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
