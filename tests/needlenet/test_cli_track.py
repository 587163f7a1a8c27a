"""needlenet track: end to end on sequence files, metrics in the JSON, clear errors."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

import synth
from needlenet.cli import main


@pytest.fixture(scope="module")
def inplane_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("track")
    seq = synth.generate("inplane", seed=12, frames=12, width_mm=25.0, depth_mm=30.0,
                         angle_deg=40.0, start_length_mm=18.0, background="homogeneous")
    return synth.save_sequence(seq, d / "ip.npz")


def test_track_writes_frames_summary_and_overlay(inplane_file, tmp_path, capsys):
    out, gif = tmp_path / "r.json", tmp_path / "r.gif"
    rc = main(["track", str(inplane_file), "--tracker", "inplane", "--method", "kf+f",
               "--json", str(out), "--overlay", str(gif), "--quiet"])
    assert rc == 0
    res = json.loads(out.read_text())
    assert len(res["frames"]) == 12
    f = res["frames"][-1]
    assert {"t", "status", "tip_mm", "direction", "latency_ms"} <= f.keys()
    s = res["summary"]
    # Table III columns computed by needlenet.eval
    for k in ("norm_e_mm", "e_theta_deg", "abs_e_theta_deg", "e_n_mm", "e_p_mm"):
        assert k in s
    assert s["tip_error_p95_mm"] < 1.0
    # what the tracker said of each frame, counted (the figures of an unlabelled recording)
    for status in ("tracking", "lost", "searching"):
        assert s[f"frames_{status}"] == sum(fr["status"] == status for fr in res["frames"])
    assert s["frames_tracking"] + s["frames_lost"] + s["frames_searching"] == 12
    assert isinstance(s["reasons"], list)
    assert gif.stat().st_size > 1000 and gif.read_bytes()[:6] in (b"GIF89a", b"GIF87a")


def test_the_summary_counts_the_reasons_for_frames_without_a_needle(tmp_path, capsys):
    # a needle-free recording: every frame says why it has no needle, the reasons counted
    # with their figures masked, the most frequent first
    seq = synth.generate("inplane", seed=113, frames=14, needle_free=True)
    f = synth.save_sequence(seq, tmp_path / "free.npz")
    out = tmp_path / "r.json"
    assert main(["track", str(f), "--json", str(out), "--quiet"]) == 0
    capsys.readouterr()
    res = json.loads(out.read_text())
    reasons = [fr["reason"] for fr in res["frames"] if fr["status"] != "tracking"]
    listed = res["summary"]["reasons"]
    assert 1 <= len(listed) <= 3
    counts = [int(r.split(" frame")[0]) for r in listed]
    assert counts == sorted(counts, reverse=True) and sum(counts) <= len(reasons)
    assert not any(ch.isdigit() for r in listed for ch in r.split(": ", 1)[1])
    masked = [re.sub(r"\d+(?:\.\d+)?", "N", r) for r in reasons]
    assert counts[0] == max(masked.count(m) for m in set(masked))


def test_track_learned_features(inplane_file, tmp_path):
    out = tmp_path / "l.json"
    rc = main(["track", str(inplane_file), "--tracker", "inplane", "--method", "om",
               "--features", "learned", "--json", str(out), "--quiet"])
    assert rc == 0
    assert json.loads(out.read_text())["summary"]["features"] == "learned"


def test_wrong_modality_is_refused_before_the_run(inplane_file, capsys):
    rc = main(["track", str(inplane_file), "--tracker", "volume", "--method", "roi-rk"])
    err = capsys.readouterr().err
    assert rc == 2 and "holds 'inplane' frames" in err and "3D volumes" in err


@pytest.mark.parametrize("argv,msg", [
    (["--method", "nope"], "has no method 'nope'"),
    (["--method", "kf", "--model", "{d}/missing.onnx"], "does not exist"),
    (["--method", "kf", "--overlay", "{d}/x.png"], "use .gif, .mp4 or .avi"),
    (["--features", "classical", "--model", "{d}/m.onnx"], "does not go with --features"),
])
def test_bad_arguments(inplane_file, tmp_path, capsys, argv, msg):
    rc = main(["track", str(inplane_file), "--tracker", "inplane",
               *[a.format(d=tmp_path) for a in argv]])
    assert rc == 2 and msg in capsys.readouterr().err


def test_tracker_params_are_read_as_their_fields_types():
    from needlenet.trackers import AxialParams, InplaneParams, VolumeTrackerParams, tracker_params

    p = tracker_params("volume", ["image_refine=false", "max_trials=200",
                                  "intensity_threshold=70", "image_refine_radii_mm=2,1.25",
                                  "insertion.variance_threshold_mm2=90", "frangi.alpha=0.3"])
    assert isinstance(p, VolumeTrackerParams)
    assert p.image_refine is False and p.max_trials == 200 and p.intensity_threshold == 70
    assert p.image_refine_radii_mm == (2.0, 1.25)
    assert p.insertion.variance_threshold_mm2 == 90.0
    assert p.insertion.n_candidates == VolumeTrackerParams().insertion.n_candidates
    assert p.frangi.alpha == 0.3
    assert tracker_params("volume", {"intensity_threshold": "none"}).intensity_threshold is None
    assert isinstance(tracker_params("inplane", []), InplaneParams)
    assert isinstance(tracker_params("axial", []), AxialParams)


@pytest.mark.parametrize("setting,msg", [
    ("max_trails=10", "unknown VolumeTrackerParams parameter 'max_trails'; did you mean "
                      "max_trials"),
    ("max_trials=2.5", "parameter max_trials: expected an integer, got '2.5'"),
    ("max_trials=many", "parameter max_trials: expected a number"),
    ("image_refine=maybe", "parameter image_refine: expected true or false"),
    ("roi_radius_mm=nan", "expected a finite number"),
    ("roi_radius_mm=-1", "roi_radius_mm must be finite and > 0"),
    ("insertion.tau=3", "unknown InsertionParams parameter 'tau' of insertion"),
    ("max_trials.x=3", "parameter max_trials has no fields"),
    ("frangi=1", "set its fields instead (frangi.FIELD=VALUE)"),
    ("image_refine", "expected NAME=VALUE"),
    # each value is checked against its field's type: none only where the field may be None,
    # floats finite, integers whole, booleans true/false/1/0/yes/no, tuples item by item
    ("roi_radius_mm=none", "parameter roi_radius_mm: expected a finite number, got 'none': "
                           "roi_radius_mm cannot be none"),
    ("roi_radius_mm=inf", "parameter roi_radius_mm: expected a finite number, got 'inf'"),
    ("intensity_threshold=nan", "parameter intensity_threshold: expected a finite number, "
                                "got 'nan'"),
    ("max_trials=inf", "parameter max_trials: expected an integer, got 'inf'"),
    ("max_trials=none", "parameter max_trials: expected an integer, got 'none'"),
    ("image_refine=on", "parameter image_refine: expected true or false (or 1/0, yes/no), "
                        "got 'on'"),
    ("image_refine_radii_mm=1,nan", "parameter image_refine_radii_mm: expected a finite "
                                    "number, got 'nan' (item 2 of '1,nan')"),
    ("insertion.variance_threshold_mm2=none", "parameter insertion.variance_threshold_mm2: "
                                              "expected a finite number, got 'none'"),
])
def test_bad_tracker_params_are_named(tmp_path, capsys, setting, msg):
    from needlenet.trackers import tracker_params

    with pytest.raises(ValueError) as exc:
        tracker_params("volume", [setting])
    assert msg in str(exc.value)
    # the CLI says the same before it reads the recording (which does not exist here)
    rc = main(["track", str(tmp_path / "none.npz"), "--tracker", "volume", "--method",
               "roi-rk", "--param", setting])
    assert rc == 2 and msg in capsys.readouterr().err


def test_settings_are_read_as_their_fields_types_strictly():
    from needlenet.settings import convert_setting, parse_value
    from needlenet.trackers import tracker_params

    # accepted: the readings of each type, none where the field may hold None
    assert [convert_setting("b", t, False) for t in ("yes", "1", "TRUE", "no", "0", "false")] \
        == [True, True, True, False, False, False]
    assert convert_setting("n", "1e2", 5) == 100 and isinstance(convert_setting("n", "7", 5), int)
    assert convert_setting("x", "2.5", 1.0) == 2.5
    assert convert_setting("t", "1, 2", (1.0, 2.0)) == (1.0, 2.0)
    assert convert_setting("o", "none", None) is None
    assert convert_setting("o", "none", 0.5, "float | None") is None
    assert convert_setting("o", "3", None, "int | None") == 3
    assert parse_value("null") is None and parse_value("4") == 4 and parse_value("a") == "a"
    p = tracker_params("volume", ["likelihood_relative=none", "image_tip_background_mm=none",
                                  "insertion_candidates_mm3=null"])
    assert p.likelihood_relative is None and p.image_tip_background_mm is None
    assert p.insertion_candidates_mm3 is None
    # refused, with the setting, the value and what is expected named
    for args, msg in [
        (("min_length_mm", "none", 10.0), "parameter min_length_mm: expected a finite "
                                          "number, got 'none': min_length_mm cannot be none"),
        (("speed", "nan", 1.0), "parameter speed: expected a finite number, got 'nan'"),
        (("speed", "-inf", 1.0), "parameter speed: expected a finite number, got '-inf'"),
        (("steps", "2.5", 10), "parameter steps: expected an integer, got '2.5'"),
        (("steps", "ten", 10), "parameter steps: expected a number (an integer), got 'ten'"),
        (("flag", "on", True), "parameter flag: expected true or false (or 1/0, yes/no), "
                               "got 'on'"),
        (("flag", "none", True), "parameter flag: expected true or false"),
        (("mode", "none", "auto"), "parameter mode: expected text, got 'none'"),
        (("pair", "1,inf", (1.0, 2.0)), "parameter pair: expected a finite number, got 'inf' "
                                        "(item 2 of '1,inf')"),
        (("pair", "none", (1.0, 2.0)), "parameter pair: expected comma-separated values, "
                                       "got 'none'"),
        (("level", "nan", None), "parameter level: expected a finite number, got 'nan'"),
        (("sign", "1.5", None, "int | None"), "parameter sign: expected an integer, got '1.5'"),
    ]:
        with pytest.raises(ValueError) as exc:
            convert_setting(*args)
        assert msg in str(exc.value), str(exc.value)
    with pytest.raises(ValueError, match="parameter insertion_sign: expected an integer"):
        tracker_params("axial", ["insertion_sign=1.5"])


def test_track_passes_params_to_the_tracker(tmp_path):
    f = synth.save_sequence(synth.generate("volume", seed=14, background="homogeneous",
                                           frames=4, output_size=64, cr=4.7),
                            tmp_path / "v.npz")
    rates = []
    for extra in ([], ["--param", "intensity_threshold=255"]):  # a grey level nothing reaches
        out = tmp_path / f"r{len(extra)}.json"
        assert main(["track", str(f), "--tracker", "volume", "--method", "roi-rk",
                     "--features", "classical", "--json",
                     str(out), "--quiet", *extra]) == 0
        rates.append(json.loads(out.read_text())["summary"]["failure_rate"])
    assert rates[0] < 1.0 and rates[1] == 1.0


def test_corrupt_file_is_named(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"garbage")
    rc = main(["track", str(bad), "--tracker", "inplane", "--method", "kf"])
    assert rc == 2 and "bad.npz" in capsys.readouterr().err


def test_constant_and_nan_frames_are_lost_not_a_crash(tmp_path):
    seq = synth.generate("inplane", seed=13, frames=6, width_mm=20.0, depth_mm=25.0,
                         start_length_mm=15.0, background="homogeneous")
    seq.images[2] = 128  # a constant frame in the middle of the sequence
    from needlenet.trackers import make_tracker

    est = make_tracker("inplane", "kf", "classical").run(seq)
    assert len(est) == 6
    assert est[2].status.value in ("lost", "searching") and "constant" in est[2].reason
    from needlenet.features import Frame

    tr = make_tracker("inplane", "kf", "classical")
    frame = Frame(np.full(seq.images.shape[1:], np.nan, np.float32), seq.grid())
    assert tr.update(frame).status.value == "searching"


@pytest.mark.parametrize("scenario,tracker,method,kw,key", [
    ("volume", "volume", "roi-rk", {"frames": 4, "output_size": 64, "cr": 4.7}, "failure_rate"),
    ("axial", "axial", "carriere", {"frames": 30, "width_mm": 20.0, "depth_mm": 30.0,
                                    "insertion_mm": 15.0, "rotation_depth_mm": 12.0},
     "tip_prediction_error_mm"),
])
def test_track_volume_and_axial(tmp_path, scenario, tracker, method, kw, key):
    f = synth.save_sequence(synth.generate(scenario, seed=14, background="homogeneous", **kw),
                            tmp_path / "s.npz")
    out = tmp_path / "r.json"
    assert main(["track", str(f), "--tracker", tracker, "--method", method, "--json",
                 str(out), "--quiet"]) == 0
    s = json.loads(out.read_text())["summary"]
    assert key in s and s["frames"] == kw["frames"]


def test_track_without_options_runs_the_default_tracker(tmp_path, capsys):
    f = synth.save_sequence(synth.generate("inplane", seed=15, frames=4, depth_mm=25.0,
                                           start_length_mm=15.0), tmp_path / "i.npz")
    assert main(["track", str(f), "--quiet"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["tracker"], out["method"], out["features"]) == ("inplane", "line", "learned")


def test_a_volume_without_options_runs_roi_rk_on_classical_features(tmp_path, capsys):
    # the features that track best on the PyMUST volume validation set; a model given is learned
    f = synth.save_sequence(synth.generate("volume", seed=14, background="homogeneous",
                                           frames=2, output_size=56, cr=4.7),
                            tmp_path / "v.npz")
    assert main(["track", str(f), "--quiet"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["tracker"], out["method"], out["features"]) == ("volume", "roi-rk", "classical")
    from needlenet.features import shipped_model_path

    assert main(["track", str(f), "--quiet", "--model", str(shipped_model_path("volume"))]) == 0
    assert json.loads(capsys.readouterr().out)["features"] == "learned"


@pytest.mark.parametrize("args,msg", [(["--angle", "120"], "0 to 90 degrees"),
                                      (["--tracker", "volume", "--angle", "30"],
                                       "--angle is for the inplane tracker"),
                                      (["--method", "ransac"], "has no method 'ransac'")])
def test_track_angle_and_method_are_checked(tmp_path, capsys, args, msg):
    f = synth.save_sequence(synth.generate("inplane", seed=15, frames=2, depth_mm=25.0),
                            tmp_path / "i.npz")
    assert main(["track", str(f), "--quiet", *args]) == 2
    assert msg in capsys.readouterr().err


def test_track_seed_makes_volume_runs_repeatable(tmp_path):
    f = synth.save_sequence(synth.generate("volume", seed=14, background="homogeneous",
                                           frames=3, output_size=56, cr=4.7),
                            tmp_path / "v.npz")
    tips = []
    for k in range(2):
        out = tmp_path / f"s{k}.json"
        assert main(["track", str(f), "--tracker", "volume", "--method", "roi-rk", "--seed",
                     "3", "--json", str(out), "--quiet"]) == 0
        tips.append([fr["tip_mm"] for fr in json.loads(out.read_text())["frames"]])
    assert tips[0] == tips[1]


def test_the_summary_counts_tips_read_from_the_echo_gained(tmp_path, capsys):
    # PyMUST's needle beside an interface, merged with it on the map: the frames whose tip
    # was read where the advancing needle gained echo are counted, as each frame says
    pytest.importorskip("onnxruntime")
    f = Path(__file__).resolve().parents[2] / "needlenet" / "data" / "validation" / \
        "val_lin_right_side_20_interface.npz"
    out = tmp_path / "m.json"
    assert main(["track", str(f), "--json", str(out), "--quiet"]) == 0
    capsys.readouterr()
    res = json.loads(out.read_text())
    moved = sum(bool(fr.get("tip_from_motion")) for fr in res["frames"])
    assert moved >= 5
    assert res["summary"]["frames_tip_from_motion"] == moved
