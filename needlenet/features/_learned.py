"""Learned features: an ONNX model run with onnxruntime as a FeatureSource.

The model carries in its metadata the spacing it was trained at, the intensity normalisation
and its modality. Each frame (or ROI) is resampled to the model's spacing, padded to the
network's multiple, run, and its shaft and tip maps are mapped back to the frame's grid.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import numpy as np

from ._base import FeatureSource, Frame, FrameError, Likelihood
from ._resample import (
    NORMALIZATIONS,
    frame_statistics,
    model_shape,
    normalize,
    pad_to_multiple,
    to_frame_grid,
    to_model_grid,
)

__all__ = ["LearnedFeatures", "ModelError", "shipped_model_path", "SHIPPED_MODELS", "wall_offsets"]

SHIPPED_MODELS = {"inplane": "inplane.onnx", "axial": "axial.onnx", "volume": "volume.onnx"}


class ModelError(ValueError):
    """A model file that is missing, corrupt, or made for another modality."""


DRY_RUN_S = 5.0  # the longest the load-time dry run of a model may take
MAX_MODEL_PIXELS = 1 << 24  # a frame on the model's grid: 4096^2 pixels or 256^3 voxels


def _check_normalization_extras(norm: dict, path: Path) -> None:
    """The optional entries of a ``robust`` normalisation: ``clip`` two finite numbers, low
    then high, and ``zero_value`` a finite number."""
    clip = norm.get("clip", NORMALIZATIONS["robust"]["clip"])
    zero = norm.get("zero_value", NORMALIZATIONS["robust"]["zero_value"])
    ok = isinstance(clip, list) and len(clip) == 2 and all(
        isinstance(c, (int, float)) and not isinstance(c, bool) and np.isfinite(c)
        for c in clip) and clip[0] < clip[1]
    ok = ok and isinstance(zero, (int, float)) and not isinstance(zero, bool) and \
        bool(np.isfinite(zero))
    if not ok:
        raise ModelError(f"model {path}: metadata normalization clip {clip!r:.40} and "
                         f"zero_value {zero!r:.40} must be [low, high] and a number, finite")


def wall_offsets(cl: np.ndarray, radius_mm: float) -> np.ndarray:
    """(K, 3) offsets from centre-line samples (probe frame, z = depth) to the wall that faces
    a linear probe: -r times the unit of the beam direction +z made perpendicular to the
    centre line's tangent (where the synth scanner draws the needle's echo). The targets of a
    ``target_reference = "wall"`` model sit there."""
    cl = np.asarray(cl, float)
    t = np.gradient(cl, axis=0) if len(cl) > 1 else np.array([[1.0, 0.0, 0.0]])
    t = t / np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
    nb = np.array([0.0, 0.0, 1.0])[None] - t[:, 2:3] * t
    n = np.linalg.norm(nb, axis=1, keepdims=True)
    nb = np.where(n > 1e-6, nb / np.maximum(n, 1e-12), 0.0)
    return -float(radius_mm) * nb


def shipped_model_path(modality: str) -> Path:
    if modality not in SHIPPED_MODELS:
        raise ModelError(f"no shipped model for modality {modality!r}; "
                         f"there are: {', '.join(SHIPPED_MODELS)}")
    p = Path(str(resources.files("needlenet") / "models" / SHIPPED_MODELS[modality]))
    if not p.exists():
        raise ModelError(f"the shipped {modality} model {p} is missing from this installation")
    return p


class LearnedFeatures(FeatureSource):
    """Shaft and tip probability maps from an ONNX model.

    ``threads``: onnxruntime intra-op threads (the session is set up for low latency:
    sequential execution, all graph optimisations, no thread spinning between calls).
    ``margin_mm``: context added around an ROI before inference.
    """

    kind = "learned"

    def __init__(self, model: str | Path, modality: str | None = None, threads: int = 2,
                 margin_mm: float = 6.0):
        import onnxruntime as ort

        path = Path(model)
        if not path.exists():
            raise ModelError(f"model {path} does not exist")
        if not path.is_file():  # a folder, or a FIFO onnxruntime would wait on for ever
            raise ModelError(f"model {path} is not a regular file")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(str(path), opts,
                                                providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types
            raise ModelError(f"model {path} cannot be loaded by onnxruntime: "
                             f"{str(exc).splitlines()[0]}") from None
        meta = self.session.get_modelmeta().custom_metadata_map
        try:
            self.modality = meta["modality"]
            self.spacing_mm = tuple(float(v) for v in json.loads(meta["spacing_mm"]))
            norm = json.loads(meta["normalization"])
            self.normalization = {**norm, "mode": str(norm.get("mode", "fixed")),
                                  "scale": float(norm["scale"]), "mean": float(norm["mean"]),
                                  "std": float(norm["std"])}
            if self.normalization["mode"] not in NORMALIZATIONS:
                raise ValueError(f"normalization mode {self.normalization['mode']!r}")
            self.stride = int(meta.get("output_stride", 2))
            self.multiple = int(meta.get("input_multiple", 4))
        except (KeyError, ValueError, TypeError, AttributeError, RecursionError) as exc:
            raise ModelError(f"model {path}: metadata key {str(exc)[:80]} missing or invalid; "
                             "was it written by 'needlenet export'?") from None
        if modality is not None and modality != self.modality:
            raise ModelError(f"model {path} is a {self.modality!r} model, not {modality!r}")
        inputs = [i.name for i in self.session.get_inputs()]
        outputs = [o.name for o in self.session.get_outputs()]
        if inputs != ["image"] or outputs != ["likelihood"]:
            raise ModelError(f"model {path}: expected input 'image' and output 'likelihood', "
                             f"got {inputs} -> {outputs}")
        self._check_model(path)
        self.path = path
        self.name = f"learned:{path.name}"
        self.margin_mm = float(margin_mm)
        self.version = meta.get("needlenet_version", "")
        # where the maps mark the needle: its centre line, or ("wall") the wall facing a
        # linear probe, which the trackers move to the centre line by the needle's radius
        self.target_reference = meta.get("target_reference", "centerline")
        if self.target_reference not in ("centerline", "wall"):
            raise ModelError(f"model {path}: metadata target_reference must be 'centerline' "
                             f"or 'wall', got {self.target_reference!r}")

    def _check_model(self, path: Path) -> None:
        """Metadata in range, an input of rank 2 + D with free spatial axes, and one dry run on
        a black image that must give two finite maps: a model that cannot track is refused
        when it is loaded, not at the first frame."""
        nd = 3 if self.modality == "volume" else 2
        if self.modality not in ("inplane", "axial", "volume"):
            raise ModelError(f"model {path}: metadata modality {self.modality!r} is not "
                             "inplane, axial or volume")
        sp = np.asarray(self.spacing_mm, float)
        if sp.shape != (nd,) or not np.all((sp >= 0.005) & (sp <= 5.0)):
            raise ModelError(f"model {path}: metadata spacing_mm {list(self.spacing_mm)} must "
                             f"be {nd} values in 0.005-5 mm")
        max_multiple = 32 if nd == 3 else 256
        if not 1 <= self.stride <= 16 or not 1 <= self.multiple <= max_multiple:
            raise ModelError(f"model {path}: metadata output_stride {self.stride} and "
                             f"input_multiple {self.multiple} must be 1-16 and 1-{max_multiple}")
        n = self.normalization
        if not all(np.isfinite(n[k]) for k in ("scale", "mean", "std")) or n["std"] <= 0 \
                or n["scale"] <= 0:
            raise ModelError(f"model {path}: metadata normalization {n} needs finite values "
                             "and a positive scale and std")
        _check_normalization_extras(n, path)
        shape = self.session.get_inputs()[0].shape
        if len(shape) != 2 + nd:
            raise ModelError(f"model {path}: input 'image' has rank {len(shape)}; a "
                             f"{self.modality} model takes (batch, 1, {nd} spatial axes)")
        if any(isinstance(d, int) for d in shape[2:]):
            raise ModelError(f"model {path}: input 'image' has fixed spatial axes {shape[2:]}; "
                             "needlenet feeds frames of any size (export with dynamic axes)")
        # the smallest input a model of this multiple takes that is still an image: 32 px
        # (2D) or 4 voxels (3D) a side, so that a model that blows its input up (or loops)
        # costs little here and is refused below (measured: a volume model that upsamples
        # 64x took 1.6 GB on an 8^3 input, 0.2 GB on 4^3)
        least = 4 if nd == 3 else 32
        side = self.multiple * -(-least // self.multiple)
        black = np.zeros((side,) * nd, np.float32)  # a black frame, normalised as any frame
        blank = normalize(black, self.normalization,
                          frame_statistics(black, self.normalization))[None, None]
        y = self._dry_run(blank, path, side)
        if y.ndim != 2 + nd or y.shape[1] != 2:
            raise ModelError(f"model {path}: output 'likelihood' has shape {y.shape} for a "
                             f"{blank.shape} input; expected (batch, 2 maps: shaft, tip, ...)")
        if not np.issubdtype(y.dtype, np.floating):
            raise ModelError(f"model {path}: output 'likelihood' is {y.dtype}; expected "
                             "probabilities (float)")
        want = side / self.stride
        if any(abs(k - want) > 1 for k in y.shape[2:]):
            raise ModelError(f"model {path}: output 'likelihood' has spatial shape "
                             f"{tuple(y.shape[2:])} for a {side}-pixel input; metadata "
                             f"output_stride {self.stride} says {side // self.stride} a side")
        if not np.all(np.isfinite(y)):
            raise ModelError(f"model {path}: output 'likelihood' is not finite on a black "
                             "frame")

    def _dry_run(self, blank: np.ndarray, path: Path, side: int) -> np.ndarray:
        """The model on ``blank``, stopped after :data:`DRY_RUN_S` (a model for real-time
        tracking takes milliseconds on it)."""
        import threading

        import onnxruntime as ort

        ro = ort.RunOptions()
        ro.log_severity_level = 4  # the error is reported below, not logged by onnxruntime
        timer = threading.Timer(DRY_RUN_S, lambda: setattr(ro, "terminate", True))
        timer.daemon = True
        timer.start()
        try:
            return self.session.run(["likelihood"], {"image": blank}, ro)[0]
        except Exception as exc:  # onnxruntime raises its own exception types
            why = f"took longer than {DRY_RUN_S:g} s" if ro.terminate else \
                f"failed: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
            raise ModelError(f"model {path}: a dry run on a blank {side}-pixel input {why}"
                             ) from None
        finally:
            timer.cancel()

    def check_frame_size(self, shape, spacing_mm) -> tuple[int, ...]:
        """The shape a frame of ``shape`` at ``spacing_mm`` takes on the model's grid; a
        ModelError when it exceeds :data:`MAX_MODEL_PIXELS` (a model made for 0.005 mm
        pixels would turn a 3D volume at 1 mm into 10^11 voxels)."""
        grid = model_shape(tuple(shape), tuple(float(s) for s in spacing_mm), self.spacing_mm)
        n = int(np.prod([float(g) for g in grid]))
        if n > MAX_MODEL_PIXELS:
            raise ModelError(f"model {self.path}: frames of {tuple(shape)} pixels at "
                             f"{[round(float(s), 4) for s in spacing_mm]} mm become {grid} = "
                             f"{n:.3g} pixels at the model's spacing_mm {list(self.spacing_mm)} "
                             f"(at most {MAX_MODEL_PIXELS}); use a model made for this spacing")
        return grid

    def run_model(self, image: np.ndarray, spacing_mm, level: float | None = None) -> np.ndarray:
        """Maps (2, *image.shape) in [0, 1] for an image at ``spacing_mm``; ``level``: the
        whole frame's :func:`frame_statistics` when ``image`` is an ROI of it. A frame too
        large on the model's grid (:meth:`check_frame_size`) is a FrameError: no evidence."""
        try:
            self.check_frame_size(np.shape(image), spacing_mm)
        except ModelError as exc:
            raise FrameError(str(exc)) from None
        x = to_model_grid(image, spacing_mm, self.spacing_mm)
        if level is None:
            level = frame_statistics(image, self.normalization)
        x = normalize(x, self.normalization, level)
        xp, crop = pad_to_multiple(x, self.multiple)
        y = self.session.run(["likelihood"], {"image": xp[None, None].astype(np.float32)})[0][0]
        up = to_frame_grid(y, xp.shape)  # stride-2 output back to the padded model grid
        up = up[(slice(None),) + crop]
        # fmax/fmin clip like np.clip but turn NaN into 0: a model that fails somewhere gives
        # no evidence there (the tracker then says lost), never a NaN estimate
        return np.fmin(np.fmax(to_frame_grid(up, image.shape), 0.0), 1.0)

    def likelihood(self, frame: Frame, roi: tuple[slice, ...] | None = None) -> Likelihood:
        im = np.asarray(frame.image)
        sp = frame.grid.spacing_mm
        if roi is None:
            maps = self.run_model(im, sp)
            return Likelihood(shaft=maps[0], tip=maps[1], source=self.name)
        # an ROI: add context, run on the crop, paste into empty full-size maps
        m = [int(np.ceil(self.margin_mm / s)) for s in sp]
        big = tuple(slice(max((r.start or 0) - k, 0), min((r.stop or n) + k, n))
                    for r, k, n in zip(roi, m, im.shape, strict=True))
        level = frame_statistics(im, self.normalization)
        maps = self.run_model(im[big], sp, level)
        shaft = np.zeros(im.shape, np.float32)
        tip = np.zeros(im.shape, np.float32)
        shaft[big], tip[big] = maps[0], maps[1]
        return Likelihood(shaft=shaft, tip=tip, source=self.name)
