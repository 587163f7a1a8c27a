import numpy as np
import pytest

from needlenet.eval._inplane_metrics import describe_errors, inplane_errors, insertion_angle_deg


def _unit(deg):
    a = np.radians(deg)
    return np.array([-np.cos(a), np.sin(a)])  # entering from the right, going down-left


def test_insertion_angle():
    assert insertion_angle_deg(_unit(35.0)) == pytest.approx(35.0)
    assert insertion_angle_deg(np.array([np.cos(0.5), np.sin(0.5)])) == pytest.approx(
        np.degrees(0.5))


def test_errors_by_hand():
    p, v = np.array([10.0, 20.0]), _unit(40.0)
    # estimate: 2 mm short along the axis, 0.5 mm off perpendicular, 1 degree steeper
    vh = _unit(41.0)
    nh = np.array([-vh[1], vh[0]])
    ph = p - 2.0 * vh - 0.5 * nh
    e = inplane_errors(p[None], v[None], ph[None], vh[None])
    assert e["e_n_mm"][0] == pytest.approx(2.0)  # positive: longer than estimated
    assert e["e_p_mm"][0] == pytest.approx(0.5)
    assert e["norm_e_mm"][0] == pytest.approx(np.hypot(2.0, 0.5))
    assert e["e_theta_deg"][0] == pytest.approx(-1.0)
    assert e["abs_e_theta_deg"][0] == pytest.approx(1.0)


def test_describe_percentiles():
    x = np.arange(1, 201, dtype=float)
    d = describe_errors(x, signed=False)
    assert d["p95"] == pytest.approx(np.percentile(x, 95)) and d["n"] == 200
    s = describe_errors(x - 100, signed=True)
    assert s["p2_5"] == pytest.approx(np.percentile(x - 100, 2.5))
    assert s["sd"] == pytest.approx(np.std(x, ddof=1))
