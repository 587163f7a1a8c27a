"""The servo loops' watchdogs (issue 21): a frozen feed, a stuck detector, a needle that is
lost and one never found each stop the probe within 1 s of simulated time and 2 mm of travel,
with the cause named; nominal runs never trip them."""

import numpy as np
import pytest

from needlenet.servo import (
    ChatelainConfig,
    Fault,
    Measurement,
    SpeedGain,
    run_chatelain,
    run_ye,
)
from needlenet.servo._images import image_measurement

REASONS = {"frozen-feed": "stale_feed", "stuck-detector": "stuck_detector",
           "needle-lost": "needle_lost", "never-found": "never_found"}


def _stop(r):
    stops = [e for e in r["events"] if e["event"] == "safety_stop"]
    assert r["stopped"] and len(stops) == 1, r["events"]
    return stops[0]


@pytest.mark.parametrize("kind", sorted(REASONS))
@pytest.mark.parametrize("filt", ["pv", "prv"])
def test_ye_loop_stops_on_each_fault(kind, filt):
    fault = Fault(kind, 500)
    r = run_ye(filt, "dynamic", n_samples=900, seed=3, gating=True, adaptive=True, fault=fault)
    ev = _stop(r)
    assert ev["reason"] == REASONS[kind] and ev["fault"] == kind
    assert 0.0 < ev["since_fault_s"] <= 1.0
    k0 = fault.start
    to_rest = np.linalg.norm(r["probe"][-1, :2] - r["probe"][k0, :2])
    assert to_rest <= 2.0  # travel from the fault until the probe is at rest
    assert np.ptp(r["probe"][ev["frame"] + 25:, 0]) < 1e-3  # at rest after the stop


def test_nominal_ye_runs_trip_no_watchdog():
    for filt in ("pv", "prv"):
        for seed in range(3):
            r = run_ye(filt, "dynamic", n_samples=1500, seed=seed, adaptive=True)
            assert not r["stopped"] and not r["stale"].any()
            assert r["K_e"].max() <= 1.5


def test_dynamic_gain_is_bounded():
    g = SpeedGain("dynamic", max_gain=1.5)
    values = [g.update(True) for _ in range(2000)]  # eq. (13) alone: 1.01**2000 = 4e8
    assert max(values) == 1.5 and values[10] == pytest.approx(1.01**11)


def test_a_repeated_image_is_no_measurement():
    """image_measurement: a frame identical to the one before is stale (the feed froze),
    without running the detector on it."""
    class World:
        grid = None

        def __init__(self):
            self.images = [np.full((8, 8), 50, np.uint8), np.full((8, 8), 50, np.uint8),
                           np.full((8, 8), 51, np.uint8)]

        def image(self, k, probe_xyz):
            return self.images[k]

    class Detector:
        calls = 0
        last = {"shaft_seen": False}

        def detect(self, image, grid):
            Detector.calls += 1
            return True, np.array([0.5, 10.0]), 1.0

    measure = image_measurement(World(), Detector())
    out = [measure(k, np.zeros(3)) for k in range(3)]
    assert [m.stale for m in out] == [False, True, False]
    assert [m.detected for m in out] == [True, False, True] and Detector.calls == 2
    assert isinstance(out[1], Measurement)


CFG = ChatelainConfig(size=32, spacing_mm=0.6, depth_start_mm=12.0, volume_rate_hz=5.0,
                      insertion_speed_mm_s=4.0, rest_s=1.0, settle_s=0.6,
                      scatterers_per_cell=4.0)  # small and fast; the classical tracker holds


@pytest.fixture(scope="module")
def nominal():
    return run_chatelain("misalignment", "classical", seed=1, config=CFG)


@pytest.mark.parametrize("kind", ["frozen-feed", "stuck-detector", "needle-lost"])
def test_chatelain_loop_stops_on_each_fault(nominal, kind):
    first = int(np.argmax(nominal["tracking"]))
    assert nominal["tracking"][first] and not nominal["stopped"]
    fault = Fault(kind, first + 3)  # while it tracks
    r = run_chatelain("misalignment", "classical", seed=1, config=CFG, fault=fault)
    ev = _stop(r)
    assert ev["reason"] == REASONS[kind] and ev["fault"] == kind
    assert 0.0 < ev["since_fault_s"] <= 1.0
    assert np.linalg.norm(r["probe"][-1] - r["probe"][fault.start]) <= 2.0
    assert np.all(r["v_c"][ev["cycle"]:] == 0.0)


def test_chatelain_never_found_needle_moves_nothing():
    r = run_chatelain("misalignment", "classical", seed=1, config=CFG,
                      fault=Fault("never-found"))
    assert not r["tracking"].any()
    assert np.allclose(r["probe"], r["probe"][0]) and np.all(r["v_c"] == 0.0)


def test_rows_record_each_stop_with_its_cause():
    from needlenet.servo import servo_rows

    for kind, reason in REASONS.items():
        rows = servo_rows("servo", filters=("prv",), gains=("dynamic",), features=("ideal",),
                          repeats=2, quick=True, fault=kind)
        assert rows[0]["safety_stops"] == 2
        assert [s["reason"] for s in rows[0]["stops"]] == [reason, reason]
        assert all(0.0 <= s["since_fault_s"] <= 1.0 and s["travel_since_fault_mm"] <= 2.0
                   for s in rows[0]["stops"])
    with pytest.raises(ValueError, match="unknown fault 'melted'"):
        servo_rows("servo", features=("ideal",), repeats=1, quick=True, fault="melted")


@pytest.mark.parametrize("kind", sorted(REASONS))
def test_cli_prints_each_stop_and_exits_with_its_code(kind, tmp_path, capsys):
    import json

    from needlenet.cli import main
    from needlenet.cli._servo import FAULT_NAMES, STOP_EXIT_CODES
    from needlenet.servo import FAULTS

    assert FAULT_NAMES == FAULTS
    out = tmp_path / "s.json"
    rc = main(["servo", "servo", "--repeat", "1", "--quick", "--filter", "prv", "--gain",
               "dynamic", "--fault", kind, "--json", str(out), "--quiet"])
    assert rc == STOP_EXIT_CODES[REASONS[kind]]
    err = capsys.readouterr().err
    assert f"needlenet: safety stop: {REASONS[kind]} (ideal dynamic-prv, seed 0)" in err
    assert f"after the {kind} fault" in err
    stop = json.loads(out.read_text())["rows"][0]["stops"][0]
    assert stop["reason"] == REASONS[kind] and stop["since_fault_s"] <= 1.0


def test_cli_nominal_run_exits_0(capsys):
    from needlenet.cli import main

    assert main(["servo", "servo", "--repeat", "1", "--quick", "--filter", "prv", "--gain",
                 "dynamic", "--quiet"]) == 0
    assert "safety stop" not in capsys.readouterr().err
