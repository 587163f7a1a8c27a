"""A model that cannot track is refused when it is loaded, naming what is wrong; a model that
gives NaN on some frames yields no evidence there, never NaN maps."""

import json

import numpy as np
import pytest

import synth
from needlenet.features import ModelError
from needlenet.features._base import Frame
from needlenet.features._learned import LearnedFeatures

onnx = pytest.importorskip("onnx")
from onnx import TensorProto, helper  # noqa: E402

_META = {"modality": "inplane", "spacing_mm": "[0.2, 0.2]", "output_stride": "1",
         "input_multiple": "4", "target_reference": "wall",
         "normalization": json.dumps({"mode": "fixed", "scale": 1 / 255, "mean": 0.35,
                                      "std": 0.25})}


def _model(path, op="sigmoid", in_shape=("N", 1, "H", "W"), channels=2, **meta):
    """A small model: 'image' -> ``channels`` copies of sigmoid(image), sqrt(image) (NaN where
    the normalised input is negative) or sqrt(-image) (NaN where it is positive)."""
    x = helper.make_tensor_value_info("image", TensorProto.FLOAT, list(in_shape))
    y = helper.make_tensor_value_info("likelihood", TensorProto.FLOAT, None)
    nodes = {"sigmoid": [helper.make_node("Sigmoid", ["image"], ["m"])],
             "sqrt": [helper.make_node("Sqrt", ["image"], ["m"])],
             "sqrt_neg": [helper.make_node("Neg", ["image"], ["n"]),
                          helper.make_node("Sqrt", ["n"], ["m"])]}[op]
    nodes.append(helper.make_node("Concat", ["m"] * channels, ["likelihood"], axis=1))
    m = helper.make_model(helper.make_graph(nodes, "g", [x], [y]),
                          opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    helper.set_model_props(m, {**_META, **meta})
    onnx.save(m, str(path))
    return path


def test_a_well_formed_model_loads(tmp_path):
    f = LearnedFeatures(_model(tmp_path / "ok.onnx"), "inplane")
    maps = f.run_model(np.full((40, 30), 90, np.uint8), (0.2, 0.2))
    assert maps.shape == (2, 40, 30) and np.all(np.isfinite(maps))


@pytest.mark.parametrize("kwargs, message", [
    ({"in_shape": ("N", "H", "W")}, r"input 'image' has rank 3"),
    ({"in_shape": (1, 1, 64, 64)}, r"fixed spatial axes \[64, 64\]"),
    ({"channels": 1}, r"output 'likelihood' has shape \(1, 1, "),
    ({"spacing_mm": "[0.0, 0.2]"}, r"spacing_mm \[0.0, 0.2\] must be 2 values in 0.005-5 mm"),
    ({"input_multiple": "0"}, r"input_multiple 0 must be"),
    ({"normalization": json.dumps({"mode": "fixed", "scale": 1, "mean": 0, "std": 0})},
     r"positive scale and std"),
    ({"op": "sqrt", "normalization": json.dumps({"mode": "fixed", "scale": 1 / 255,
                                                 "mean": 0.5, "std": 0.25})},
     r"not finite on a black frame"),
])
def test_a_model_that_cannot_track_is_refused_at_load(tmp_path, kwargs, message):
    with pytest.raises(ModelError, match=rf"bad\.onnx: .*{message}"):
        LearnedFeatures(_model(tmp_path / "bad.onnx", **kwargs), "inplane")


def test_nan_from_the_model_is_no_evidence(tmp_path):
    """sqrt(-normalised image): finite on the black dry run, NaN on every pixel brighter than
    the normalisation's mean grey (89) of a real frame."""
    f = LearnedFeatures(_model(tmp_path / "n.onnx", op="sqrt_neg"), "inplane")
    seq = synth.generate("inplane", seed=3, frames=1, width_mm=12.0, depth_mm=12.0)
    assert (seq.images[0] > 89).mean() > 0.05
    lik = f.likelihood(Frame(seq.images[0], seq.grid(), 0.0))
    for m in (lik.shaft, lik.tip):
        assert np.all(np.isfinite(m)) and m.min() >= 0.0 and m.max() <= 1.0


# -- found by the fuzz suite (tests/fuzz) --------------------------------------------------------

def test_a_model_of_ints_or_of_the_wrong_size_is_refused(tmp_path):
    """An int64 output made OpenCV's resize raise at the first frame; an output 64 times the
    input's size allocated 1.6 GB in the dry run of a volume model."""
    from tests.fuzz.cases._base import make_model

    (tmp_path / "i.onnx").write_bytes(make_model("inplane", op="int64"))
    with pytest.raises(ModelError, match=r"output 'likelihood' is int64; expected"):
        LearnedFeatures(tmp_path / "i.onnx", "inplane")
    (tmp_path / "u.onnx").write_bytes(make_model("volume", op="up64"))
    with pytest.raises(ModelError, match=r"spatial shape \(256, 256, 256\) for a 4-pixel input"):
        LearnedFeatures(tmp_path / "u.onnx", "volume")
    (tmp_path / "m.onnx").write_bytes(make_model("volume", meta={"input_multiple": "256"}))
    with pytest.raises(ModelError, match=r"input_multiple 256 must be 1-16 and 1-32"):
        LearnedFeatures(tmp_path / "m.onnx", "volume")


def test_a_model_that_never_ends_its_dry_run_is_stopped(tmp_path, monkeypatch):
    import time

    from needlenet.features import _learned
    from tests.fuzz.cases._base import make_model

    monkeypatch.setattr(_learned, "DRY_RUN_S", 0.5)
    (tmp_path / "slow.onnx").write_bytes(make_model("inplane", op="slow"))
    t0 = time.perf_counter()
    with pytest.raises(ModelError, match=r"a dry run on a blank 32-pixel input took longer "
                                         r"than 0\.5 s"):
        LearnedFeatures(tmp_path / "slow.onnx", "inplane")
    assert time.perf_counter() - t0 < 10


def test_a_fifo_a_bad_robust_clip_and_a_spacing_too_fine_are_named(tmp_path):
    import os

    from needlenet.features._base import FrameError

    os.mkfifo(tmp_path / "fifo.onnx")
    with pytest.raises(ModelError, match=r"fifo\.onnx is not a regular file"):
        LearnedFeatures(tmp_path / "fifo.onnx", "inplane")
    norm = {"mode": "robust", "scale": 1, "mean": 0, "std": 1, "clip": "x"}
    with pytest.raises(ModelError, match=r"normalization clip 'x'"):
        LearnedFeatures(_model(tmp_path / "c.onnx", normalization=json.dumps(norm)), "inplane")
    f = LearnedFeatures(_model(tmp_path / "fine.onnx", spacing_mm="[0.005, 0.005]"), "inplane")
    with pytest.raises(ModelError, match=r"become \(100000, 100000\) = 1e\+10 pixels at the "
                                         r"model's spacing_mm \[0\.005, 0\.005\]"):
        f.check_frame_size((1000, 1000), (0.5, 0.5))
    with pytest.raises(FrameError):  # tracking goes on without evidence, allocates nothing
        f.run_model(np.zeros((1000, 1000), np.uint8), (0.5, 0.5))
