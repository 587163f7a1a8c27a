"""What a recipe's training worlds look like, written into an in-plane model's metadata.

The runtime matches each recording to the worlds a model was trained on:
- speckle size: where the recording's speckle is coarser than training's, the model runs on a
  grid coarsened by the ratio (``needlenet.features._speckle``); the reference is the median
  speckle cell size (the geometric mean of the axial and lateral widths) on the model's grid;
- grey levels: a model trained on fixed grey levels sees each frame mapped affinely so that
  the median and spread of its non-zero pixels are training's (``needlenet.features.
  _resample.normalize``); the reference is the median over worlds of each statistic.
Both are measured on the first frame of held-out worlds drawn as the recipe draws its training
worlds, by the runtime's own functions.

``python -m training.references MODEL.onnx`` computes them for the shipped recipe of the
model's modality and writes them into the model (``needlenet train inplane --export`` does so
itself).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

import synth
from needlenet.features._resample import image_statistics
from needlenet.features._speckle import cell_size, speckle_widths

from .data import DataConfig, randomize

__all__ = ["REFERENCE_MODALITIES", "world_references", "write_references"]

REFERENCE_MODALITIES = ("inplane",)  # the 2D models checked on recordings synth did not make


def world_references(cfg: DataConfig, worlds: int) -> dict:
    """``speckle_cell_mm``: the median speckle cell size (:func:`cell_size`), mm, on the
    model's grid; ``grey_reference``: the medians of the frames' grey median and spread
    (:func:`image_statistics`); over ``worlds`` held-out worlds of ``cfg``'s recipe (seeded:
    the same numbers every run)."""
    if worlds < 1:
        raise ValueError(f"reference_worlds must be at least 1, got {worlds}")
    rng = np.random.default_rng([cfg.val_seed, 2])
    grid = (cfg.spacing_mm, cfg.spacing_mm)
    cells: list[float] = []
    greys: list[tuple[float, float]] = []
    for k in range(20 * worlds):
        if len(cells) == worlds:
            break
        name, kw = randomize(cfg.modality, rng, cfg)
        try:
            seq = synth.generate(name, seed=cfg.val_seed + k, frames=1, **kw)
        except ValueError:
            continue  # a rare impossible draw, as in training
        w = speckle_widths(seq.images[0], seq.spacing_mm, grid)
        if w is not None:
            cells.append(cell_size(w))
            greys.append(image_statistics(seq.images[0]))
    if len(cells) < worlds:
        raise RuntimeError(f"references: {len(cells)} of {worlds} worlds gave a speckle "
                           "measurement")
    grey = np.median(np.asarray(greys), axis=0)
    return {"speckle_cell_mm": round(float(np.median(cells)), 4),
            "grey_reference": [round(float(grey[0]), 2), round(float(grey[1]), 2)]}


def write_references(model: str | os.PathLike, refs: dict) -> None:
    """Set ``speckle_cell_mm`` and, for a ``fixed`` normalisation, its ``grey_reference`` in
    an ONNX model's metadata, in place (written atomically)."""
    import onnx

    path = Path(model)
    m = onnx.load(path)
    props = {p.key: p.value for p in m.metadata_props}
    props["speckle_cell_mm"] = json.dumps(float(refs["speckle_cell_mm"]))
    norm = json.loads(props["normalization"])
    if norm.get("mode", "fixed") == "fixed":
        norm["grey_reference"] = [float(v) for v in refs["grey_reference"]]
        props["normalization"] = json.dumps(norm)
    del m.metadata_props[:]
    for k, v in props.items():
        p = m.metadata_props.add()
        p.key, p.value = k, v
    tmp = path.with_name(path.name + ".tmp")
    onnx.save(m, tmp)
    os.replace(tmp, path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m training.references", description=__doc__)
    p.add_argument("model", help="an in-plane .onnx model written by needlenet")
    p.add_argument("--worlds", type=int, default=DataConfig.reference_worlds)
    args = p.parse_args(argv)
    import onnx

    from .train import config_for

    meta = {q.key: q.value for q in onnx.load(args.model).metadata_props}
    modality = meta.get("modality")
    if modality not in REFERENCE_MODALITIES:
        print(f"{args.model}: a {modality!r} model; the references are for "
              f"{', '.join(REFERENCE_MODALITIES)} models", file=sys.stderr)
        return 2
    refs = world_references(config_for(modality).data, args.worlds)
    write_references(args.model, refs)
    print(f"{args.model}: {refs} (medians over {args.worlds} held-out worlds)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
