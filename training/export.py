"""Export a trained network to ONNX, verified against torch, with the metadata the runtime
needs (spacing, intensity normalisation, modality, version, output stride)."""

from __future__ import annotations

import json
import os
import tempfile
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from needlenet.features import NORMALIZATIONS

from .networks import INPUT_MULTIPLE, OUTPUT_STRIDE, build_network

__all__ = ["export_onnx", "load_checkpoint", "set_metadata", "ExportError", "OPSET", "IR_VERSION"]

OPSET = 17  # loaded by onnxruntime >= 1.14
IR_VERSION = 8  # ONNX IR version matching opset 17; onnxruntime >= 1.14 loads it
MAX_ABS_DIFF = 1e-4


class ExportError(RuntimeError):
    """The exported model does not agree with torch; nothing was written."""


class _WithSigmoid(nn.Module):
    """The exported graph returns probabilities, not logits."""

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net

    def forward(self, image):
        return torch.sigmoid(self.net(image))


def set_metadata(model, meta: dict) -> None:
    """Replace an ONNX model's metadata by ``meta`` (string keys and values)."""
    del model.metadata_props[:]
    for k, v in meta.items():
        p = model.metadata_props.add()
        p.key, p.value = k, v


def load_checkpoint(path: str | os.PathLike) -> tuple[nn.Module, dict]:
    """The network and hyper-parameters of a Lightning checkpoint written by ``train``."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
        hp = dict(ckpt["hyper_parameters"])
        state = {k[len("net."):]: v for k, v in ckpt["state_dict"].items()
                 if k.startswith("net.")}
    except (KeyError, RuntimeError, EOFError, OSError) as exc:
        raise ValueError(f"checkpoint {path}: not a needlenet training checkpoint ({exc})") \
            from None
    width = None
    for k, v in state.items():
        if k.startswith("stem.0.weight"):
            width = int(v.shape[0])
    net = build_network(hp["modality"], width)
    try:
        net.load_state_dict(state)
    except RuntimeError as exc:
        raise ValueError(f"checkpoint {path}: its network is not this version's "
                         f"({str(exc).splitlines()[0]})") from None
    net.eval()
    return net, hp


def export_onnx(net: nn.Module, modality: str, spacing_mm: float, out: str | os.PathLike,
                version: str = "0.1.0", extra_metadata: dict | None = None,
                overwrite: bool = False, seed: int = 0,
                target_reference: str = "centerline", normalization: str = "fixed",
                speckle_cell_mm: float | None = None) -> dict:
    """Write ``net`` as ONNX (input ``image``, output ``likelihood``, dynamic spatial axes).

    ``normalization``: a key of ``NORMALIZATIONS`` (the model's input intensity scaling).
    ``target_reference`` (metadata): where the maps mark the needle, ``"centerline"`` or
    ``"wall"`` (the wall facing the probe; see ``training.data.WALL_REFERENCED``).
    ``speckle_cell_mm`` (metadata, 2D models): the training worlds' median speckle cell size
    on the model's grid (``training.speckle``), to which the runtime matches a recording's
    grid.

    onnxruntime's output is compared with torch's on random inputs of several (odd-padded)
    sizes; if the largest absolute difference exceeds 1e-4, :class:`ExportError` is raised
    and nothing is written. Returns the check's figures.
    """
    import onnx
    import onnxruntime as ort

    out = Path(out)
    if out.suffix != ".onnx":
        raise ValueError(f"--out {out}: must end in .onnx")
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
    # eval() on the wrapper: the exporter restores the wrapper's mode recursively afterwards,
    # and a wrapper left in training mode would put BatchNorm back on batch statistics.
    net = _WithSigmoid(net).eval()
    dims = 3 if modality == "volume" else 2
    base = (32,) * dims if dims == 3 else (64, 96)
    x = torch.zeros((1, 1, *base))
    axes = {i: f"d{i}" for i in range(2, 2 + dims)}
    fd, tmp = tempfile.mkstemp(suffix=".onnx", dir=out.parent if str(out.parent) else ".")
    os.close(fd)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(net, (x,), tmp, input_names=["image"],
                              output_names=["likelihood"], opset_version=OPSET,
                              dynamic_axes={"image": axes, "likelihood": axes}, dynamo=False)
        model = onnx.load(tmp)
        model.ir_version = IR_VERSION
        meta = {
            "needlenet_version": version, "modality": modality,
            "spacing_mm": json.dumps([spacing_mm] * dims),
            "normalization": json.dumps(NORMALIZATIONS[normalization]),
            "output_stride": str(OUTPUT_STRIDE), "input_multiple": str(INPUT_MULTIPLE),
            "channels": json.dumps(["shaft", "tip"]),
            "target_reference": target_reference,
            **({"speckle_cell_mm": json.dumps(float(speckle_cell_mm))}
               if speckle_cell_mm is not None else {}),
        }
        meta.update({k: str(v) for k, v in (extra_metadata or {}).items()})
        set_metadata(model, meta)
        onnx.checker.check_model(model)
        onnx.save(model, tmp)
        net.eval()
        sess = ort.InferenceSession(tmp, providers=["CPUExecutionProvider"])
        rng = np.random.default_rng(seed)
        sizes = ([(40, 56, 48), (32, 32, 64)] if dims == 3 else [(64, 96), (132, 100),
                                                                   (256, 256)])
        worst = 0.0
        for s in sizes:
            inp = rng.normal(0, 1, (1, 1, *s)).astype(np.float32)
            with torch.no_grad():
                ref = net(torch.from_numpy(inp)).numpy()
            got = sess.run(["likelihood"], {"image": inp})[0]
            if got.shape != ref.shape:
                raise ExportError(f"onnxruntime output shape {got.shape} != torch {ref.shape}")
            worst = max(worst, float(np.abs(got - ref).max()))
        if worst > MAX_ABS_DIFF:
            raise ExportError(f"onnxruntime and torch differ by {worst:.2e} > {MAX_ABS_DIFF:g}; "
                              f"{out} not written")
        os.chmod(tmp, 0o644)  # mkstemp makes it private; a model is for everyone to read
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return {"max_abs_diff": worst, "sizes": sizes, "opset": OPSET, "ir_version": IR_VERSION,
            "bytes": out.stat().st_size, "metadata": meta}
