"""Learned features: an ONNX model run with onnxruntime as a FeatureSource.

The model carries in its metadata the spacing it was trained at, the intensity normalisation
and its modality. Each frame (or ROI) is resampled to the model's spacing, padded to the
network's multiple, run, and its shaft and tip maps are mapped back to the frame's grid.

A region given as voxels (a tracker's ROI) is covered by boxes of the whole frame's model
grid, each the region's part plus ``margin_mm`` of context (:func:`plan_boxes`); the network
runs on each box, and the maps are mapped back only around the region, by the same linear
maps as the whole frame's (:class:`GridMaps`), so inside the region they differ from the
whole-frame maps only by the context the boxes leave out.
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import numpy as np

from ._base import FeatureSource, Frame, FrameError, Likelihood
from ._resample import (
    NORMALIZATIONS,
    apply_weights,
    clip_unit,
    frame_image_statistics,
    frame_statistics,
    model_grid,
    model_shape,
    normalize,
    pad_to_multiple,
    resize_weights,
    to_frame_grid,
    to_model_grid,
)
from ._sessions import ModelSessions, session_options
from ._speckle import grid_scale, speckle_widths

__all__ = ["GridMaps", "LearnedFeatures", "ModelError", "SHIPPED_MODELS", "plan_boxes",
           "shipped_model_path", "wall_offsets"]

SHIPPED_MODELS = {"inplane": "inplane.onnx", "axial": "axial.onnx", "volume": "volume.onnx"}


class ModelError(ValueError):
    """A model file that is missing, corrupt, or made for another modality."""


DRY_RUN_S = 5.0  # the longest the load-time dry run of a model may take
MAX_MODEL_PIXELS = 1 << 24  # a frame on the model's grid: 4096^2 pixels or 256^3 voxels
# plan_boxes: the fixed cost of one onnxruntime call in output samples of the network (0.1-0.2
# ms, what a network of the shipped size spends on ~500 of them) and the most boxes a region is
# split into; the fixed cost of mapping one part of a region back to the frame, in output
# samples mapped, and the most parts
CALL_COST_SAMPLES = 500
MAX_BOXES = 8
PART_COST_SAMPLES = 50
MAX_PARTS = 16


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


class GridMaps:
    """The linear maps between the grid of frames of one shape and spacing and a model's grid,
    as :meth:`LearnedFeatures.run_model` applies them (:func:`resize_weights`), one matrix
    per axis:

    - ``w_in``: frame samples -> the model's grid padded to the network's ``multiple`` (the
      padding repeats the last sample, as :func:`pad_to_multiple`);
    - ``w_out``: the network's output (``stride`` samples of the model's grid apart) -> frame
      samples: up to the padded model grid, cropped to the model's grid, to the frame's grid;
    - ``first``, ``last``: for each frame sample, the first and last output sample it reads.
    """

    def __init__(self, shape, spacing_mm, model_spacing_mm, multiple: int, stride: int):
        self.shape = tuple(int(n) for n in shape)
        self.model = model_shape(self.shape, tuple(spacing_mm), tuple(model_spacing_mm))
        self.padded = tuple(n + (-n) % multiple for n in self.model)
        self.out = tuple(-(-n // stride) for n in self.padded)
        self.stride = stride
        self.w_in = [np.vstack([w, np.repeat(w[-1:], p - g, axis=0)]) for w, g, p in
                     zip(resize_weights(self.shape, self.model), self.model, self.padded,
                         strict=True)]
        up = resize_weights(self.out, self.padded)
        down = resize_weights(self.model, self.shape)
        self.w_out = [d @ u[:g] for d, u, g in zip(down, up, self.model, strict=True)]
        nz = [w != 0 for w in self.w_out]
        self.first = [np.argmax(z, axis=1) for z in nz]
        self.last = [z.shape[1] - 1 - np.argmax(z[:, ::-1], axis=1) for z in nz]


def _split(pts: np.ndarray, t: np.ndarray, k: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The bounds (inclusive) of the points in each of ``k`` equal intervals of ``t``; the
    points sorted by ``t``."""
    cuts = np.searchsorted(t, np.linspace(t[0], t[-1], k + 1)[1:-1], side="right")
    starts = np.unique(np.r_[0, cuts])
    starts = starts[starts < len(t)]
    lo = np.minimum.reduceat(pts, starts, axis=0)
    hi = np.maximum.reduceat(pts, starts, axis=0)
    return list(zip(lo, hi, strict=True))


def plan_boxes(cells: np.ndarray, grid, margin, align: int, reach):
    """Where to run a network so that its output covers ``cells``, and the parts to map back.

    ``cells`` (N, D): output samples (the first each voxel of a region reads, each reading up
    to ``reach`` samples further per axis); ``margin``: samples of context a box adds on each
    side (none where it meets the grid's faces, as the whole grid does); box corners are
    multiples of ``align`` (where the network's strides line a box up with the whole grid).
    The cells are split into parts of equal length along their principal axis (a tube along a
    diagonal fills few of the voxels of one box around it): up to ``MAX_BOXES`` boxes, the
    number with the fewest samples to run (each run counting ``CALL_COST_SAMPLES`` more), and
    up to ``MAX_PARTS`` parts to map back, the number with the fewest samples to map.

    Returns ``(parts, boxes)``: the inclusive bounds ``(lo, hi)`` of the cells of each part,
    and the ``(start, stop)`` of each box, None when one run on the whole grid costs less.
    """
    pts = np.asarray(cells, np.int64)
    grid, margin, reach = (np.asarray(a, np.int64) for a in (grid, margin, reach))
    centred = pts - pts.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0] if len(pts) > 1 else \
        np.eye(pts.shape[1])[0]
    t = centred @ axis
    order = np.argsort(t, kind="stable")
    pts, t = pts[order], t[order]
    best_boxes = best_parts = None
    for k in range(1, max(MAX_BOXES, MAX_PARTS) + 1):
        split = _split(pts, t, k)
        cost = sum(int(np.prod(hi + reach + 1 - lo)) + PART_COST_SAMPLES for lo, hi in split)
        if k <= MAX_PARTS and (best_parts is None or cost < best_parts[0]):
            best_parts = (cost, split)
        if k > MAX_BOXES:
            continue
        boxes = [(np.maximum((lo - margin) // align * align, 0),
                  np.minimum(-(-(hi + reach + 1 + margin) // align) * align, grid))
                 for lo, hi in split]
        cost = sum(int(np.prod(b - a)) + CALL_COST_SAMPLES for a, b in boxes)
        if best_boxes is None or cost < best_boxes[0]:
            best_boxes = (cost, boxes)
    if int(np.prod(grid)) + CALL_COST_SAMPLES <= best_boxes[0]:
        return best_parts[1], None
    return best_parts[1], best_boxes[1]


class LearnedFeatures(FeatureSource):
    """Shaft and tip probability maps from an ONNX model.

    ``threads``: onnxruntime intra-op threads (the sessions are set up for low latency:
    :func:`~._sessions.session_options`; a 2-D frame size that recurs runs on a session fixed
    to it, :class:`~._sessions.ModelSessions`). ``margin_mm``: context added around an ROI,
    or around each box covering a region, before inference.
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
        try:
            session = ort.InferenceSession(str(path), session_options(threads),
                                           providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types
            raise ModelError(f"model {path} cannot be loaded by onnxruntime: "
                             f"{str(exc).splitlines()[0]}") from None
        self.sessions = ModelSessions(path, session, threads)
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
            self.speckle_cell_mm = None if "speckle_cell_mm" not in meta else \
                float(meta["speckle_cell_mm"])
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
        if self.modality == "volume":  # load the compiled resampling now, not at a volume
            apply_weights(np.zeros((2, 2, 2), np.float32), [np.eye(2)] * 3)
        self._grid: GridMaps | None = None
        self._grid_key: tuple | None = None
        self.model_spacing_mm = self.spacing_mm  # the grid the model was trained on
        self._speckle_grids: dict[tuple, tuple[float, ...]] = {}
        self.recording_speckle_mm: tuple[float, float] | None = None  # last measured widths
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

    @property
    def session(self):
        """The onnxruntime session of the model as exported (free spatial axes)."""
        return self.sessions.exported

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
        if self.speckle_cell_mm is not None and not (nd == 2 and 0 < self.speckle_cell_mm <= 50):
            raise ModelError(f"model {path}: metadata speckle_cell_mm {self.speckle_cell_mm} "
                             "must be a size in 0-50 mm, on a 2D model")
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

    def match_speckle(self, image: np.ndarray, spacing_mm) -> tuple[float, ...]:
        """The grid the model runs on for frames like ``image`` (2D), returned and set: the
        model's own, or for a model that records its training worlds' speckle cell size
        (``speckle_cell_mm``) one coarsened so that the recording's speckle has that size on
        it (:mod:`._speckle`). Chosen on the first frame of a shape and spacing that holds
        speckle, then kept for the recording; the widths measured are kept in
        ``recording_speckle_mm``."""
        if self.speckle_cell_mm is None or np.ndim(image) != 2:
            return self.spacing_mm
        key = (tuple(np.shape(image)), tuple(float(s) for s in spacing_mm))
        grid = self._speckle_grids.get(key)
        if grid is None:
            w = speckle_widths(image, spacing_mm, self.model_spacing_mm)
            if w is None:  # no speckle on this frame (blank, masked): the model's grid for now
                self.spacing_mm = self.model_spacing_mm
                return self.spacing_mm
            self.recording_speckle_mm = (float(w[0]), float(w[1]))
            s = grid_scale(w, self.speckle_cell_mm)
            grid = tuple(v * s for v in self.model_spacing_mm)
            if len(self._speckle_grids) >= 16:  # a stream of ever-new frame sizes
                self._speckle_grids.clear()
            self._speckle_grids[key] = grid
        self.spacing_mm = grid
        return grid

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
        # linear resampling keeps the clipped maps in [0, 1]
        return to_frame_grid(self._model_grid_maps(image, spacing_mm, level,
                                                   whole_frame=level is None), image.shape)

    def _model_grid_maps(self, image: np.ndarray, spacing_mm, level=None,
                         whole_frame: bool = False) -> np.ndarray:
        """The network's maps (2, *model shape) on the model's grid, in [0, 1]; a FrameError
        for a frame too large there. ``whole_frame``: ``image`` is a whole frame (its size
        recurs: :meth:`~._sessions.ModelSessions.run`)."""
        try:
            self.check_frame_size(np.shape(image), spacing_mm)
        except ModelError as exc:
            raise FrameError(str(exc)) from None
        x = to_model_grid(image, spacing_mm, self.spacing_mm)
        if level is None:
            level = frame_statistics(image, self.normalization)
        x = normalize(x, self.normalization, level)
        xp, crop = pad_to_multiple(x, self.multiple)
        y = self.sessions.run(xp[None, None].astype(np.float32), whole_frame)[0]
        up = to_frame_grid(y, xp.shape)[(slice(None),) + crop]  # stride 2 -> the model grid
        return clip_unit(up)

    def native_likelihood(self, frame: Frame):
        """2D frames: the maps on the model's grid (:func:`model_grid`), without their return
        to the frame's grid; 3D frames: :meth:`likelihood`'s."""
        im = np.asarray(frame.image)
        if im.ndim != 2:
            return self.likelihood(frame), frame.grid
        self.match_speckle(im, frame.grid.spacing_mm)
        level = frame_image_statistics(frame) if self.normalization["mode"] == "robust" else None
        maps = self._model_grid_maps(im, frame.grid.spacing_mm, level, whole_frame=True)
        return (Likelihood(shaft=maps[0], tip=maps[1], source=self.name),
                model_grid(frame.grid, maps.shape[1:]))

    def likelihood(self, frame: Frame, roi=None) -> Likelihood:
        """Maps on the frame's grid. ``roi``: None (the whole frame); a tuple of slices (one
        box, run with ``margin_mm`` of context around it); or the flat indices of a region's
        voxels (:meth:`region_likelihood`). Away from the ROI or region the maps are 0."""
        im = np.asarray(frame.image)
        sp = frame.grid.spacing_mm
        self.match_speckle(im, sp)
        if roi is None and im.ndim == 3:  # mapped back by GridMaps, in half cv2's time
            return self.region_likelihood(frame, None)
        if roi is None:
            maps = self.run_model(im, sp)
            return Likelihood(shaft=maps[0], tip=maps[1], source=self.name)
        if isinstance(roi, np.ndarray):
            return self.region_likelihood(frame, roi)
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

    def _grid_maps(self, shape, spacing_mm) -> GridMaps:
        """The :class:`GridMaps` of frames of this shape and spacing (the last one kept)."""
        key = (tuple(shape), tuple(float(s) for s in spacing_mm))
        if self._grid_key != key:
            self._grid = GridMaps(shape, spacing_mm, self.spacing_mm, self.multiple, self.stride)
            self._grid_key = key
        return self._grid

    def _run_box(self, x: np.ndarray) -> np.ndarray | None:
        """The shaft and tip outputs for a model-grid input ``x``; None when their shape is not
        ``x``'s over the stride (a model the region path cannot line up)."""
        y = self.sessions.run(x[None, None].astype(np.float32))[0]
        want = tuple(-(-n // self.stride) for n in x.shape)
        return y[:2] if tuple(y.shape[1:]) == want else None

    def region_likelihood(self, frame: Frame, region: np.ndarray | None) -> Likelihood:
        """Maps valid on the voxels ``region`` (flat indices; None: every voxel); 0 away from
        the parts of the frame around them.

        The voxels' output samples are covered by boxes of the whole frame's padded model grid
        (:func:`plan_boxes`, with ``margin_mm`` of context, or the whole grid where that costs
        less); each box is resampled from the frame by the rows of the whole frame's linear
        maps (:class:`GridMaps`), normalised with the whole frame's statistics and run; its
        output away from the context is pasted into the output grid, which is mapped to the
        frame's grid around the region's parts only. Where the context covers the network's
        receptive field the maps are :meth:`run_model`'s (to float rounding)."""
        im = np.asarray(frame.image)
        sp = frame.grid.spacing_mm
        try:
            self.check_frame_size(im.shape, sp)
        except ModelError as exc:
            raise FrameError(str(exc)) from None
        g = self._grid_maps(im.shape, sp)
        align = self.multiple // self.stride if self.multiple % self.stride == 0 else 0
        margin = [int(np.ceil(self.margin_mm / (self.stride * s))) for s in self.spacing_mm]
        if region is None or not align:  # every voxel, from one run on the whole grid
            shaft = np.empty(im.shape, np.float32)
            tip = np.empty(im.shape, np.float32)
            parts, boxes = [(np.zeros(im.ndim, int), np.asarray(g.out) - 1)], None
        else:
            shaft = np.zeros(im.shape, np.float32)
            tip = np.zeros(im.shape, np.float32)
            region = np.asarray(region, np.int64).reshape(-1)
            if region.size == 0:
                return Likelihood(shaft=shaft, tip=tip, source=self.name)
            idx = np.unravel_index(region, im.shape)
            hit = np.zeros(g.out, bool)  # the output samples the region's voxels start reading
            hit[tuple(f[i] for f, i in zip(g.first, idx, strict=True))] = True
            reach = [int(np.max(b - a)) for a, b in zip(g.first, g.last, strict=True)]
            parts, boxes = plan_boxes(np.argwhere(hit), g.out, margin, align, reach)
        level = frame_statistics(im, self.normalization)
        if boxes is None:
            x = normalize(to_model_grid(im, sp, self.spacing_mm), self.normalization, level)
            y = self._run_box(pad_to_multiple(x, self.multiple)[0])
        else:
            y = np.zeros((2, *g.out), np.float32)
            for start, stop in boxes:
                rows = [w[self.stride * a:self.stride * b] for w, a, b in
                        zip(g.w_in, start, stop, strict=True)]
                cols = [np.flatnonzero(r.any(axis=0)) for r in rows]
                crop = tuple(slice(c[0], c[-1] + 1) for c in cols)
                x = apply_weights(im[crop], [r[:, c] for r, c in zip(rows, crop, strict=True)])
                out = self._run_box(normalize(x, self.normalization, level))
                if out is None:
                    y = None
                    break
                core = tuple(slice(a + m if a > 0 else 0, b - m if b < n else n) for a, b, m, n
                             in zip(start, stop, margin, g.out, strict=True))
                y[(slice(None),) + core] = out[(slice(None),) + tuple(
                    slice(c.start - a, c.stop - a) for c, a in zip(core, start, strict=True))]
        if y is None:  # a model whose output does not line up: the whole frame, resized
            maps = self.run_model(im, sp)
            return Likelihood(shaft=maps[0], tip=maps[1], source=self.name)
        for lo, hi in parts:
            rows = tuple(slice(int(np.searchsorted(f, a, "left")),
                               int(np.searchsorted(f, b, "right")))
                         for f, a, b in zip(g.first, lo, hi, strict=True))
            cols = tuple(slice(int(f[r.start]), int(la[r.stop - 1]) + 1)
                         for f, la, r in zip(g.first, g.last, rows, strict=True))
            maps = apply_weights(y[(slice(None),) + cols],
                                 [w[r, c] for w, r, c in zip(g.w_out, rows, cols, strict=True)])
            clip_unit(maps)  # NaN (a model that fails somewhere) becomes 0, as in run_model
            shaft[rows], tip[rows] = maps[0], maps[1]
        return Likelihood(shaft=shaft, tip=tip, source=self.name)
