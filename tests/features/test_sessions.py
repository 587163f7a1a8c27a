"""The sessions that run a model: a 2-D input size that recurs runs on a session fixed to it,
whose maps are the exported session's to float rounding."""

import numpy as np
import pytest

from needlenet.features import LearnedFeatures
from needlenet.features._learned import shipped_model_path
from needlenet.features._sessions import MAX_FIXED, ModelSessions


def _model(modality: str):
    try:
        return shipped_model_path(modality)
    except ValueError:
        pytest.skip(f"no shipped {modality} model in this checkout")


def _input(shape, seed=0):
    return np.random.default_rng(seed).normal(0.0, 2.0, (1, 1, *shape)).astype(np.float32)


@pytest.mark.parametrize("modality,shape", [("inplane", (252, 192)), ("inplane", (64, 100)),
                                            ("axial", (64, 64))])
def test_a_recurring_size_runs_fixed_with_the_exported_maps(modality, shape):
    """The first run of a size is the exported session's; the second builds the fixed one,
    which gives the same maps to float rounding (onnxruntime fuses the network's additions
    and activations into its convolutions there, in another order of rounding). A whole
    frame's size gets its session on its first run."""
    f = LearnedFeatures(_model(modality))
    s = f.sessions
    x = _input(shape)
    first = s.run(x)
    assert s.session_for(shape, build=False) is s.exported  # seen once: no session yet
    second = s.run(x)
    fixed = s.session_for(shape, build=False)
    assert fixed is not s.exported
    assert fixed.get_inputs()[0].shape == [1, 1, *shape]
    np.testing.assert_array_equal(first, s.exported.run(["likelihood"], {"image": x})[0])
    assert second.shape == first.shape and second.dtype == np.float32
    np.testing.assert_allclose(second, first, rtol=0, atol=2e-6)
    other = tuple(n + 4 for n in shape)
    s.run(_input(other), whole_frame=True)
    assert s.session_for(other, build=False) is not s.exported


def test_fixed_sessions_are_bounded_and_3d_inputs_keep_the_exported_one():
    """At most ``MAX_FIXED`` fixed sessions, the least recently used dropped first; a
    volume's input keeps the exported session (no block layout for 3-D convolutions)."""
    f = LearnedFeatures(_model("inplane"))
    s = f.sessions
    shapes = [(32 + 4 * k, 40) for k in range(MAX_FIXED + 1)]
    for shape in shapes:
        s.session_for(shape)
    assert s.session_for(shapes[0], build=False) is s.exported  # dropped
    assert all(s.session_for(sh, build=False) is not s.exported for sh in shapes[1:])
    v = LearnedFeatures(_model("volume"))
    x = _input((16, 16, 16))
    v.sessions.run(x)
    v.sessions.run(x)
    assert v.sessions.session_for((16, 16, 16)) is v.sessions.exported


def test_unnamed_spatial_axes_keep_the_exported_session(tmp_path):
    """A free dimension is fixed by its name: a model whose spatial axes share one name, or
    have none, runs on the exported session (the same maps)."""
    onnx = pytest.importorskip("onnx")
    m = onnx.load(str(_model("inplane")))
    dims = m.graph.input[0].type.tensor_type.shape.dim
    dims[2].dim_param = dims[3].dim_param = "side"
    path = tmp_path / "one_name.onnx"
    onnx.save(m, str(path))
    f = LearnedFeatures(path)
    x = _input((64, 64))
    a, b = f.sessions.run(x), f.sessions.run(x)
    assert f.sessions.session_for((64, 64)) is f.sessions.exported
    np.testing.assert_array_equal(a, b)


def test_a_session_that_cannot_be_built_falls_back(tmp_path):
    """When the fixed session cannot be built (the file gone since the model was loaded),
    the exported session runs the size."""
    src = _model("inplane")
    path = tmp_path / "gone.onnx"
    path.write_bytes(src.read_bytes())
    s = ModelSessions(path, LearnedFeatures(path).session, threads=1)
    path.unlink()
    assert s.session_for((64, 64)) is s.exported
