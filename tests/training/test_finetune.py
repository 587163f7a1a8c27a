"""Fine-tuning from a checkpoint (``train --init``) and the narrow worlds' specular boundaries."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("lightning")
pytest.importorskip("onnx")

from training.data import DataConfig  # noqa: E402
from training.export import load_checkpoint  # noqa: E402
from training.networks import build_network  # noqa: E402
from training.train import DEFAULTS, _start_from, config_for  # noqa: E402
from training.worlds import randomize  # noqa: E402

BASE = Path(__file__).resolve().parents[2] / "training" / "checkpoints" / "inplane_base.ckpt"


def test_boundaries_are_drawn_in_their_share_of_narrow_worlds_and_nowhere_else():
    def draws(share, n=400):
        cfg = DataConfig(inplane_worlds="narrow", inplane_boundaries=share)
        return [randomize("inplane", np.random.default_rng(s), cfg)[1] for s in range(n)]

    none, half, every = draws(0.0), draws(0.5), draws(1.0)
    assert not any("interface_echo" in d for d in none)
    assert all(d["interface_echo"] > 0 for d in every)
    assert abs(np.mean(["interface_echo" in d for d in half]) - 0.5) < 0.07
    off = np.abs([d["interface_offset_mm"] for d in every])
    assert 1.0 <= off.min() < 1.3 and 7.7 < off.max() <= 8.0
    ratio = np.array([d["interface_echo"] / d["needle_echo"] for d in every])
    assert 0.25 <= ratio.min() < 0.3 and 2.2 < ratio.max() <= 2.5
    assert max(abs(d["interface_tilt_deg"]) for d in every) <= 15.0
    # a world's other draws are those of the recipe without boundaries
    for a, b in zip(none[:50], half[:50], strict=True):
        assert {k: v for k, v in b.items() if not k.startswith("interface_")} == a
    # the wide worlds draw their own interfaces: the share leaves them alone
    wide = DataConfig(inplane_boundaries=1.0)
    w = [randomize("inplane", np.random.default_rng(s), wide)[1] for s in range(50)]
    assert not any("interface_echo" in d for d in w)
    with pytest.raises(ValueError, match="inplane_boundaries"):
        DataConfig(inplane_boundaries=-0.1)


def test_a_run_starts_from_the_checkpoint_it_is_given():
    cfg = replace(DEFAULTS["inplane"], init=str(BASE))
    net = build_network("inplane")
    _start_from(net, cfg)
    ref, hp = load_checkpoint(BASE)
    assert hp["modality"] == "inplane" and hp["normalization"] == "robust"
    for (k, a), (_, b) in zip(net.state_dict().items(), ref.state_dict().items(), strict=True):
        assert torch.equal(a, b), k


@pytest.mark.parametrize("change, match", [
    ({"width": 8}, "not this recipe's"),
    ({"spacing_mm": 0.3}, "spacing_mm"),
    ({"normalization": "fixed"}, "normalization"),
])
def test_a_checkpoint_of_another_recipe_is_refused(change, match):
    cfg = config_for("inplane", init=str(BASE), **change)
    with pytest.raises(ValueError, match=match):
        _start_from(build_network("inplane", cfg.width), cfg)


def test_cli_init_is_checked_before_training_and_named_in_the_metadata(tmp_path, capsys):
    import onnx

    from needlenet.cli import main

    assert main(["train", "inplane", "--init", str(tmp_path / "none.ckpt")]) == 2
    assert "no such checkpoint file" in capsys.readouterr().err
    assert main(["train", "inplane", "--param", f"init={BASE}"]) == 2
    assert "--init" in capsys.readouterr().err
    assert main(["train", "axial", "--init", str(BASE), "--steps", "1", "--out",
                 str(tmp_path / "ax")]) == 2
    assert "modality 'inplane'" in capsys.readouterr().err
    out = tmp_path / "m.onnx"
    args = ["train", "inplane", "--init", str(BASE), "--steps", "2", "--workers", "0",
            "--out", str(tmp_path / "run"), "--export", str(out)]
    for p in ("crop=48", "frames_per_world=2", "val_frames=2", "val_every=1",
              "shuffle_buffer=4", "batch_size=2", "speckle_worlds=3",
              "inplane_boundaries=1.0", "lr=1e-3"):
        args += ["--param", p]
    assert main(args) == 0
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert meta["train_init"].startswith("inplane_base.ckpt sha256:")
    assert "inplane_boundaries=1.0" in meta["train_params"]


def test_the_shipped_inplane_model_names_its_base_and_its_fine_tuning():
    # the shipped in-plane model is the base checkpoint fine-tuned on narrow worlds with
    # specular boundaries (README: the command)
    import hashlib

    import onnx

    from needlenet.features import shipped_model_path

    meta = {p.key: p.value for p in onnx.load(str(shipped_model_path("inplane"))).metadata_props}
    digest = hashlib.sha256(BASE.read_bytes()).hexdigest()[:16]
    assert meta["train_init"] == f"inplane_base.ckpt sha256:{digest}"
    assert meta["train_params"] == "lr=1e-3 inplane_boundaries=0.5"
    assert meta["train_seed"] == "100" and meta["train_steps"] == "900"
    _, hp = load_checkpoint(BASE)
    assert hp["max_steps"] == DEFAULTS["inplane"].steps  # the base is the recipe's stage one
