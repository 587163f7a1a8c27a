"""needlenet synth/track on recordings of your own: PLUS files written by SimpleITK and by
needlenet track end to end; synth -> PLUS -> track -> PLUS keeps frames, spacing, transforms
and timestamps; bad input is one line and exit status 2; nothing is overwritten unasked."""

import json
import socket

import cv2
import numpy as np
import pytest

import synth
from needlenet.cli import main
from needlenet.io import read_plus

sitk = pytest.importorskip("SimpleITK")

ARGS = ["--frames", "12", "--param", "width_mm=25", "--param", "depth_mm=30", "--param",
        "start_length_mm=18", "--angle", "40", "--background", "homogeneous", "--seed", "12"]


@pytest.fixture(scope="module")
def seq():
    return synth.generate("inplane", seed=12, frames=12, width_mm=25.0, depth_mm=30.0,
                          angle_deg=40.0, start_length_mm=18.0, background="homogeneous")


@pytest.fixture(scope="module")
def sitk_file(seq, tmp_path_factory):
    """The sequence as SimpleITK writes a PLUS file: no labels, no needlenet fields."""
    img = sitk.GetImageFromArray(seq.images)
    dz, dx = seq.spacing_mm
    z0, x0 = seq.origin_mm
    img.SetSpacing((float(dx), float(dz), 1.0))
    img.SetOrigin((float(x0), float(z0), 0.0))
    for i, t in enumerate(seq.timestamps_s):
        img.SetMetaData(f"Seq_Frame{i:04d}_Timestamp", repr(float(t)))
        img.SetMetaData(f"Seq_Frame{i:04d}_ImageStatus", "OK")
    img.SetMetaData("UltrasoundImageOrientation", "MF")
    path = tmp_path_factory.mktemp("sitk") / "scan.seq.mha"
    sitk.WriteImage(img, str(path), useCompression=True)
    return path


def _tips(res):
    return [(i, np.array(f["tip_mm"])) for i, f in enumerate(res["frames"])
            if f["status"] == "tracking"]


def test_simpleitk_plus_file_tracks_end_to_end(seq, sitk_file, tmp_path, capsys):
    out = tmp_path / "r.json"
    rc = main(["track", str(sitk_file), "--tracker", "inplane", "--method", "kf+f",
               "--json", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    res = json.loads(out.read_text())
    assert len(res["frames"]) == 12 and "norm_e_mm" not in res["summary"]  # no labels
    tips = _tips(res)
    assert len(tips) >= 8
    # the geometry came through: the tracked tips are where synth put the needle
    err = [np.linalg.norm(t - seq.tip_mm[i]) for i, t in tips]
    assert np.median(err) < 1.0


def test_synth_plus_track_plus_round_trip(tmp_path, capsys):
    src, res_plus, res_json = tmp_path / "s.seq.mha", tmp_path / "r.seq.mha", tmp_path / "r.json"
    assert main(["synth", "inplane", "--out", str(src), *ARGS, "--quiet"]) == 0
    assert main(["track", str(src), "--tracker", "inplane", "--method", "kf+f", "--json",
                 str(res_json), "--out-plus", str(res_plus), "--quiet"]) == 0
    a, b = read_plus(src), read_plus(res_plus)
    np.testing.assert_array_equal(b.images, a.images)
    np.testing.assert_array_equal(b.spacing_mm, a.spacing_mm)
    np.testing.assert_array_equal(b.origin_mm, a.origin_mm)
    np.testing.assert_array_equal(b.timestamps_s, a.timestamps_s)
    np.testing.assert_array_equal(b.transforms["ProbeToReference"],
                                  a.transforms["ProbeToReference"])
    res = json.loads(res_json.read_text())
    assert res["summary"]["tip_error_p95_mm"] < 1.0  # labels came through the PLUS file
    ok = b.transform_ok["NeedleTipToReference"]
    np.testing.assert_array_equal(ok, [f["status"] == "tracking" for f in res["frames"]])
    pose = b.transforms["ProbeToReference"]
    for i, tip in _tips(res):
        m = np.linalg.inv(pose[i]) @ b.transforms["NeedleTipToReference"][i]
        np.testing.assert_allclose(m[[0, 2], 3], tip, atol=1e-5)
        np.testing.assert_allclose(m[[0, 2], 2], res["frames"][i]["direction"], atol=1e-5)
    # the ground truth of synth's PLUS file equals the .npz labels
    gt = synth.generate("inplane", seed=12, frames=12, width_mm=25.0, depth_mm=30.0,
                        angle_deg=40.0, start_length_mm=18.0, background="homogeneous")
    m = np.linalg.inv(a.transforms["ProbeToReference"]) @ a.transforms["NeedleTipToReference"]
    np.testing.assert_allclose(m[:, [0, 2], 3], gt.tip_mm, atol=1e-10)


def test_synth_mhd_and_format_checks(tmp_path, capsys):
    out = tmp_path / "s.mhd"
    assert main(["synth", "inplane", "--out", str(out), "--frames", "2", "--param",
                 "width_mm=10", "--param", "depth_mm=12", "--quiet"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.mhd", "s.zraw"]
    assert read_plus(out).n_frames == 2
    (tmp_path / "s.mhd").unlink()  # the data file alone still blocks a new output
    rc = main(["synth", "inplane", "--out", str(out), "--frames", "2", "--quiet"])
    assert rc == 2 and "s.zraw exists" in capsys.readouterr().err
    rc = main(["synth", "inplane", "--out", str(tmp_path / "x.npz"), "--format", "plus"])
    assert rc == 2 and "must end in .mha or .mhd" in capsys.readouterr().err


def _one_line_error(capsys, *needles):
    err = capsys.readouterr().err
    assert err.startswith("needlenet: error: ") and err.count("\n") == 1, err
    for n in needles:
        assert n in err, err
    return err


def test_bad_recordings_are_one_line(seq, tmp_path, capsys):
    from needlenet.io import save_plus_sequence

    p = save_plus_sequence(seq, tmp_path / "a.seq.mha", compress=False)[0]
    data = p.read_bytes()
    track = ["--tracker", "inplane", "--method", "kf"]
    p.write_bytes(data.replace(b"ElementSpacing = 0.1 0.1 1\n", b""))
    assert main(["track", str(p), *track]) == 2
    _one_line_error(capsys, "a.seq.mha: no pixel spacing", "--spacing")
    p.write_bytes(data[:-5000])
    assert main(["track", str(p), *track]) == 2
    _one_line_error(capsys, "a.seq.mha: truncated")
    p.write_bytes(data.replace(b"Orientation = MF\n", b"Orientation = FM\n"))
    assert main(["track", str(p), *track]) == 2
    _one_line_error(capsys, "UltrasoundImageOrientation = 'FM' is unknown")
    assert main(["track", str(p), *track, "--crop", "1,2,3"]) == 2
    _one_line_error(capsys, "--crop '1,2,3': expected X,Y,W,H")
    assert main(["track", str(p), *track, "--spacing", "abc"]) == 2
    _one_line_error(capsys, "--spacing 'abc'")


def test_outputs_are_checked_before_work(sitk_file, tmp_path, capsys):
    out = tmp_path / "r.seq.mha"
    out.write_bytes(b"precious")
    track = ["track", str(sitk_file), "--tracker", "inplane", "--method", "kf", "--quiet"]
    assert main([*track, "--out-plus", str(out)]) == 2
    _one_line_error(capsys, "r.seq.mha exists; pass --overwrite")
    assert out.read_bytes() == b"precious"
    assert main([*track, "--out-plus", str(tmp_path / "r.nrrd")]) == 2
    _one_line_error(capsys, "must end in .mha or .mhd")
    assert main([*track, "--out-plus", str(out), "--overwrite"]) == 0
    assert read_plus(out).n_frames == 12


def test_an_input_a_directory_or_a_bad_seed_is_refused_before_work(sitk_file, tmp_path,
                                                                    capsys):
    """Issue 21: ``--out-plus`` naming the input replaced it (and its labels) even with
    --overwrite; an output path that is a directory failed after the whole run; a negative
    seed was a traceback."""
    rec = tmp_path / "rec.seq.mha"
    rec.write_bytes(sitk_file.read_bytes())
    track = ["track", str(rec), "--tracker", "inplane", "--method", "kf", "--quiet"]
    assert main([*track, "--out-plus", str(rec), "--overwrite"]) == 2
    _one_line_error(capsys, "--out-plus", "is the input", "write the results to another file")
    assert rec.read_bytes() == sitk_file.read_bytes()
    for option, name in (("--json", "d.json"), ("--overlay", "d.gif"),
                         ("--out-plus", "d.seq.mha")):
        (tmp_path / name).mkdir()
        assert main([*track, option, str(tmp_path / name), "--overwrite"]) == 2
        _one_line_error(capsys, f"{option} ", f"{name} is a directory")
    for cmd in (["synth", "inplane", "--out", str(tmp_path / "s.npz")], track):
        with pytest.raises(SystemExit) as exc:
            main([*cmd, "--seed", "-1"])
        assert exc.value.code == 2
        assert "argument --seed: -1 is outside 0 to 2^63 - 1" in capsys.readouterr().err


def test_reading_notes_are_printed_as_warnings(seq, tmp_path, capsys):
    """A NaN pixel in a float recording is shown black and reported; tracking goes on."""
    img = sitk.GetImageFromArray(seq.images.astype(np.float32) * 0.01)
    img.SetSpacing((float(seq.spacing_mm[1]), float(seq.spacing_mm[0]), 1.0))
    path = tmp_path / "f.seq.mha"
    sitk.WriteImage(img, str(path))
    data = sitk.GetArrayFromImage(sitk.ReadImage(str(path)))
    data[3, 5, 7] = np.nan
    out = sitk.GetImageFromArray(data)
    out.CopyInformation(img)
    sitk.WriteImage(out, str(path))
    assert main(["track", str(path), "--tracker", "inplane", "--fps", "20", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "needlenet: warning: " in err and "1 pixels in 1 frames (first: frame 3) are not " \
        "finite numbers" in err


def test_igtl_port_in_use_and_no_client(sitk_file, capsys):
    track = ["track", str(sitk_file), "--tracker", "inplane", "--method", "kf", "--quiet"]
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        assert main([*track, "--igtl", str(port)]) == 2
        _one_line_error(capsys, f"port {port}", "address already in use")
    assert main([*track, "--igtl", "0"]) == 0  # no client: tracks anyway, sends nothing
    assert "sent 0 frames, skipped 12" in capsys.readouterr().err


def test_png_folder_with_spacing_on_the_command_line(seq, tmp_path, capsys):
    d = tmp_path / "frames"
    d.mkdir()
    pad = np.zeros((seq.images.shape[0], seq.images.shape[1] + 20, seq.images.shape[2] + 30),
                   np.uint8)
    pad[:, 20:, 30:] = seq.images  # a screen capture: the image area starts at (30, 20)
    for i, f in enumerate(pad):
        cv2.imwrite(str(d / f"{i:03d}.png"), f)
    out = tmp_path / "r.json"
    track = ["track", str(d), "--tracker", "inplane", "--method", "kf+f", "--quiet"]
    assert main(track) == 2
    _one_line_error(capsys, "no pixel spacing", "--spacing")
    assert main([*track, "--spacing", "0.1"]) == 2
    _one_line_error(capsys, "no frame times", "--fps")
    assert main([*track, "--spacing", "0.1", "--fps", "20", "--crop", "30,20,250,300",
                 "--json", str(out)]) == 0
    tips = _tips(json.loads(out.read_text()))
    # without a sidecar, origin 0 is the capture's top-left pixel, so the crop's corner is at
    # (x, z) = (30, 20) px * 0.1 mm; synth's image starts at its origin_mm
    shift = np.array(seq.origin_mm[::-1]) - [3.0, 2.0]
    err = [np.linalg.norm(t + shift - seq.tip_mm[i]) for i, t in tips]
    assert len(tips) >= 8 and np.median(err) < 1.0


# -- found by the fuzz suite (tests/fuzz) --------------------------------------------------------

def test_undefined_metrics_are_null_never_nan(seq, tmp_path, capsys):
    """A labelled recording where nothing is tracked: the error statistics are undefined, and
    were printed (and written to --json) as NaN, which is not JSON."""
    dark = synth.Sequence(**{**seq.as_dict(), "images": np.zeros_like(seq.images)})
    src = synth.save_sequence(dark, tmp_path / "dark.npz")
    out = tmp_path / "r.json"
    assert main(["track", str(src), "--method", "kf", "--features", "classical", "--quiet",
                 "--json", str(out)]) == 0

    def strict(text):
        return json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in the output"))

    printed = capsys.readouterr().out
    summary = strict(printed[:printed.rindex("}") + 1])
    assert summary["tip_error_median_mm"] is None or "tip_error_median_mm" not in summary
    assert strict(out.read_text())["summary"]["frames"] == 12


def test_output_names_too_long_or_looping_are_refused_before_work(sitk_file, tmp_path, capsys):
    track = ["track", str(sitk_file), "--method", "kf", "--features", "classical", "--quiet"]
    assert main([*track, "--json", str(tmp_path / ("x" * 300 + ".json"))]) == 2
    _one_line_error(capsys, "longer than this file system allows")
    (tmp_path / "loop.json").symlink_to(tmp_path / "loop.json")  # was a RuntimeError
    assert main([*track, "--json", str(tmp_path / "loop.json")]) == 2
    _one_line_error(capsys, "loop.json exists; pass --overwrite")
    long = tmp_path / ("y" * 245 + ".json")  # fits; the temporary name beside it must too
    assert main([*track, "--json", str(long)]) == 0
    assert json.loads(long.read_text())["summary"]["frames"] == 12
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loop.json", long.name]


def test_a_dangling_symlink_an_empty_name_or_a_sidecar_is_no_new_output(seq, sitk_file,
                                                                           tmp_path, capsys):
    """A dangling symlink was replaced without --overwrite; ``--overlay ''`` was ignored;
    ``--json`` could replace a video's sidecar."""
    track = ["track", str(sitk_file), "--method", "kf", "--features", "classical", "--quiet"]
    (tmp_path / "d.json").symlink_to(tmp_path / "nowhere" / "x.json")
    assert main([*track, "--json", str(tmp_path / "d.json")]) == 2
    _one_line_error(capsys, "d.json exists; pass --overwrite")
    assert (tmp_path / "d.json").is_symlink()
    assert main([*track, "--overlay", ""]) == 2
    _one_line_error(capsys, "--overlay ''")
    video = tmp_path / "clip.avi"
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 20,
                        seq.images.shape[:0:-1], False)
    for im in seq.images:
        w.write(im)
    w.release()
    sidecar = tmp_path / "clip.json"
    sidecar.write_text(json.dumps({"spacing_mm": 0.1}))
    assert main(["track", str(video), "--quiet", "--features", "classical", "--json",
                 str(sidecar), "--overwrite"]) == 2
    _one_line_error(capsys, "is the input")
    assert json.loads(sidecar.read_text()) == {"spacing_mm": 0.1}


def test_an_mhd_output_whose_name_its_header_cannot_hold(sitk_file, tmp_path, capsys):
    """The data file is named in the header: a line break in it wrote an unreadable file."""
    track = ["track", str(sitk_file), "--method", "kf", "--features", "classical", "--quiet"]
    assert main([*track, "--out-plus", str(tmp_path / "r\nx.mhd")]) == 2
    _one_line_error(capsys, "cannot be read back; use .mha")
    assert list(tmp_path.iterdir()) == []


def test_angle_and_tuples_are_checked_against_the_tracker_that_runs(tmp_path, capsys):
    vol = synth.save_sequence(synth.generate("volume", seed=1, frames=1, output_size=24,
                                             background="homogeneous"), tmp_path / "v.npz")
    assert main(["track", str(vol), "--angle", "45", "--quiet"]) == 2  # was a TypeError
    _one_line_error(capsys, "--angle is for the inplane tracker", "'volume' frames")
    src = synth.save_sequence(synth.generate("inplane", seed=1, frames=2, width_mm=10.0,
                                             depth_mm=10.0), tmp_path / "i.npz")
    assert main(["track", str(src), "--method", "kfv", "--features", "classical", "--quiet",
                 "--param", "axis.background_band_mm=-0"]) == 2  # was a ValueError mid-run
    _one_line_error(capsys, "axis.background_band_mm: expected 2 comma-separated values")


@pytest.mark.parametrize("args, message", [
    (["--param", "frame_rate_hz="], "frame_rate_hz: parameter frame_rate_hz: expected a number"),
    (["--param", "stop_length_mm=nan"], "expected a finite number"),
    (["--speed", "1e9"], "speed_mm_s = 1000000000.0 must be a number in 0.0-1000.0"),
    (["--param", "frame_rate_hz=1e9"], "frame_rate_hz = 1000000000.0 frames/s is outside"),
    (["--frames", "100001"], "frames 100001: expected 1 to 100000"),
    (["--angle", "nan"], "--angle nan: expected a finite number"),
])
def test_synth_settings_are_read_as_their_fields_and_written_readable(tmp_path, capsys, args,
                                                                       message):
    """Each was a traceback inside the simulator, or a file track could not read."""
    out = tmp_path / "s.npz"
    assert main(["synth", "inplane", "--out", str(out), "--frames", "2", "--quiet",
                 *args]) == 2
    _one_line_error(capsys, message)
    assert not out.exists()


def test_synth_volume_too_large_is_refused_before_work(tmp_path, capsys):
    out = tmp_path / "v.npz"
    assert main(["synth", "volume", "--out", str(out), "--param", "output_size=2000",
                 "--quiet"]) == 2  # allocated 7.5 GiB
    _one_line_error(capsys, "output_size=2000 makes volumes of 8e+09 voxels")
