"""End-to-end tests of Mathiassen 2017's in-plane trackers (needlenet/trackers/_inplane.py) on
seeded synth sequences."""

import dataclasses

import numpy as np
import pytest

import synth
from needlenet.features import FeatureSource, Frame, Likelihood
from needlenet.trackers._base import Status
from needlenet.trackers._inplane import InplaneParams, InplaneTracker

# High contrast on a homogeneous background, 20 frames at 0.1 mm; 25 mm deep keeps it fast.
# (synth's in-plane contrast ratio tops out near 1.8 at the default tissue gray level of 70:
# synth refuses a larger ``cr``.)
SCENE = dict(frames=20, speed_mm_s=10.0, background="homogeneous", cr=1.5, depth_mm=25.0)


@pytest.fixture(scope="module")
def sequences():
    return {35: synth.generate("inplane", seed=21, angle_deg=35.0, **SCENE),
            45: synth.generate("inplane", seed=22, angle_deg=45.0, **SCENE)}


def _errors(estimates, seq):
    return np.array([np.linalg.norm(e.tip_mm - t) if e.status == Status.TRACKING else np.inf
                     for e, t in zip(estimates, seq.tip_mm, strict=True)])


@pytest.mark.parametrize("method", InplaneTracker.methods)
def test_every_method_tracks_with_a_consistent_estimate(sequences, method):
    for angle, seq in sequences.items():
        estimates = InplaneTracker(method, expected_angle_deg=angle, rng=1).run(seq)
        assert len(estimates) == seq.n_frames
        err = _errors(estimates, seq)
        assert np.median(err) < 1.5  # DF included
        for e in estimates:
            if e.status != Status.TRACKING:
                continue
            assert e.tip_mm.shape == (2,)
            assert np.linalg.norm(e.direction) == pytest.approx(1.0)
            assert e.covariance.shape == (2, 2)
            np.testing.assert_allclose(e.covariance, e.covariance.T, atol=1e-12)
            assert np.all(np.linalg.eigvalsh(e.covariance) > 0)
            assert e.axis_point_mm.shape == (2,) and e.details.theta_deg is not None
        theta = np.degrees(np.arctan2(estimates[-1].direction[1], -estimates[-1].direction[0]))
        # DF, the Hough baseline, is the least precise (Mathiassen Table III: -2.7 +- 3.6 deg)
        assert theta == pytest.approx(angle, abs=2.5 if method == "df" else 1.0)


@pytest.mark.parametrize("method", ["om", "kf", "kf+f", "pf", "kfv"])
def test_median_tip_error_below_one_millimetre(sequences, method):
    for angle, seq in sequences.items():
        estimates = InplaneTracker(method, expected_angle_deg=angle, rng=0).run(seq)
        err = _errors(estimates, seq)
        # frame 0 finds the needle; it is reported from frame 1, where it is seen again
        assert estimates[0].status == Status.SEARCHING and estimates[0].tip_mm is None
        assert "next frame" in estimates[0].reason and estimates[1].details.detected
        assert np.all(np.isfinite(err[1:])), f"{method} at {angle} deg lost the needle"
        assert np.median(err[1:]) < 1.0, \
            f"{method} at {angle} deg: median {np.median(err[1:]):.2f} mm"


def test_feedback_velocity_filter_reaches_the_paper_precision(sequences):
    # KF_v+F, the paper's best method: sub-millimetre at the 95th percentile here
    for angle, seq in sequences.items():
        err = _errors(InplaneTracker("kfv+f", expected_angle_deg=angle).run(seq), seq)
        assert np.percentile(err[1:], 95) < 0.5  # frame 0: the detection, not reported


def test_robot_velocity_is_used_in_px_per_second(sequences):
    estimates = InplaneTracker("kfv", expected_angle_deg=35.0).run(sequences[35])
    # 10 mm/s measured with R_v = (1 px/frame)^2: the filter's velocity follows it
    assert estimates[-1].details.tip_velocity_mm_s == pytest.approx(10.0, abs=0.3)


def test_expected_angle_can_be_found_by_the_tracker(sequences):
    seq = sequences[45]
    estimates = InplaneTracker("kf+f").run(seq)  # detection over 20-70 degrees
    err = _errors(estimates, seq)
    assert np.isfinite(err[-5:]).all() and np.median(err[np.isfinite(err)]) < 1.0
    assert estimates[-1].details.theta_deg == pytest.approx(45.0, abs=1.0)


def test_particle_filters_are_reproducible(sequences):
    seq = sequences[35]
    a = InplaneTracker("pf+f", expected_angle_deg=35.0, seed=5).run(seq)
    b = InplaneTracker("pf+f", expected_angle_deg=35.0, rng=5).run(seq)
    np.testing.assert_array_equal(np.array([e.tip_mm for e in a[1:]]),
                                  [e.tip_mm for e in b[1:]])


@pytest.fixture(scope="module")
def comeback():
    """A needle sequence and the same scene (seed, tissue) before the needle entered."""
    needle = synth.generate("inplane", seed=7, angle_deg=35.0, **SCENE)
    empty = synth.generate("inplane", seed=7, angle_deg=35.0,
                           **{**SCENE, "frames": 3, "start_length_mm": 0.5})
    return needle, empty


@pytest.mark.parametrize("method", ["kf+f", "om", "pf", "df"])
def test_lost_when_the_needle_leaves_and_found_when_it_returns(comeback, method):
    needle, empty = comeback
    assert not empty.visible.any()
    grid = needle.grid()
    order = ([(needle, i) for i in range(10)] + [(empty, i) for i in range(3)] * 2
             + [(needle, i) for i in range(10, 20)])
    tracker = InplaneTracker(method, expected_angle_deg=35.0, rng=0)
    out = [tracker.update(Frame(seq.images[i], grid, t=0.05 * k, index=k,
                                insertion_speed_mm_s=10.0))
           for k, (seq, i) in enumerate(order)]
    status = [e.status for e in out]
    assert status[0] == Status.SEARCHING  # found; reported once seen on the next frame
    assert all(s == Status.TRACKING for s in status[1:10])
    lost_after = InplaneParams().lost_after_frames
    assert all(s == Status.LOST for s in status[10 + lost_after - 1:16])
    assert all(e.tip_mm is None for e in out[10 + lost_after - 1:16])
    # the track was forgotten in the gap: found again on the needle's first frame back,
    # reported from the next
    assert status[16] == Status.LOST and out[16].tip_mm is None
    assert all(s == Status.TRACKING for s in status[17:])
    err = [np.linalg.norm(e.tip_mm - needle.tip_mm[i])
           for e, (_, i) in zip(out[-5:], order[-5:], strict=True)]
    assert max(err) < 1.0


def test_constant_and_nan_frames_never_raise(sequences):
    seq = sequences[35]
    grid = seq.grid()
    tracker = InplaneTracker("kf+f", expected_angle_deg=35.0)
    assert tracker.update(Frame(np.zeros(grid.shape, np.uint8), grid)).status == \
        Status.SEARCHING
    nan = np.full(grid.shape, np.nan, np.float32)
    assert tracker.update(Frame(nan, grid, t=0.05)).status == Status.SEARCHING
    for i in range(5):  # found on the first needle frame, reported from the second
        assert tracker.update(Frame(seq.images[i], grid, t=0.1 + 0.05 * i)).status == \
            (Status.SEARCHING if i == 0 else Status.TRACKING)
    est = tracker.update(Frame(np.full(grid.shape, 7, np.uint8), grid, t=0.4))
    assert est.status == Status.LOST and "constant" in est.reason
    est = tracker.update(Frame(nan, grid, t=0.45))
    assert est.status == Status.LOST and "NaN" in est.reason
    assert tracker.update(Frame(seq.images[6], grid, t=0.5)).status == Status.TRACKING


class _TipMapSource(FeatureSource):
    """A stand-in for a learned source: the image as the shaft map and a Gaussian tip map at
    the true tip of the sequence's frame."""

    kind = "learned"
    name = "tip-map-stub"

    def __init__(self, seq):
        self.seq = seq

    def likelihood(self, frame, roi=None):
        grid = frame.grid
        zz, xx = np.meshgrid(*(grid.axis_coords(a) for a in range(2)), indexing="ij")
        d = self.seq.direction[frame.index]
        # on the upper-wall echo, which is what the shaft map (the image) shows
        tx, tz = self.seq.tip_mm[frame.index] - 1.1 * np.array([d[1], -d[0]])
        tip = np.exp(-0.5 * ((xx - tx) ** 2 + (zz - tz) ** 2) / 0.3**2).astype(np.float32)
        return Likelihood(shaft=frame.image.astype(np.float32) / 255.0, tip=tip,
                          source=self.name)


def test_a_tip_map_replaces_the_five_features(sequences):
    seq = sequences[45]
    # the stand-in's shaft map is the image, not a probability: no probability level applies
    estimates = InplaneTracker("om", _TipMapSource(seq), expected_angle_deg=45.0,
                               weights="/nonexistent.json",
                               params=InplaneParams(learned_level=0.0)).run(seq)
    along = [e.details.tip_along_mm for e in estimates[1:]]  # frame 0 finds the needle
    truth = [(t - e.axis_point_mm) @ e.direction for e, t in
             zip(estimates[1:], seq.tip_mm[1:], strict=True)]
    np.testing.assert_allclose(along, truth, atol=0.6)  # the map's peak, not the features'


def test_frames_without_the_needle_are_lost_without_a_tip(sequences):
    from needlenet.features import learned_features

    seq = sequences[35]
    images = seq.images.copy()
    free = synth.generate("inplane", seed=21, angle_deg=35.0, elevation_offset_mm=12.0,
                          **SCENE).images  # the same world, the needle out of the plane
    images[8:13] = free[8:13]
    gap = dataclasses.replace(seq, images=images)
    for source in (None, learned_features("inplane")):
        est = InplaneTracker("kf+f", source, expected_angle_deg=35.0, rng=0).run(gap)
        assert all(e.status != Status.TRACKING and e.tip_mm is None for e in est[8:13])
        assert est[-1].status == Status.TRACKING


def test_construction_errors(tmp_path):
    with pytest.raises(ValueError, match="unknown method 'kalman'"):
        InplaneTracker("kalman")
    with pytest.raises(ValueError, match="expected_angle_deg"):
        InplaneTracker("om", expected_angle_deg=85.0)
    with pytest.raises(FileNotFoundError, match="mathiassen_fit"):
        InplaneTracker("om", weights=tmp_path / "missing.json")
    with pytest.raises(ValueError, match="keep_contrast"):
        InplaneParams(detect_contrast=1.0, keep_contrast=2.0)


@pytest.mark.parametrize("method", ["om", "kf+f", "pf+f", "df"])
def test_a_needle_from_the_left_is_tracked_on_mirrored_frames(sequences, method):
    from .test_inplane_line import _mirror

    seq = sequences[35]
    left = _mirror(seq)
    right_est = InplaneTracker(method, expected_angle_deg=35, rng=0).run(seq)
    left_est = InplaneTracker(method, expected_angle_deg=35, rng=0).run(left)
    err_r, err_l = _errors(right_est, seq), _errors(left_est, left)
    assert np.median(err_l) < 1.0
    # mirroring is exact: the same estimates, mirrored back into the frame's coordinates
    np.testing.assert_allclose(err_l, err_r, atol=1e-6)
    last = left_est[-1]
    assert last.details.mirrored and last.direction[0] > 0  # from the left, going right
    with pytest.raises(ValueError, match="entry_side"):
        InplaneParams(entry_side="top")
    fixed = InplaneTracker(method, expected_angle_deg=35, rng=0,
                           params=InplaneParams(entry_side="right")).run(left)
    assert np.mean(np.isfinite(_errors(fixed, left))) < 0.5  # the paper's corner misses it


@pytest.mark.parametrize("setting, message", [
    ("df.half_range_deg=1e9", "DFParams.half_range_deg must lie in"),
    ("angle.q_theta_deg2=-0", "q_theta_deg2 must be positive"),
    ("axis.sq_shift_mm=-1", "MathiassenParams.sq_shift_mm must lie in"),
    ("axis.ray_length_mm=1e9", "MathiassenParams.ray_length_mm must be at most")])
def test_settings_the_methods_cannot_run_are_refused_when_read(setting, message):
    """Issue 21's fuzz: these had failed at the first frame (a 15 GiB Hough accumulator, a
    Kalman filter's ValueError, np.pad's traceback)."""
    from needlenet.trackers._registry import tracker_params

    with pytest.raises(ValueError, match=message):
        tracker_params("inplane", [setting], "kf+f")


@pytest.mark.parametrize("method", ["kf+f", "om"])
def test_a_tissue_line_found_on_one_frame_only_is_not_reported(method):
    """Issue 21's protocol, shortened (world 13 at 5 mm/s, frames 25-44 without the needle):
    with no angle given, the full-range search finds a 19-degree tissue line through the ROI's
    corner on every fourth needle-free frame, and the tracking test on the next frame does not
    see it (6 and 5 needle-free frames were reported `tracking`, one per find, before a
    detection waited for that frame). The needle is reported again within 10 frames of its
    return."""
    seq = synth.generate("inplane", seed=13, frames=70, speed_mm_s=5.0)
    free = synth.generate("inplane", seed=13, frames=70, speed_mm_s=5.0, needle_free=True)
    images = seq.images.copy()
    images[25:45] = free.images[25:45]
    est = InplaneTracker(method, rng=0).run(dataclasses.replace(seq, images=images))
    assert not any(e.status == Status.TRACKING for e in est[25:45])
    err = _errors(est, seq)
    back = np.flatnonzero(err[45:] < 2.0)
    assert back.size and back[0] < 10


def test_df_does_not_take_a_tissue_line_beside_the_needle_that_left():
    """World 18 (default speed), frames 25-44 without the needle: DF's Hough search, within
    +-5 degrees of the tracked 45 degrees, finds a 6 mm tissue line entering the right edge
    7.5 mm below the needle's entry (17 of the 20 needle-free frames were `tracking` before
    the axis gate and the growth rule). The needle, back on its own axis, is taken again."""
    seq = synth.generate("inplane", seed=18, frames=60)
    free = synth.generate("inplane", seed=18, frames=60, needle_free=True)
    images = seq.images.copy()
    images[25:45] = free.images[25:45]
    est = InplaneTracker("df", rng=0).run(dataclasses.replace(seq, images=images))
    assert not any(e.status == Status.TRACKING for e in est[25:45])
    err = _errors(est, seq)
    back = np.flatnonzero(err[45:] < 2.0)
    assert back.size and back[0] < 10


def test_df_takes_a_line_off_the_departed_axis_only_once_it_grows():
    from needlenet.features._hough import DFResult

    tr = InplaneTracker("df")
    d = np.array([-np.sqrt(0.5), np.sqrt(0.5)])
    entry = np.array([19.0, 0.5])
    tr._df_departed = (entry, d)

    def line(start, length):
        return DFResult(True, theta_deg=45.0, direction=d, entry_mm=start,
                        tip_mm=start + length * d)

    beside = entry + np.array([0.0, 7.5])  # 5.3 mm off the departed axis
    assert not tr._df_taken(line(beside, 6.0))
    assert not tr._df_taken(line(beside, 6.4))  # a still line's end jitters
    assert tr._df_taken(line(beside, 7.2))  # grown by 1.2 mm where it was first seen
    assert tr._df_taken(line(entry + np.array([0.5, 0.5]), 6.0))  # on the departed axis


def test_a_detection_is_confirmed_by_the_needle_seen_as_the_tracking_test_sees_it():
    """`bench inplane`'s world 30000011 (45 degrees, 5 mm/s, the angle given): the needle
    found on frame 0 is found again on frame 1 with its tip 2.7 mm along the axis, short of
    the 3 mm a detection asks. Asking a detection's tests there dropped it, and a line found on
    frame 2 was tracked 10-12 mm off for the rest of the sequence (95th percentile 0.34 ->
    10.15 mm); the tracking test's are asked."""
    from needlenet.bench._trackers import SEED0

    seq = synth.generate("inplane", seed=SEED0 + 11, frames=20, angle_deg=45.0,
                         speed_mm_s=5.0, background="inhomogeneous")
    est = InplaneTracker("kf", expected_angle_deg=45.0, rng=11).run(seq)
    assert est[1].status == Status.TRACKING and est[1].details.detected
    err = _errors(est, seq)
    assert np.all(err[6:] < 1.0)
