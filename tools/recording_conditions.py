"""Write a copy of a set of labelled 2D sequences as another recording would show it: receiver
noise, a depth-dependent gain, a brighter display, coarser pixels, or a gray biopsy guide
drawn over a live recording (docs/results.md, "Recording conditions").

    python tools/recording_conditions.py SRC DST OP VALUE

SRC: a directory of sequence files (.npz, needlenet's format), e.g. the in-plane validation set
``needlenet/data/validation``; DST: a new directory (refused if it holds files). OP and VALUE:

- ``noise`` SIGMA: Gaussian receiver noise of SIGMA grey levels, new in every frame (seeded by
  the file's name), on the imaged pixels (those above 0; they stay above 0);
- ``ramp`` LEVELS: a gain that changes linearly with depth, from -LEVELS/2 grey levels at the
  top to +LEVELS/2 at the bottom (negative: darker with depth), on the imaged pixels;
- ``gain`` FACTOR: a brighter display, the imaged pixels' grey levels times FACTOR, clipped
  at 255 (a bright needle and the streak past its tip go white together);
- ``scale`` FACTOR: pixels FACTOR times larger (OpenCV's area resampling), spacing and origin
  moved to match, labels unchanged (they are in mm);
- ``guide`` GRAY: receiver noise of 2 grey levels (a live recording) and a dotted biopsy guide
  drawn in GRAY over every frame: 40 dashes, 2 pixels wide, anti-aliased, from 85% of the width
  at the top to 25% of it at 80% of the depth.

Score a copy with ``needlenet bench external --data DST``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import synth  # noqa: E402

OPS = ("noise", "ramp", "gain", "scale", "guide")


def _imaged(x: np.ndarray, original: np.ndarray) -> np.ndarray:
    """``x`` rounded to uint8, 0 where ``original`` is 0 and at least 1 where it is not."""
    on = original > 0
    out = np.clip(np.rint(np.where(on, x, 0.0)), 0, 255)
    return np.where(on & (out == 0), 1, out).astype(np.uint8)


def noisy(images: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    ims = np.asarray(images, np.float32)
    return _imaged(ims + rng.normal(0.0, sigma, ims.shape), ims)


def depth_ramp(images: np.ndarray, levels: float) -> np.ndarray:
    ims = np.asarray(images, np.float32)
    ramp = np.linspace(-levels / 2, levels / 2, ims.shape[1], dtype=np.float32)[None, :, None]
    return _imaged(ims + ramp, ims)


def brighter(images: np.ndarray, factor: float) -> np.ndarray:
    ims = np.asarray(images, np.float32)
    return _imaged(ims * np.float32(factor), ims)


def drawn_guide(images: np.ndarray, gray: int) -> np.ndarray:
    """``images`` with the dotted guide blended over every frame (anti-aliased)."""
    h, w = images.shape[1:]
    cover = np.zeros((h, w), np.uint8)
    p0, p1 = np.array([0.85 * w, 0.0]), np.array([0.25 * w, 0.8 * h])
    for k in range(40):
        a = tuple(int(v) for v in p0 + (p1 - p0) * k / 40)
        b = tuple(int(v) for v in p0 + (p1 - p0) * (k + 0.5) / 40)
        cv2.line(cover, a, b, 255, 2, cv2.LINE_AA)
    alpha = cover.astype(np.float32)[None] / 255.0
    return np.rint(images * (1.0 - alpha) + gray * alpha).astype(np.uint8)


def converted(seq, op: str, value: float, rng: np.random.Generator):
    ims = np.asarray(seq.images)
    if op == "noise":
        return dataclasses.replace(seq, images=noisy(ims, value, rng))
    if op == "ramp":
        return dataclasses.replace(seq, images=depth_ramp(ims, value))
    if op == "gain":
        return dataclasses.replace(seq, images=brighter(ims, value))
    if op == "guide":
        return dataclasses.replace(seq, images=drawn_guide(noisy(ims, 2.0, rng), int(value)))
    h, w = ims.shape[1:]
    nh, nw = int(round(h / value)), int(round(w / value))
    small = np.stack([cv2.resize(im, (nw, nh), interpolation=cv2.INTER_AREA) for im in ims])
    old = np.asarray(seq.spacing_mm, float)
    sp = old * np.array([h / nh, w / nw])
    origin = np.asarray(seq.origin_mm, float) + 0.5 * (sp - old)  # pixel centres kept
    return dataclasses.replace(seq, images=small, spacing_mm=sp, origin_mm=origin)


def write_copies(files, dst: Path, op: str, value: float, overwrite: bool = False) -> None:
    """Each sequence file of ``files`` under ``op`` at ``value``, written to ``dst`` under its
    own name; the random stream of each is seeded by its file name."""
    dst.mkdir(parents=True, exist_ok=True)
    for f in files:
        rng = np.random.default_rng(zlib.crc32(f.name.encode()))
        synth.save_sequence(converted(synth.load_sequence(f), op, value, rng), dst / f.name,
                            overwrite=overwrite)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("op", choices=OPS)
    ap.add_argument("value", type=float)
    a = ap.parse_args(argv)
    src, dst = Path(a.src), Path(a.dst)
    files = sorted(src.glob("*.npz"))
    if not files:
        ap.error(f"no sequence files (*.npz) in {src}")
    if a.op == "scale" and not 1.0 <= a.value <= 4.0:
        ap.error(f"scale must lie in 1-4, got {a.value}")
    if a.op == "gain" and not 0.1 <= a.value <= 4.0:
        ap.error(f"gain must lie in 0.1-4, got {a.value}")
    if a.op in ("noise",) and not 0.0 < a.value <= 50.0:
        ap.error(f"noise sigma must lie in (0, 50] grey levels, got {a.value}")
    if a.op == "guide" and not 1 <= a.value <= 254:
        ap.error(f"guide gray must lie in 1-254 (0 is black, 255 saturation), got {a.value}")
    if dst.exists() and any(dst.iterdir()):
        ap.error(f"{dst} holds files; give a new directory")
    write_copies(files, dst, a.op, a.value)
    print(f"wrote {len(files)} sequences to {dst}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
