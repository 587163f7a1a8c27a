"""Write a copy of a set of labelled 2D sequences as a scanner's post-processing would show it.

    python tools/postprocessed_set.py SRC DST OP [VALUE]

SRC: a directory of sequence files (.npz, needlenet's format), e.g. the in-plane validation set
``needlenet/data/validation``; DST: a new directory (refused if it holds files). OP and its
default VALUE:

- ``bilateral`` 40 (the grey-level sigma; 0.9 mm window), ``median`` 5 (kernel, pixels),
  ``nlm`` 12 (non-local means' h), ``gaussian`` 0.6 (mm), ``sharpen`` 1.0 (unsharp amount, a
  2-pixel Gaussian), ``jpeg`` 50 (quality): the families ``training.postprocess`` draws for
  training worlds, at fixed strengths;
- ``diffusion`` 25 (kappa, grey levels; 15 steps of 0.2): Perona-Malik anisotropic diffusion,
  the speckle-reducing family scanners use and training never draws, so a model's robustness
  to it is measured on a process it has not seen.

Labels are copied unchanged; pixels outside the imaged region (0) stay 0. Score a copy with
``needlenet bench external --data DST``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from training.postprocess import postprocess  # noqa: E402

DEFAULTS = {"bilateral": 40.0, "median": 5.0, "nlm": 12.0, "gaussian": 0.6, "sharpen": 1.0,
            "jpeg": 50.0, "diffusion": 25.0}


def perona_malik(image: np.ndarray, kappa: float, steps: int = 15,
                 lam: float = 0.2) -> np.ndarray:
    """Perona-Malik diffusion with the exponential conductance exp(-(|grad| / kappa)^2)."""
    u = image.astype(np.float64)
    for _ in range(steps):
        flux = 0.0
        for axis in (0, 1):
            for shift in (-1, 1):
                d = np.roll(u, shift, axis) - u
                flux = flux + np.exp(-(d / kappa) ** 2) * d
        u = u + lam * flux
    return np.clip(np.rint(u), 0, 255).astype(np.uint8)


def process(image: np.ndarray, spacing_mm: float, op: str, value: float) -> np.ndarray:
    if op == "diffusion":
        return np.where(image > 0, perona_malik(image, value), 0).astype(np.uint8)
    params = {"bilateral": {"size_mm": 9 * spacing_mm, "sigma_color": value},
              "median": {"size_mm": value * spacing_mm},
              "nlm": {"h": value}, "gaussian": {"size_mm": value},
              "sharpen": {"sigma_mm": 2 * spacing_mm, "amount": value},
              "jpeg": {"quality": int(value)}}[op]
    return postprocess(image, spacing_mm, [(op, params)])


def write_copies(files, dst: Path, op: str, value: float) -> None:
    """Each sequence file of ``files`` written into ``dst`` with its frames through ``op``."""
    for f in files:
        with np.load(f, allow_pickle=False) as z:
            d = dict(z)
        s = float(np.min(d["spacing_mm"][:2]))
        d["images"] = np.stack([process(im, s, op, value) for im in d["images"]])
        np.savez_compressed(dst / f.name, **d)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("op", choices=sorted(DEFAULTS))
    ap.add_argument("value", nargs="?", type=float)
    a = ap.parse_args(argv)
    value = DEFAULTS[a.op] if a.value is None else a.value
    files = sorted(Path(a.src).glob("*.npz"))
    if not files:
        ap.error(f"{a.src}: no .npz sequence files")
    dst = Path(a.dst)
    if dst.exists() and any(dst.iterdir()):
        ap.error(f"{dst} already holds files; give a new directory")
    dst.mkdir(parents=True, exist_ok=True)
    write_copies(files, dst, a.op, value)
    print(f"wrote {len(files)} sequences to {dst} ({a.op} {value:g})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
