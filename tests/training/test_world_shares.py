"""Shares of the volume training worlds drawn with an interface beside the needle, and with no
needle at all."""

import numpy as np
import pytest

import synth

pytest.importorskip("torch")
pytest.importorskip("lightning")

from training.data import sample_from_sequence  # noqa: E402
from training.train import config_for  # noqa: E402
from training.worlds import randomize  # noqa: E402


def _draws(modality, n, **shares):
    cfg = config_for(modality, **shares).data
    return [randomize(modality, np.random.default_rng(s), cfg) for s in range(n)]


def test_volume_interfaces_and_needle_free_worlds_are_drawn_in_their_shares():
    plain = _draws("volume", 400)
    drawn = _draws("volume", 400, volume_interfaces=0.4, volume_needle_free=0.2)
    zhao = [w for name, w in drawn if name == "volume"]  # the Zhao-scenario worlds
    with_if = [w for w in zhao if "interface_offset_mm" in w]
    free = [w for w in zhao if w.get("needle_free")]
    assert abs(len(with_if) / len(zhao) - 0.4) < 0.08
    assert abs(len(free) / len(zhao) - 0.2) < 0.07
    assert all(w["cr"] is None for w in free)
    off = np.abs([w["interface_offset_mm"] for w in with_if])
    assert 1.5 <= off.min() and off.max() <= 8.0
    assert max(abs(w["interface_roll_deg"]) for w in with_if) <= 40.0
    assert all(1.5 <= w["interface_brightness"] <= 6.0 for w in with_if)
    # the draws of the recipe are otherwise the shipped recipe's
    for (na, a), (nb, b) in zip(plain, drawn, strict=True):
        assert na == nb
        keep = {k: v for k, v in b.items() if not k.startswith("interface_")
                and k not in ("needle_free", "cr")}
        assert keep == {k: v for k, v in a.items() if k != "cr"}
    assert not any("interface_offset_mm" in w or w.get("needle_free") for _, w in plain)


def test_a_needle_free_training_volume_has_no_target():
    cfg = config_for("volume", volume_needle_free=1.0).data
    name, world = next(w for w in (randomize("volume", np.random.default_rng(s), cfg)
                                   for s in range(20)) if w[0] == "volume")
    assert world["needle_free"] and world["cr"] is None
    seq = synth.generate(name, seed=3, frames=2, **{**world, "output_size": 56})
    x, y = sample_from_sequence(seq, 1, cfg, np.random.default_rng(0))[:2]
    assert x.shape == (1, 40, 40, 40) and np.isfinite(x).all()
    assert float(y.max()) == 0.0
