import numpy as np
import pytest

import synth
from needlenet.cli import main


def test_synth_writes_sequence_and_preview(tmp_path, capsys):
    out, prev = tmp_path / "s.npz", tmp_path / "s.png"
    rc = main(["synth", "inplane", "--out", str(out), "--frames", "2", "--seed", "4",
               "--param", "width_mm=12", "--param", "depth_mm=15", "--speed", "5",
               "--angle", "45", "--preview", str(prev), "--quiet"])
    assert rc == 0
    s = synth.load_sequence(out)
    assert s.n_frames == 2 and s.meta["params"]["speed_mm_s"] == 5.0
    assert s.meta["draw"]["angle_deg"] == 45.0
    assert prev.stat().st_size > 1000
    assert "wrote" in capsys.readouterr().out


@pytest.mark.parametrize("argv,msg", [
    (["synth", "nope", "--out", "{d}/x.npz"], "unknown scenario 'nope'"),
    (["synth", "inplane", "--out", "{d}/x.npz", "--speed", "-2"], "speed_mm_s must be positive"),
    (["synth", "volume", "--out", "{d}/x.npz", "--cr", "40"], "cr"),
    (["synth", "inplane", "--out", "{d}/x.txt"], "must end in .npz"),
    (["synth", "inplane", "--out", "{d}/missing/x.npz"], "does not exist"),
    (["synth", "axial", "--out", "{d}/x.npz", "--angle", "30"], "--angle does not apply"),
    (["synth", "inplane", "--out", "{d}/x.npz", "--param", "bogus=1"], "no parameter 'bogus'"),
    (["synth", "volume", "--out", "{d}/x.npz", "--param", "noise_db=1e300"],
     "noise_db must lie within +-200 dB"),
])
def test_bad_input_one_line_error_nothing_written(tmp_path, capsys, argv, msg):
    rc = main([a.format(d=tmp_path) for a in argv])
    err = capsys.readouterr().err
    assert rc == 2
    assert msg in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_existing_output_is_not_overwritten(tmp_path, capsys):
    out = tmp_path / "s.npz"
    out.write_bytes(b"precious")
    rc = main(["synth", "inplane", "--out", str(out), "--frames", "1"])
    assert rc == 2 and "--overwrite" in capsys.readouterr().err
    assert out.read_bytes() == b"precious"


def test_list_shows_scenarios(capsys):
    assert main(["synth", "--list"]) == 0
    text = capsys.readouterr().out
    for name in ("inplane", "volume", "volume-motion", "axial", "servo"):
        assert name in text
    assert "speed_mm_s" in text


def test_unwritable_directory(tmp_path, capsys):
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o500)
    try:
        import os
        if os.access(d, os.W_OK):  # running as root: permissions are not enforced
            pytest.skip("root can write anywhere")
        rc = main(["synth", "inplane", "--out", str(d / "x.npz")])
        assert rc == 2 and "not writable" in capsys.readouterr().err
    finally:
        d.chmod(0o700)
    assert np.asarray(list(d.iterdir())).size == 0
