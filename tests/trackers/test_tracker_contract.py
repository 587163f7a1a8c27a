"""One constructor contract for every tracker (issue 23): ``rng`` or ``seed`` through the base
class, the same estimates for the same seed, and both at once refused."""

import numpy as np
import pytest

import synth
from needlenet.trackers import make_tracker
from needlenet.trackers._registry import tracker_class, tracker_methods

CASES = [("inplane", "line"), ("inplane", "pf+f"), ("axial", "carriere"),
         ("volume", "roi-rk"), ("volume", "chatelain")]


@pytest.fixture(scope="module")
def sequences():
    return {"inplane": synth.generate("inplane", seed=5, frames=6, width_mm=20.0,
                                      depth_mm=25.0, start_length_mm=15.0),
            "axial": synth.generate("axial", seed=5, frames=6),
            "volume": synth.generate("volume", seed=5, frames=4, output_size=48, cr=3.0)}


def _tips(estimates):
    return [None if e.tip_mm is None else np.asarray(e.tip_mm).tolist() for e in estimates]


@pytest.mark.parametrize("name, method", CASES)
def test_seed_and_rng_repeat_a_run_for_every_tracker(sequences, name, method):
    seq = sequences[name]
    a = make_tracker(name, method, "classical", seed=7).run(seq)
    b = make_tracker(name, method, "classical", rng=7).run(seq)
    c = make_tracker(name, method, "classical", rng=np.random.default_rng(7)).run(seq)
    assert _tips(a) == _tips(b) == _tips(c)
    tr = make_tracker(name, method, "classical", seed=7)
    assert isinstance(tr.rng, np.random.Generator)


@pytest.mark.parametrize("name", ["inplane", "axial", "volume"])
def test_rng_and_seed_together_are_refused(name):
    method = tracker_methods(name)[0]
    with pytest.raises(ValueError, match="give rng or seed, not both"):
        tracker_class(name, method)(method, rng=1, seed=1)
