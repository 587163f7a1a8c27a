"""Tests for the region maps of Carriere's axial tracker (needlenet/trackers/_axial_maps.py):
while tracking, a learned source runs on the box the step reads, and the tracked centres are
those of whole-slice inference; detection and re-detection read the whole slice."""

import numpy as np
import pytest

import synth
from needlenet.features import FeatureSource, Likelihood, learned_features
from needlenet.trackers._axial import AxialParams, AxialTracker
from needlenet.trackers._axial_maps import region_box, roi_reach_px, slice_maps
from needlenet.trackers._base import Status, frames_from_sequence


class _Recording(FeatureSource):
    """A feature source that passes every call on and records the ROI it was given."""

    def __init__(self, inner):
        self.inner = inner
        self.kind, self.name = inner.kind, inner.name
        self.rois = []

    def __getattr__(self, name):  # margin_mm, multiple, target_reference, ...
        return getattr(self.inner, name)

    def likelihood(self, frame, roi=None):
        self.rois.append(roi)
        return self.inner.likelihood(frame, roi)


def _track(seq_or_frames, learned_roi, source):
    params = AxialParams(rotation_depth_mm=40.0, learned_roi=learned_roi)
    tracker = AxialTracker(features=source, params=params, rng=0)
    frames = seq_or_frames if isinstance(seq_or_frames, list) else \
        list(frames_from_sequence(seq_or_frames))
    return [tracker.update(f) for f in frames]


def _assert_same_track(a, b, tol_mm=0.1):
    assert [e.status for e in a] == [e.status for e in b]
    for x, y in zip(a, b, strict=True):
        assert (x.tip_mm is None) == (y.tip_mm is None)
        if x.tip_mm is not None:
            assert np.linalg.norm(x.tip_mm - y.tip_mm) < tol_mm


@pytest.fixture(scope="module")
def shipped():
    return learned_features("axial")


def test_region_inference_tracks_like_whole_slice_inference(shipped):
    """128 x 128 slices at 0.3 mm, inhomogeneous background (the latency benchmark's):
    the network runs on the ROI's box once the needle is tracked, and every tracked centre
    lies within 0.1 mm of whole-slice inference's."""
    seq = synth.generate("axial", seed=2024, insertion_mm=30.0, background="inhomogeneous")
    source = _Recording(shipped)
    region = _track(seq, True, source)
    whole = _track(seq, False, shipped)
    assert all(e.status == Status.TRACKING for e in whole)
    _assert_same_track(region, whole)
    assert source.rois[0] is None  # the detection ran on the whole slice
    boxes = [r for r in source.rois[1:] if r is not None]
    assert len(boxes) == seq.n_frames - 1
    area = [(r[0].stop - r[0].start) * (r[1].stop - r[1].start) for r in boxes]
    assert max(area) < 0.15 * seq.images[0].size  # a box of ~37 x 37 px, not the slice


def test_lost_while_tracking_detects_again_on_the_whole_slice(shipped):
    """Slices 3 mm ahead of the tip (no cross-section) in frames 20-27: the region's match no
    longer stands out, the tracker reports lost, and the detector runs on the whole slice in
    that same frame and in the following ones; the same statuses and centres as whole-slice
    inference throughout."""
    kw = dict(width_mm=19.2, depth_mm=19.2, needle_depth_mm=10.0, background="homogeneous",
              frames=40, cr=2.5)
    seq = synth.generate("axial", seed=3, **kw)
    ahead = synth.generate("axial", seed=3, plane_lag_mm=-3.0, **kw)
    frames = list(frames_from_sequence(seq))
    frames[20:28] = list(frames_from_sequence(ahead))[20:28]
    source = _Recording(shipped)
    region = _track(frames, True, source)
    whole = _track(frames, False, shipped)
    _assert_same_track(region, whole)
    status = [e.status for e in region]
    assert status[20] == Status.LOST and status[28:] == [Status.TRACKING] * 12
    # frame 20: the box, then the whole slice for the detector
    k = 20 + sum(1 for e in region[:20] if e.status != Status.TRACKING)
    assert source.rois[k] is not None and source.rois[k + 1] is None


class _Pointwise(FeatureSource):
    """A learned-like source whose map at a pixel depends on that pixel alone, so that a box
    run differs from the whole slice's run nowhere; 0 outside an ROI, no context."""

    kind = "learned"
    name = "pointwise"
    margin_mm = 0.0
    multiple = 4

    def likelihood(self, frame, roi=None):
        im = np.asarray(frame.image, np.float32) / 255.0
        if roi is None:
            return Likelihood(shaft=im, source=self.name)
        out = np.zeros_like(im)
        out[roi] = im[roi]
        return Likelihood(shaft=out, source=self.name)


@pytest.mark.parametrize("centre", [(64.0, 64.0), (20.3, 70.6), (3.0, 125.0)])
def test_box_holds_every_sample_the_step_reads(centre):
    """The smoothed map wherever a match can lie (the ROI +- size - size // 2 + 1) and the
    template image wherever the drift window and the template reach: the same on the box
    as on the whole slice (a box with no context)."""
    rng = np.random.default_rng(5)
    seq = synth.generate("axial", seed=4, frames=2)
    frame = next(iter(frames_from_sequence(seq)))
    frame.image = rng.integers(0, 256, frame.image.shape).astype(np.uint8)
    size, drift, sigma = (11, 11), np.array([2, 2]), 0.635 / 0.3
    half = roi_reach_px(size, drift, sigma, np.array([3, 3]))
    box = region_box(frame.image.shape, centre, half, (0, 0), 4)
    src = _Pointwise()
    whole = slice_maps(src, frame, sigma, 1e-3, "variance")
    part = slice_maps(src, frame, sigma, 1e-3, "variance", box)
    c = np.rint(centre).astype(int)
    shape = np.array(frame.image.shape)

    def window(r):
        lo, hi = np.maximum(c - r, 0), np.minimum(c + r + 1, shape)
        return tuple(slice(a, b) for a, b in zip(lo, hi, strict=True))

    match = np.array(size) - np.array(size) // 2 + 1
    np.testing.assert_allclose(part.S[window(match + 1)], whole.S[window(match + 1)],
                               rtol=0, atol=1e-6)
    reach = match + np.array(size) // 2 + drift + 1
    np.testing.assert_array_equal(part.M[window(reach)], whole.M[window(reach)])


def test_region_box_lines_up_with_the_network_grid():
    for centre in [(64, 64), (30.4, 99.7), (5, 5), (127, 0)]:
        for context in [(0, 0), (20, 20), (7, 13)]:
            box = region_box((128, 128), centre, (18, 17), context, 4)
            c = np.rint(centre).astype(int)
            for s, ci, h, k in zip(box, c, (18, 17), context, strict=True):
                assert s.start <= max(ci - h, 0) and s.stop == min(ci + h + 1, 128)
                assert s.start - k <= 0 or (s.start - k) % 4 == 0
