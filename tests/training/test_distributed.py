"""Training past one process: Lightning DDP on CPUs (gloo), each process its own worlds."""

import itertools
import json
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("lightning")
pytest.importorskip("onnx")

from training.data import DataConfig, SynthStream  # noqa: E402


def _first(cfg, rank, n=2):
    return [np.asarray(x) for x, _ in itertools.islice(iter(SynthStream(cfg, rank)), n)]


def test_each_process_simulates_its_own_worlds():
    cfg = DataConfig(crop=32, frames_per_world=2, shuffle_buffer=4, num_workers=0, seed=5)
    a0, a1 = _first(cfg, 0), _first(cfg, 1)
    assert all(np.array_equal(x, y) for x, y in zip(a0, _first(cfg, 0), strict=True))
    assert not any(np.array_equal(x, y) for x, y in zip(a0, a1, strict=True))


def test_two_cpu_processes_train_and_rank_zero_alone_reports(tmp_path):
    out = tmp_path / "run"
    onnx_path = tmp_path / "m.onnx"
    cmd = [sys.executable, "-m", "needlenet", "train", "inplane", "--steps", "2",
           "--devices", "2", "--workers", "0", "--out", str(out), "--export", str(onnx_path),
           "--param", "crop=32", "--param", "frames_per_world=2", "--param", "val_frames=2",
           "--param", "batch_size=2", "--param", "shuffle_buffer=4", "--param", "val_every=2",
           "--param", "speckle_worlds=2"]
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["processes"] == 2 and metrics["steps"] == 2
    assert np.isfinite(metrics["val/loss"])
    assert onnx_path.stat().st_size > 10_000
    assert r.stdout.count("wrote ") == 1  # one export, by rank 0


def test_bad_process_counts_are_refused(capsys):
    from needlenet.cli import main

    assert main(["train", "inplane", "--devices", "0"]) == 2
    assert "--devices must be at least 1, got 0" in capsys.readouterr().err
