"""Learned maps of the ROI/VOI only: once roi-rk and chatelain track, their source is asked for
the maps of the cylinder they read (Zhao eq. (1), Chatelain's VOI); detection and
initialisation read the whole volume's. Tracking on the region's maps stays within RANSAC's
spread of tracking on the whole volume's, on seeded volumes with the shipped model."""

import numpy as np
import pytest

import synth
from needlenet.features import FeatureSource, Frame, LearnedFeatures, ModelError, shipped_model_path
from needlenet.trackers._base import Status
from needlenet.trackers.volume import VolumeTracker

SIZE = 64  # the model's grid is the same at any size (its 0.5 mm over the same 50 mm)


class _Recording(FeatureSource):
    """A source's maps, recording for each call the frame and the region asked for (None:
    the whole volume). ``whole_only``: the whole volume's maps whatever is asked."""

    kind = "learned"

    def __init__(self, source: FeatureSource, whole_only: bool = False):
        self.source, self.whole_only, self.name = source, whole_only, source.name
        self.calls: list[tuple[int, int | None]] = []

    def likelihood(self, frame, roi=None):
        self.calls.append((frame.index, None if roi is None else int(np.size(roi))))
        return self.source.likelihood(frame, None if self.whole_only else roi)


@pytest.fixture(scope="module")
def model():
    try:
        return LearnedFeatures(shipped_model_path("volume"))
    except ModelError:
        pytest.skip("no shipped volume model in this checkout")


@pytest.fixture(scope="module")
def seq():
    return synth.generate("volume", seed=21, frames=8, alpha_deg=30, cr=3.0, output_size=SIZE)


@pytest.fixture(scope="module")
def needle_free():
    """The tissue of ``seq`` without the needle (a needle of 0.1 micrometre)."""
    return synth.generate("volume", seed=21, frames=2, alpha_deg=30, cr=3.0, output_size=SIZE,
                          start_length_mm=0.0, stop_length_mm=0.001, speed_mm_s=0.0001)


def _frames(seq, indices, t0):
    grid = seq.grid()
    return [Frame(image=seq.images[i], grid=grid, t=t0 + k, index=t0 + k)
            for k, i in enumerate(indices)]


@pytest.mark.parametrize("method", ["roi-rk", "chatelain"])
def test_tracking_on_the_region_stays_with_the_whole_volume(model, seq, method):
    """The same seeded run with the maps of the region and with the whole volume's: the
    same statuses, tips a few tenths of a millimetre apart (RANSAC draws from candidates
    whose likelihoods differ by the context a box leaves out), both on the needle."""
    runs = {}
    for whole_only in (False, True):
        source = _Recording(model, whole_only)
        runs[whole_only] = (VolumeTracker(method, features=source, rng=0).run(seq), source)
    (region, rec), (whole, _) = runs[False], runs[True]
    first = 1 if method == "roi-rk" else 2  # roi-rk initialises, chatelain detects a change
    assert [c for c in rec.calls[:first]] == [(i, None) for i in range(first)]
    assert all(size is not None and 0 < size < np.prod(seq.images.shape[1:])
               for _, size in rec.calls[first:])
    assert [e.status for e in region] == [e.status for e in whole]
    both = [(a.tip_mm, b.tip_mm, t) for a, b, t in zip(region, whole, seq.tip_mm, strict=True)
            if a.tip_mm is not None and b.tip_mm is not None]
    assert len(both) >= len(seq.tip_mm) - 1
    apart = [np.linalg.norm(a - b) for a, b, _ in both]
    assert np.median(apart) < 0.5
    for k in (0, 1):
        assert np.median([np.linalg.norm(x[k] - x[2]) for x in both]) < 1.0


def test_ransac_reads_the_whole_volume(model, seq):
    source = _Recording(model)
    VolumeTracker("ransac", features=source, rng=0).run(seq)
    assert all(size is None for _, size in source.calls)


def test_chatelain_compares_whole_maps_after_losing_the_needle(model, seq, needle_free):
    """Needle-free volumes longer than max_coast_volumes drop the Kalman state; the next
    insertion detection needs the previous volume's whole map, which tracking computed on
    its VOI only: it is computed again, and the needle reappearing is detected as with
    whole maps throughout."""
    frames = (_frames(seq, [0, 1, 2], 0) + _frames(needle_free, [0, 1, 0, 1], 3)
              + _frames(seq, [3, 4, 5], 7))
    statuses = {}
    for whole_only in (False, True):
        source = _Recording(model, whole_only)
        tracker = VolumeTracker("chatelain", features=source, rng=0)
        statuses[whole_only] = [tracker.update(f).status for f in frames]
        if not whole_only:
            calls = source.calls
    assert statuses[False] == statuses[True]
    assert statuses[False][2] == Status.TRACKING and statuses[False][-1] == Status.TRACKING
    # the volume after the Kalman state was dropped: its whole map, and the previous
    # volume's again (tracking had computed its VOI's only)
    lost = statuses[False].index(Status.LOST)
    drop = lost + 3  # the coasts of max_coast_volumes = 2, then the state is dropped
    assert (drop - 1, None) in calls and (drop, None) in calls
