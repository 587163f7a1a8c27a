"""The Python entry points a user's own acquisition loop needs: ``needlenet.make_tracker``
with the defaults ``needlenet track`` runs, frames built from arrays with
``needlenet.Frame.from_image``, and a light ``import needlenet``."""

import subprocess
import sys

import numpy as np
import pytest

import needlenet
import synth
from needlenet.trackers import DEFAULT_FEATURES, DEFAULT_METHODS


@pytest.mark.parametrize("name", ["inplane", "volume", "axial"])
def test_make_tracker_defaults_are_those_track_runs(name):
    tr = needlenet.make_tracker(name)
    assert tr.method == DEFAULT_METHODS[name]
    assert tr.features.kind == DEFAULT_FEATURES[name]
    assert needlenet.make_tracker(name, features="classical").features.kind == "classical"


def test_make_tracker_names_what_is_unknown():
    with pytest.raises(ValueError, match="unknown tracker 'sagittal'; choose one of inplane"):
        needlenet.make_tracker("sagittal")
    with pytest.raises(ValueError, match="tracker 'inplane' has no method 'rk'"):
        needlenet.make_tracker("inplane", "rk")


def test_frames_from_arrays_track_as_the_sequence_does():
    """A loop over arrays (the frames a scanner's SDK hands over) gives the estimates
    ``tracker.run`` gives on the same sequence."""
    seq = synth.generate("inplane", seed=21, frames=6)
    want = needlenet.make_tracker("inplane", seed=0).run(seq)
    tr = needlenet.make_tracker("inplane", seed=0)
    got = [tr.update(needlenet.Frame.from_image(np.asarray(im), seq.spacing_mm, t=t, index=i,
                                                origin_mm=seq.origin_mm))
           for i, (im, t) in enumerate(zip(seq.images, seq.timestamps_s, strict=True))]
    assert [e.status for e in got] == [e.status for e in want]
    assert any(e.status is needlenet.Status.TRACKING for e in got)
    for a, b in zip(got, want, strict=True):
        if b.tip_mm is not None:
            np.testing.assert_array_equal(a.tip_mm, b.tip_mm)
            np.testing.assert_array_equal(a.covariance, b.covariance)


@pytest.mark.parametrize("image,spacing,kw,msg", [
    (np.zeros((4, 5, 6, 3)), 0.1, {}, r"2D \(H, W\) or 3D"),
    (np.zeros((40, 50), object), 0.1, {}, "must hold numbers"),
    (np.zeros((40, 50)), 0.0, {}, "spacing_mm must be one positive number or 2"),
    (np.zeros((40, 50)), (0.1, 0.1, 0.1), {}, "spacing_mm must be one positive number or 2"),
    (np.zeros((40, 50)), float("nan"), {}, "spacing_mm"),
    (np.zeros((40, 50)), 0.1, {"origin_mm": (0.0,)}, "origin_mm must be 2 finite numbers"),
    (np.zeros((40, 50)), 0.1, {"t": float("inf")}, "t must be a finite time"),
    (np.zeros((40, 50)), 0.1, {"probe_pose": np.eye(3)}, "probe_pose must be a 4 x 4"),
])
def test_frame_from_image_names_what_does_not_fit(image, spacing, kw, msg):
    with pytest.raises(ValueError, match=msg):
        needlenet.Frame.from_image(image, spacing, **kw)


def test_a_volume_frame_takes_one_spacing_per_axis():
    f = needlenet.Frame.from_image(np.zeros((8, 9, 10), np.uint8), (0.3, 0.2, 0.1))
    assert f.grid.shape == (8, 9, 10) and f.grid.spacing_mm == (0.3, 0.2, 0.1)
    assert f.grid.origin_mm == (0.0, 0.0, 0.0)


def test_import_needlenet_loads_no_tracker_until_asked():
    code = ("import sys, needlenet; print('cv2' in sys.modules, 'onnxruntime' in sys.modules); "
            "needlenet.make_tracker; print('cv2' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["False", "False", "True"]
    with pytest.raises(AttributeError, match="no attribute 'tracker'"):
        needlenet.tracker  # noqa: B018
