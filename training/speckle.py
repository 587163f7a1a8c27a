"""The speckle size of a recipe's training worlds, written into an in-plane model's metadata.

The runtime measures each recording's speckle (``needlenet.features._speckle``) and, where it
is coarser than the speckle the model was trained on, runs the model on a grid coarsened by the
ratio. The reference is the median speckle cell size (the geometric mean of the axial and
lateral widths) over held-out worlds drawn as the recipe draws its training worlds, measured
the same way on the model's grid.

``python -m training.speckle MODEL.onnx`` computes the reference for the shipped recipe of the
model's modality and writes it into the model (``needlenet train inplane --export`` does so
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
from needlenet.features._speckle import cell_size, speckle_widths

from .data import DataConfig, randomize
from .export import set_metadata

__all__ = ["SPECKLE_MODALITIES", "speckle_reference", "write_reference"]

SPECKLE_MODALITIES = ("inplane",)  # the 2D models checked on recordings synth did not make


def speckle_reference(cfg: DataConfig, worlds: int) -> float:
    """The median speckle cell size (:func:`cell_size`), mm, on the model's grid over
    ``worlds`` held-out worlds of ``cfg``'s recipe (seeded: the same number every run)."""
    if worlds < 1:
        raise ValueError(f"speckle_worlds must be at least 1, got {worlds}")
    rng = np.random.default_rng([cfg.val_seed, 2])
    grid = (cfg.spacing_mm, cfg.spacing_mm)
    out: list[float] = []
    for k in range(20 * worlds):
        if len(out) == worlds:
            break
        name, kw = randomize(cfg.modality, rng, cfg)
        try:
            seq = synth.generate(name, seed=cfg.val_seed + k, frames=1, **kw)
        except ValueError:
            continue  # a rare impossible draw, as in training
        w = speckle_widths(seq.images[0], seq.spacing_mm, grid)
        if w is not None:
            out.append(cell_size(w))
    if len(out) < worlds:
        raise RuntimeError(f"speckle reference: {len(out)} of {worlds} worlds gave a speckle "
                           "measurement")
    return round(float(np.median(out)), 4)


def write_reference(model: str | os.PathLike, reference: float) -> None:
    """Set the ``speckle_cell_mm`` metadata of an ONNX model in place (written atomically)."""
    import onnx

    path = Path(model)
    m = onnx.load(path)
    props = {p.key: p.value for p in m.metadata_props}
    props["speckle_cell_mm"] = json.dumps(float(reference))
    set_metadata(m, props)
    tmp = path.with_name(path.name + ".tmp")
    onnx.save(m, tmp)
    os.replace(tmp, path)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m training.speckle", description=__doc__)
    p.add_argument("model", help="an in-plane .onnx model written by needlenet")
    p.add_argument("--worlds", type=int, default=DataConfig.speckle_worlds)
    args = p.parse_args(argv)
    import onnx

    from .train import config_for

    meta = {q.key: q.value for q in onnx.load(args.model).metadata_props}
    modality = meta.get("modality")
    if modality not in SPECKLE_MODALITIES:
        print(f"{args.model}: a {modality!r} model; the speckle reference is for "
              f"{', '.join(SPECKLE_MODALITIES)} models", file=sys.stderr)
        return 2
    ref = speckle_reference(config_for(modality).data, args.worlds)
    write_reference(args.model, ref)
    print(f"{args.model}: speckle_cell_mm {ref} (median of {args.worlds} held-out worlds)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
