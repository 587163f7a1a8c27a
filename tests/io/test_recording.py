"""load_recording and save_plus_sequence: exact round trips of frames, geometry, poses and
labels; the needle transform's axes."""

import dataclasses

import numpy as np
import pytest

import synth
from needlenet.io import (
    RecordingError,
    load_recording,
    needle_tip_matrix,
    read_plus,
    save_plus_sequence,
)
from needlenet.trackers import NeedleEstimate, Status


@pytest.fixture(scope="module")
def inplane():
    return synth.generate("inplane", seed=21, frames=5, width_mm=16.0, depth_mm=20.0,
                          angle_deg=35.0, start_length_mm=12.0, background="homogeneous")


def _pose(i):
    R = synth.rotation_matrix((0.3, 1.0, 0.2), 0.2 + 0.05 * i)
    return synth.rigid_transform(R, [10.0 + i, -4.0, 2.5 * i])


@pytest.mark.parametrize("name", ["s.seq.mha", "s.mhd"])
def test_inplane_round_trip_keeps_everything(tmp_path, inplane, name):
    seq = dataclasses.replace(  # a moving probe
        inplane, probe_pose=np.stack([_pose(i) for i in range(inplane.n_frames)]))
    save_plus_sequence(seq, tmp_path / name)
    back = load_recording(tmp_path / name)
    np.testing.assert_array_equal(back.images, seq.images)
    np.testing.assert_array_equal(back.spacing_mm, seq.spacing_mm)
    np.testing.assert_array_equal(back.origin_mm, seq.origin_mm)
    np.testing.assert_array_equal(back.timestamps_s, seq.timestamps_s)
    np.testing.assert_array_equal(back.probe_pose, seq.probe_pose)
    assert back.modality == "inplane" and back.dynamic_range_db == seq.dynamic_range_db
    assert back.meta["params"] == seq.meta["params"]
    np.testing.assert_allclose(back.tip_mm, seq.tip_mm, atol=1e-10)
    np.testing.assert_allclose(back.direction, seq.direction, atol=1e-10)
    np.testing.assert_allclose(back.entry_mm, seq.entry_mm, atol=1e-10)
    np.testing.assert_array_equal(back.visible, seq.visible)


def test_volume_labels_through_a_rotated_probe(tmp_path):
    rng = np.random.default_rng(3)
    T = 3
    tip = rng.normal(size=(T, 3)) + [0, 0, 10]
    d = rng.normal(size=(T, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    seq = synth.Sequence(
        images=rng.integers(0, 256, (T, 7, 5, 9), dtype=np.uint8),
        spacing_mm=np.array([0.4, 0.6, 0.3]), origin_mm=np.array([0.5, -1.5, -1.2]),
        modality="volume", timestamps_s=np.array([0.0, 0.5, 1.25]), dynamic_range_db=55.0,
        probe_pose=np.stack([_pose(i) for i in range(T)]), tip_mm=tip, direction=d,
        entry_mm=tip - 20 * d, visible=np.array([True, False, True]))
    synth.validate_sequence(seq)
    save_plus_sequence(seq, tmp_path / "v.seq.mha", compress=False)
    p = read_plus(tmp_path / "v.seq.mha")
    # in the file: the tip in the reference frame, +Z along the needle
    ref = seq.probe_pose[1] @ np.append(tip[1], 1.0)
    np.testing.assert_allclose(p.transforms["NeedleTipToReference"][1][:3, 3], ref[:3])
    np.testing.assert_allclose(p.transforms["NeedleTipToReference"][1][:3, 2],
                               seq.probe_pose[1][:3, :3] @ d[1])
    back = load_recording(tmp_path / "v.seq.mha")
    np.testing.assert_array_equal(back.images, seq.images)
    np.testing.assert_allclose(back.tip_mm, tip, atol=1e-10)
    np.testing.assert_allclose(back.direction, d, atol=1e-12)
    np.testing.assert_allclose(back.entry_mm, seq.entry_mm, atol=1e-10)
    np.testing.assert_array_equal(back.visible, seq.visible)
    assert back.dynamic_range_db == 55.0


def test_estimates_become_tip_transforms_with_status(tmp_path, inplane):
    seq = dataclasses.replace(inplane, probe_pose=None)
    st = [Status.SEARCHING, Status.TRACKING, Status.TRACKING, Status.LOST, Status.TRACKING]
    est = [NeedleEstimate(t=float(t), status=s,
                          tip_mm=None if s == Status.SEARCHING else np.array([1.0 + i, 5.0]),
                          direction=np.array([0.6, 0.8]))
           for i, (t, s) in enumerate(zip(seq.timestamps_s, st, strict=True))]
    save_plus_sequence(seq, tmp_path / "r.seq.mha", est)
    p = read_plus(tmp_path / "r.seq.mha")
    m = p.transforms["NeedleTipToReference"]
    np.testing.assert_array_equal(p.transform_ok["NeedleTipToReference"], [0, 1, 1, 0, 1])
    np.testing.assert_array_equal(m[0], np.eye(4))  # INVALID: identity, as PLUS writes
    np.testing.assert_array_equal(m[3], np.eye(4))  # lost: the last tip is not reported
    np.testing.assert_allclose(m[2][:3, 3], [3.0, 0.0, 5.0])
    np.testing.assert_allclose(m[2][:3, 2], [0.6, 0.0, 0.8])
    assert p.frame_fields["NeedleTrackerStatus"] == [s.value for s in st]
    assert "ProbeToReference" not in p.transforms


@pytest.mark.parametrize("direction", [(0.6, 0.8), (-0.6, 0.8), (0.2, -0.3, 0.9),
                                       (0.0, 1.0, 0.0), (0.05, 0.99, 0.1)])
def test_needle_tip_matrix_is_a_rotation_with_z_along_the_needle(direction):
    d = np.asarray(direction, float)
    tip = np.arange(1.0, 1.0 + d.size)
    m = needle_tip_matrix(tip, d)
    R = m[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    u = d / np.linalg.norm(d)
    want = u if d.size == 3 else np.array([u[0], 0.0, u[1]])
    np.testing.assert_allclose(R[:, 2], want, atol=1e-12)
    np.testing.assert_allclose(m[:3, 3], tip if d.size == 3 else [tip[0], 0, tip[1]])
    if d.size == 2:  # a needle in the image plane: +Y is the probe's elevation axis
        np.testing.assert_allclose(R[:, 1], [0, 1, 0], atol=1e-12)
    np.testing.assert_array_equal(needle_tip_matrix(tip)[:3, :3], np.eye(3))


def test_missing_spacing_and_bad_arguments(tmp_path, inplane):
    save_plus_sequence(inplane, tmp_path / "a.mha", compress=False)
    data = (tmp_path / "a.mha").read_bytes()
    (tmp_path / "a.mha").write_bytes(data.replace(b"ElementSpacing = 0.1 0.1 1\n", b""))
    with pytest.raises(RecordingError, match=r"a\.mha: no pixel spacing \(ElementSpacing\); "
                                             r"pass spacing_mm \(--spacing MM or"):
        load_recording(tmp_path / "a.mha")
    seq = load_recording(tmp_path / "a.mha", spacing_mm=[0.2, 0.1])
    np.testing.assert_allclose(seq.spacing_mm, [0.2, 0.1])
    with pytest.raises(RecordingError, match="holds 2D frames; modality 'volume'"):
        load_recording(tmp_path / "a.mha", spacing_mm=0.1, modality="volume")
    with pytest.raises(RecordingError, match="spacing_mm"):
        load_recording(tmp_path / "a.mha", spacing_mm=[0.1, -0.1])
    with pytest.raises(RecordingError, match="modality must be one of"):
        load_recording(tmp_path / "a.mha", modality="sideways")
