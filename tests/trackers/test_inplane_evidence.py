"""Whether Mathiassen's in-plane tracker sees a needle (needlenet/trackers/_inplane_evidence.py):
the classical echo test on made-up profiles, and frames without a needle in a seeded synth
sequence with needle-like tissue lines."""

import dataclasses

import numpy as np
import pytest

import synth
from needlenet.features._mathiassen import TipFeatures
from needlenet.trackers._base import Status
from needlenet.trackers._inplane import InplaneParams, InplaneTracker
from needlenet.trackers._inplane_evidence import (
    classical_echo_seen,
    echo_sections,
    echo_shown,
    learned_level_reached,
)

N_SEC = 19  # 2s+1 samples of 0.1 mm, eq. (1)


def _features(line_gain, noise=1.0, n=500, seed=0):
    """Profiles along a 50 mm axis of tissue with Gaussian noise, the line echo raised by
    ``line_gain`` (an array of n values, or a number)."""
    rng = np.random.default_rng(seed)
    x = 0.1 * np.arange(n)
    line = rng.normal(0, noise, n) + line_gain
    background = rng.normal(0, noise / 3, n)
    null = rng.normal(0, noise, n) - rng.normal(0, noise / 3, n)  # the same rows on tissue
    return TipFeatures(x, None, line, background, np.full(n, noise), null)


def test_sections_are_in_units_of_the_tissue_noise():
    z = echo_sections(_features(0.0, noise=7.0), 0.0, 50.0, N_SEC)
    assert z.size == 500 // N_SEC
    assert 0.6 < np.std(z) < 1.5  # whatever the image's noise level
    assert classical_echo_seen(_features(0.0, noise=7.0), 0.0, 40.0, N_SEC, 2.0, 0.5)[1] \
        < 0.2


def test_an_echo_along_the_whole_axis_is_seen_and_a_partial_one_is_not():
    whole = _features(3.0)  # z about 3 sqrt(19) / sqrt(1 + 1/9) = 12 in every section
    seen, share = classical_echo_seen(whole, 0.0, 30.0, N_SEC, 2.0, 0.5)
    assert seen and share > 0.9
    # a tissue line on the far 60 % of the axis: most sections, but not of the entry half
    far = _features(np.where(np.arange(500) >= 120, 3.0, 0.0))
    seen, share = classical_echo_seen(far, 0.0, 30.0, N_SEC, 2.0, 0.5)
    assert not seen and 0.5 < share < 0.8
    # a short stretch at the entry: not half of the axis
    near = _features(np.where(np.arange(500) < 80, 3.0, 0.0))
    seen, share = classical_echo_seen(near, 0.0, 30.0, N_SEC, 2.0, 0.5)
    assert not seen and share < 0.5


def test_no_samples_or_no_null_is_not_seen():
    f = _features(3.0)
    assert classical_echo_seen(f, 60.0, 70.0, N_SEC, 2.0, 0.5) == (False, 0.0)
    learned = dataclasses.replace(f, null_difference=None)
    assert classical_echo_seen(learned, 0.0, 30.0, N_SEC, 2.0, 0.5) == (False, 0.0)
    probability = dataclasses.replace(f, line=np.full(500, 0.6))
    assert learned_level_reached(probability, 0.0, 30.0, 0.5)
    assert not learned_level_reached(probability, 0.0, 30.0, 0.7)


def test_sections_without_evidence_are_left_out():
    """NaN sections (the line echo's premise, tissue above, fails there) count neither way."""
    z = np.array([np.nan, np.nan, 3.0, 3.0, 0.0, 3.0])
    assert echo_shown(z, 2.0, 0.5) == (True, 0.75)  # entry half: its one counted section
    assert echo_shown(np.array([np.nan, 0.0, 3.0, 3.0]), 2.0, 0.5) == (False, 2 / 3)
    assert echo_shown(np.full(4, np.nan), 2.0, 0.5) == (False, 0.0)
    assert echo_shown(np.array([3.0, 0.0, 3.0, 3.0]), 2.0, 0.5) == (True, 0.75)


def test_settings_are_checked():
    for bad in (dict(echo_z=0.0), dict(echo_coverage=0.0), dict(echo_coverage=1.5)):
        with pytest.raises(ValueError, match="echo_"):
            InplaneParams(**bad)


GAP = (25, 45)  # frames replaced by needle-free frames of the same world


@pytest.fixture(scope="module")
def gap_sequence():
    """Seed 36's world (a needle at 35-45 degrees among needle-like tissue lines), 60 frames,
    the needle absent from frames 25-44."""
    seq = synth.generate("inplane", seed=36, frames=60)
    free = synth.generate("inplane", seed=36, frames=60, needle_free=True)
    images = seq.images.copy()
    images[GAP[0]:GAP[1]] = free.images[GAP[0]:GAP[1]]
    return seq, dataclasses.replace(seq, images=images)


@pytest.mark.parametrize("method", ["kf+f", "om+f", "pf+f"])
def test_classical_methods_report_no_needle_on_needle_free_frames(gap_sequence, method):
    # with the shaft contrast alone kf+f tracked 12 and pf+f 14 of the 20 needle-free frames
    # here, on a tissue line within the feedback ROI
    seq, gap = gap_sequence
    est = InplaneTracker(method, rng=0).run(gap)
    tracking = np.array([e.status == Status.TRACKING for e in est])
    err = np.array([np.linalg.norm(e.tip_mm - t) if e.tip_mm is not None else np.inf
                    for e, t in zip(est, seq.tip_mm, strict=True)])
    a, b = GAP
    assert tracking[a:b].sum() == 0
    assert all(e.tip_mm is None for e in est[a:b])
    assert (tracking & (err < 2.0))[:a].sum() >= a - 2  # measured: 25 of 25
    assert (tracking & (err < 2.0))[b:].sum() >= len(est) - b - 2  # re-acquired: 15 of 15
