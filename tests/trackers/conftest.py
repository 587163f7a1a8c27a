"""The in-plane model the line tracker's rules were built on: the shipped model's base (stage
one of its recipe, ``training/checkpoints/inplane_base.ckpt``), exported once per session.
Tests of a rule on a particular sequence pin these maps, so that a retrained shipped model
changes what the benchmarks measure, not what such a test means."""

from pathlib import Path

import pytest

BASE = Path(__file__).resolve().parents[2] / "training" / "checkpoints" / "inplane_base.ckpt"


@pytest.fixture(scope="session")
def base_inplane_model(tmp_path_factory) -> str:
    pytest.importorskip("torch")
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from training.export import export_onnx, load_checkpoint

    net, hp = load_checkpoint(BASE)
    out = tmp_path_factory.mktemp("base") / "inplane_base.onnx"
    export_onnx(net, hp["modality"], hp["spacing_mm"], out,
                target_reference=hp["target_reference"], normalization=hp["normalization"],
                speckle_cell_mm=hp["speckle_cell_mm"])
    return str(out)
