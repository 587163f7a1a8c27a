"""A synth development set of in-plane needles beside a specular tissue boundary.

Twelve seeded sequences (12 frames each, 10 mm/s): a needle at 15-50 degrees from either side,
a boundary 1.5-4 mm above or below it, reflecting specularly (`interface_echo` 30-120, the
needle's echo model without reverberation or tip) and turned up to a few degrees from it.
PyMUST's and real images show such boundaries as needle-like lines; this set shows the same
failure on synth's own images, so that work on it need not look at the PyMUST sets. Written as
sequence files; score them as an external set:

    python tools/synth_interface_set.py /tmp/interface_set
    needlenet bench external --data /tmp/interface_set [--model candidate.onnx]

About 5 s on 2 cores. Seeds 20-31 (never used in training: training draws its own worlds).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import synth

SEEDS = range(20, 32)


def interface_sequence(seed: int) -> synth.Sequence:
    """The set's sequence of ``seed``; its meta says side, angle and the boundary's offset."""
    rng = np.random.default_rng(seed)
    offset = float(rng.choice([-1, 1]) * rng.uniform(1.5, 4.0))
    angle = float(rng.uniform(15, 50))
    echo = float(rng.uniform(30, 120))
    tilt = float(rng.normal(0, 3))
    side = str(rng.choice(["left", "right"]))
    seq = synth.generate("inplane", seed=seed, frames=12, speed_mm_s=10.0, angle_deg=angle,
                         start_length_mm=8.0, interface_offset_mm=offset,
                         interface_brightness=1.5, interface_echo=echo,
                         interface_tilt_deg=tilt, side=side)
    seq.meta.update(probe="synth linear", side=side, angle_deg=round(angle, 1),
                    feature=f"specular boundary {offset:+.1f} mm, tilt {tilt:+.1f} deg")
    return seq


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__.strip().splitlines()[0] + "\nusage: python tools/synth_interface_set.py DIR",
              file=sys.stderr)
        return 2
    out = Path(argv[0])
    out.mkdir(parents=True, exist_ok=True)
    for seed in SEEDS:
        path = out / f"synth_interface_{seed}.npz"
        if path.exists():
            print(f"{path} exists; choose an empty directory", file=sys.stderr)
            return 2
        synth.save_sequence(interface_sequence(seed), path)
    print(f"wrote {len(SEEDS)} sequences to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
