"""The onnxruntime sessions that run one model: the model as exported, whose spatial axes are
free, and for a 2-D input size that recurs (a recording's frames) one fixed to that size.

onnxruntime runs a 2-D network's convolutions with its tensors laid out in blocks of channels
(its NCHWc layout), and fuses a residual addition and the activation after it into the
convolution before, only where it can show that the two tensors added have one shape. With
free spatial axes it cannot after a dilated convolution (the shape it infers there is a new
unknown), so around those additions it reorders the tensors back, reshapes and adds them
apart, and the decoder's upsampling leaves the layout as well. Fixed to the input's size
(a free dimension override), the whole network runs in that layout, in about two thirds of
the time for the shipped in-plane model (docs/notes/speed.md); its maps agree with the
exported session's to float rounding (a few 1e-7). 3-D convolutions have no such layout, and
3-D inputs keep the exported session.
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import numpy as np

__all__ = ["ModelSessions", "session_options"]

MAX_FIXED = 4  # fixed-size sessions kept (the least recently used goes first)
_MAX_SEEN = 64  # input sizes remembered until they recur: a bound on memory


def session_options(threads: int, free_dims: dict[str, int] | None = None):
    """onnxruntime's options for low latency, as its tuning guide has them: ``threads``
    intra-op threads, sequential execution, every graph optimisation, and no thread spinning
    between calls (on a shared machine spinning threads take the cores other work needs);
    ``free_dims`` fixes the model's named free dimensions to those sizes."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = int(threads)
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    for name, size in (free_dims or {}).items():
        opts.add_free_dimension_override_by_name(name, int(size))
    return opts


class ModelSessions:
    """The exported session of the model at ``path`` (``exported``; built by the caller, who
    checks the model) and the fixed-size ones: built for a whole frame's size when it is first
    run, and for another input's (an ROI's crop) the second time its size is run (a size met
    once is not worth a session)."""

    def __init__(self, path: str | Path, exported, threads: int):
        self.path = str(path)
        self.exported = exported
        self.threads = int(threads)
        self._fixed: OrderedDict[tuple[int, ...], object] = OrderedDict()
        self._seen: set[tuple[int, ...]] = set()

    def _axes(self) -> list[str] | None:
        """The names of the exported input's spatial axes, when it has two, named, and
        different (a free dimension is fixed by its name)."""
        names = self.exported.get_inputs()[0].shape[2:]
        if len(names) != 2 or not all(isinstance(n, str) and n for n in names) or \
                len(set(names)) != len(names):
            return None
        return list(names)

    def session_for(self, shape: tuple[int, ...], build: bool = True):
        """The session that runs inputs of spatial ``shape``: its fixed one (built now when
        ``build`` and there is none yet), else the exported one."""
        shape = tuple(int(n) for n in shape)
        fixed = self._fixed.get(shape)
        if fixed is not None:
            self._fixed.move_to_end(shape)
            return fixed
        if not build or len(shape) != 2:
            return self.exported
        names = self._axes()
        fixed = self.exported  # where the axes cannot be fixed, or the session not built
        if names is not None:
            import onnxruntime as ort

            opts = session_options(self.threads, dict(zip(names, shape, strict=True)))
            try:
                fixed = ort.InferenceSession(self.path, opts, providers=["CPUExecutionProvider"])
            except Exception:  # onnxruntime raises its own exception types
                pass
        self._fixed[shape] = fixed
        if len(self._fixed) > MAX_FIXED:
            self._fixed.popitem(last=False)
        return fixed

    def run(self, x: np.ndarray, whole_frame: bool = False) -> np.ndarray:
        """The model's ``likelihood`` output for the input ``x`` (batch, channels, *spatial),
        float32. ``whole_frame``: ``x`` is a whole frame of a recording, whose size recurs
        with every frame, so its fixed session is built now rather than on its second run."""
        shape = tuple(int(n) for n in x.shape[2:])
        again = whole_frame or shape in self._seen
        if not again:
            if len(self._seen) >= _MAX_SEEN:
                self._seen.clear()
            self._seen.add(shape)
        return self.session_for(shape, build=again).run(["likelihood"], {"image": x})[0]
