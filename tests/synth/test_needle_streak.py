"""The streak of unfocused imaging past a specular needle's tip (synth.NeedleSpec.streak_db)."""

import numpy as np
import pytest

import synth

KW = dict(seed=5, frames=1, angle_deg=12.0, start_length_mm=25.0, stop_length_mm=26.0,
          needle_echo=150.0, dynamic_range_db=55.0, background="homogeneous")


def _along_axis(seq, ds_mm):
    """Mean grey on the needle's axis (its wall facing the probe) ``ds_mm`` past the tip."""
    tip, d = seq.tip_mm[0], seq.direction[0]
    r = synth.needle_radius_mm(seq.meta["needle"]["gauge"])
    n = np.array([-d[1], d[0]])
    n = n if n[1] < 0 else -n  # towards the probe
    g = seq.grid()
    out = []
    for s in ds_mm:
        pts = tip + s * d + r * n + np.linspace(-0.15, 0.15, 7)[:, None] * n
        idx = np.rint(g.points_to_index(pts)).astype(int)
        out.append(float(seq.images[0][idx[:, 0], idx[:, 1]].max()))
    return np.array(out)


@pytest.fixture(scope="module")
def pair():
    plain = synth.generate("inplane", **KW)
    streak = synth.generate("inplane", **KW, needle_overrides={
        "streak_db": -10.0, "streak_fade_db_per_mm": 3.0})
    return plain, streak


def test_no_streak_by_default_and_nothing_changes_before_the_tip(pair):
    plain, streak = pair
    before = _along_axis(plain, [-6.0, -4.0, -2.0])
    assert np.array_equal(before, _along_axis(streak, [-6.0, -4.0, -2.0]))


def test_the_streak_continues_the_echo_past_the_tip_and_fades(pair):
    plain, streak = pair
    near = np.arange(1.0, 3.01, 0.25)  # 1-3 mm past the tip: -13 to -19 dB re the shaft
    far = np.arange(13.0, 15.01, 0.25)  # 13-15 mm: below -40 dB, nothing left
    gain_near = _along_axis(streak, near).mean() - _along_axis(plain, near).mean()
    gain_far = _along_axis(streak, far).mean() - _along_axis(plain, far).mean()
    assert gain_near > 40  # grey levels on a 55 dB, 8-bit display
    assert abs(gain_far) < 5
