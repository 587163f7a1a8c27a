"""The `line` tracker's reported covariance on a frame whose tip measurement the filter's gate
refused: the prediction is reported, and its covariance covers the measured tip too (the image
put the tip there; one of the two is wrong and the frame cannot tell which).

PyMUST validation sequence `val_lin_right_side_10_faint` (a needle advancing 1.4 mm per frame):
the filter, started on a first tip 5.9 mm past the needle's, refuses correct measurements on
three of its first five frames."""

from pathlib import Path

import numpy as np
import pytest

import synth

SEQ = (Path(__file__).resolve().parents[2] / "needlenet" / "data" / "validation"
       / "val_lin_right_side_10_faint.npz")


def test_a_refused_measurement_lies_inside_the_reported_covariance():
    pytest.importorskip("onnxruntime")
    from needlenet.trackers import make_tracker

    seq = synth.load_sequence(SEQ)
    est = make_tracker("inplane", "line", "learned", seed=0).run(seq)
    refused = [e for e in est if e.details is not None and e.details.measurement_accepted is
               False and not e.details.restarted]
    assert len(refused) >= 2
    for e in refused:
        y = np.asarray(e.details.tip_measurement_mm) - np.asarray(e.tip_mm)
        assert np.linalg.norm(y) > 1.0  # refused: well outside the filter's gate
        C = np.asarray(e.covariance)
        assert np.all(np.linalg.eigvalsh(C) > 0)
        assert float(y @ np.linalg.solve(C, y)) < 1.0  # within one standard deviation
    accepted = [e for e in est if e.details is not None and e.details.measurement_accepted]
    # an accepted measurement: the filter's own covariance, a fraction of a millimetre
    assert accepted and all(np.sqrt(np.trace(e.covariance)) < 1.0 for e in accepted)
