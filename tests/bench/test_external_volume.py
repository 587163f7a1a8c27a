"""The external volume sets (PyMUST swept volumes) and ``needlenet bench external`` on them."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest

import synth
from needlenet.bench import _external as ext
from needlenet.bench._external_volume import (
    markdown_volume_set,
    run_volume_set,
    volume_data_dir,
    zhao_failures,
)
from needlenet.bench.external.volume_specs import (
    VOLUME_PROBES,
    VOLUME_SPECS,
    VOLUME_VALIDATION_SPECS,
    VolumeProbe,
    VolumeSpec,
    needle_direction,
)
from needlenet.trackers import NeedleEstimate, Status

SETS = {"validation_volume": VOLUME_VALIDATION_SPECS, "external_volume": VOLUME_SPECS}


def _present(name):
    return any(volume_data_dir(name == "validation_volume").glob("*.npz"))


@pytest.fixture(scope="module", params=[n for n in SETS if _present(n)])
def committed(request):
    name = request.param
    folder = volume_data_dir(name == "validation_volume")
    return name, folder, ext.external_sequences(folder)


# -- the metrics, on hand-made volumes and estimates --------------------------------------

def _labelled(tips, visible, entry=(0.0, 0.0, 10.0)):
    """A volume sequence of len(tips) blank volumes with these labels (direction +x)."""
    T = len(tips)
    return synth.Sequence(
        images=np.zeros((T, 2, 2, 2), np.uint8), spacing_mm=np.full(3, 0.5),
        origin_mm=np.zeros(3), modality="volume", timestamps_s=np.arange(T) * 0.5,
        dynamic_range_db=50.0, meta={"needle": True}, tip_mm=np.asarray(tips, float),
        entry_mm=np.repeat(np.asarray(entry, float)[None], T, 0),
        direction=np.repeat(np.array([[1.0, 0.0, 0.0]]), T, 0),
        visible=np.asarray(visible, bool))


def _est(status, tip=None, direction=(1.0, 0.0, 0.0), axis_point=None):
    if tip is None:
        return NeedleEstimate(t=0.0, status=Status(status))
    return NeedleEstimate(t=0.0, status=Status(status), tip_mm=np.asarray(tip, float),
                          direction=np.asarray(direction, float),
                          axis_point_mm=None if axis_point is None else np.asarray(axis_point,
                                                                                   float))


def test_volume_tip_errors_are_three_dimensional():
    # tips at x = 10..14 on the axis y = 0, z = 10; the estimates miss by (3, 4, 12) = 13 mm,
    # (0, 0, 1) = 1 mm and (1, 2, 2) = 3 mm (a 2-D error would drop y); volume 3 is not
    # tracked and volume 4 lies outside the volume (not visible): neither counts
    tips = [[10 + i, 0.0, 10.0] for i in range(5)]
    seq = _labelled(tips, [True, True, True, True, False])
    est = [_est("tracking", [13.0, 4.0, 22.0]), _est("tracking", [11.0, 0.0, 11.0]),
           _est("tracking", [13.0, 2.0, 12.0]), _est("lost"), _est("tracking", tips[4])]
    tracking, tip_est, m = ext.estimate_metrics(est, seq)
    assert tip_est.shape == (5, 3) and np.isnan(tip_est[3]).all()
    assert m["tip_errors_mm"] == pytest.approx([13.0, 1.0, 3.0])
    assert m["tip_error_median_mm"] == pytest.approx(3.0)
    assert m["tip_error_p95_mm"] == pytest.approx(3.0 + 0.9 * 10.0)  # numpy's linear rule
    assert m["needle_frames"] == 4 and m["tracked_fraction"] == pytest.approx(3 / 4)
    # 1 and 3 mm lie within 3 mm; no needle-free volume, so nothing is subtracted
    assert m["within_3mm_frames"] == 2 and m["score"] == pytest.approx(2 / 4)
    assert m["false_tracking_fraction"] is None


def test_zhao_failures_count_the_axis_as_well_as_the_tip():
    # the needle runs from the entry (0, 0, 10) to the tip (20, 0, 10) along +x
    tip = [20.0, 0.0, 10.0]
    seq = _labelled([tip] * 4, [True] * 4)
    tilted = np.array([20.0, 0.0, 4.0]) / np.hypot(20.0, 4.0)  # through the tip, 4 mm off at 0
    est = [_est("tracking", [22.9, 0.0, 10.0], axis_point=[2.9, 0.0, 10.0]),  # tip 2.9: passes
           _est("tracking", [20.5, 0.0, 10.0], tilted, axis_point=tip),  # axis 4 mm off: fails
           _est("tracking", [20.0, 0.0, 13.5], axis_point=[0.0, 0.0, 13.5]),  # tip 3.5: fails
           _est("searching")]  # no estimate: fails
    assert zhao_failures(est, seq) == (3, 4)
    free = synth.Sequence(**{**seq.as_dict(), "tip_mm": None, "entry_mm": None,
                             "direction": None, "meta": {"needle": False}})
    assert zhao_failures([_est("tracking", tip)] * 4, free) == (0, 0)


def test_a_needle_free_volume_reported_tracking_is_false_tracking():
    free = synth.Sequence(images=np.zeros((3, 2, 2, 2), np.uint8), spacing_mm=np.full(3, 0.5),
                          origin_mm=np.zeros(3), modality="volume",
                          timestamps_s=np.arange(3.0), dynamic_range_db=50.0,
                          meta={"needle": False}, visible=np.zeros(3, bool))
    est = [_est("tracking", [1.0, 1.0, 1.0]), _est("searching"), _est("lost")]
    _, tip_est, m = ext.estimate_metrics(est, free)
    assert tip_est.shape == (3, 3)
    assert m["needle_frames"] == 0 and m["needle_free_frames"] == 3
    assert m["false_tracking_fraction"] == pytest.approx(1 / 3)
    assert m["score"] == pytest.approx(-1 / 3) and m["tip_error_median_mm"] is None


def test_the_markdown_table_has_a_row_per_sequence_and_features():
    rows = [{"sequence": "a", "probe": "P4-2v", "needle": True, "gauge": 18, "target_cr": 2.5,
             "features": "classical", "method": "roi-rk", "tip_error_median_mm": 1.234,
             "tip_error_p95_mm": 2.5, "tracked_fraction": 0.5,
             "false_tracking_fraction": None, "score": 0.5, "failure_rate": 0.25},
            {"sequence": "pooled", "probe": None, "needle": None, "gauge": None,
             "target_cr": None, "features": "classical", "method": "roi-rk",
             "tip_error_median_mm": None, "tip_error_p95_mm": None, "tracked_fraction": None,
             "false_tracking_fraction": 0.0, "score": -0.0, "failure_rate": None}]
    md = ext.markdown({"rows": [{**r, "tracker": "volume"} for r in rows]},
                      {"cpu": "x", "cores": 2})
    assert "| a | P4-2v | 18 G, CR 2.5 | classical | 1.23 | 2.50 | 50% | - | 0.500 | 25% |" in md
    assert "| **pooled** | - | - | classical | - | - | - | 0% | -0.000 | - |" in md
    assert md == markdown_volume_set({"rows": [{**r, "tracker": "volume"} for r in rows]},
                                     {"cpu": "x", "cores": 2})


# -- the committed sets -------------------------------------------------------------------

def test_a_committed_set_holds_its_specs_files_and_readme(committed):
    name, folder, seqs = committed
    specs = {s.name: s for s in SETS[name]}
    assert [n for n, _ in seqs] == sorted(specs)
    readme = (folder / "README.md").read_text()
    listed = set(re.findall(r"`([\w.]+\.npz)`", readme))
    assert listed == {f"{n}.npz" for n, _ in seqs}
    for n, seq in seqs:
        spec, vp = specs[n], VOLUME_PROBES[specs[n].probe]
        assert seq.modality == "volume" and seq.meta["source"] == "pymust"
        assert seq.meta["seed"] == spec.seed and seq.meta["probe"] == spec.probe
        assert seq.images.shape == (spec.n_volumes, *vp.shape)
        np.testing.assert_allclose(seq.spacing_mm, 0.5)
        np.testing.assert_allclose(seq.origin_mm, vp.origin_mm)
        np.testing.assert_allclose(np.diff(seq.timestamps_s), 1 / spec.volume_rate_hz)
        assert np.array_equal(seq.probe_pose, np.repeat(np.eye(4)[None], spec.n_volumes, 0))


def test_committed_labels_follow_the_specs(committed):
    _, _, seqs = committed
    specs = {s.name: s for s in VOLUME_SPECS + VOLUME_VALIDATION_SPECS}
    for n, seq in seqs:
        spec = specs[n]
        needle, free = ext.frame_classes(seq)
        if not spec.needle:
            assert free.all() and seq.tip_mm is None and not seq.visible.any(), n
            continue
        assert needle.all() and seq.visible.all(), n
        u = needle_direction(spec.alpha_deg, spec.beta_deg)
        np.testing.assert_allclose(seq.direction, np.broadcast_to(u, seq.direction.shape),
                                   atol=1e-12)
        np.testing.assert_allclose(seq.tip_mm[-1], spec.tip_mm, atol=1e-9)
        # the tip advances step_mm per volume along the shaft
        np.testing.assert_allclose(np.diff(seq.tip_mm, axis=0),
                                   np.repeat(spec.step_mm * u[None], seq.n_frames - 1, 0),
                                   atol=1e-9)
        # the centreline runs from the entry to the tip, along the shaft
        c = seq.centerline_mm
        np.testing.assert_allclose(c[:, 0], seq.entry_mm, atol=1e-9)
        np.testing.assert_allclose(c[:, -1], seq.tip_mm, atol=1e-9)
        d = np.diff(c, axis=1)
        np.testing.assert_allclose(d / np.linalg.norm(d, axis=2, keepdims=True),
                                   np.broadcast_to(u, d.shape), atol=1e-9)


def _tube_mean(seq, t, pts, radius):
    grid = seq.grid()
    idx = synth.tube_indices(grid, pts, radius)
    return float(seq.images[t].reshape(-1)[idx].mean())


def test_the_needle_is_where_the_labels_put_it(committed):
    # the voxels within a radius and a voxel of the labelled axis are bright, those of the
    # axis mirrored in y (an elevation flip of the labels) and the imaged tissue are not
    _, _, seqs = committed
    for n, seq in seqs:
        if not seq.meta["needle"]:
            continue
        r = seq.meta["needle_radius_mm"] + 0.5
        shown = seq.images[-1][seq.images[-1] > 0].mean()
        for t in range(seq.n_frames):
            c = seq.centerline_mm[t]
            mirror = c * np.array([1.0, -1.0, 1.0])
            on = _tube_mean(seq, t, c, r)
            assert on > 1.4 * shown, (n, t, on, shown)
            assert on > 1.3 * _tube_mean(seq, t, mirror, r), (n, t)


def test_the_volume_sets_are_apart_from_each_other_and_from_the_other_sets():
    from needlenet.bench.external.axial_specs import AXIAL_SPECS, AXIAL_VALIDATION_SPECS
    from needlenet.bench.external.specs import SPECS, VALIDATION_SPECS

    val, test = VOLUME_VALIDATION_SPECS, VOLUME_SPECS
    assert not {s.name for s in val} & {s.name for s in test}
    others = SPECS + VALIDATION_SPECS + AXIAL_SPECS + AXIAL_VALIDATION_SPECS
    seeds = [s.seed for s in val + test]
    assert len(set(seeds)) == len(seeds) and not set(seeds) & {s.seed for s in others}
    for specs in (val, test):  # both probes, needle-free sequences, an interface
        assert {s.probe for s in specs} == {"L11-5v", "P4-2v"}
        assert sum(not s.needle for s in specs) >= 1
        assert any(s.needle and s.interface is not None for s in specs)
        for s in specs:  # oblique needles: neither level nor along an axis
            if s.needle:
                assert abs(np.sin(np.deg2rad(2 * s.alpha_deg))) > 0.3, s.name
                assert 50 <= s.beta_deg < 85 and 2.0 <= s.step_mm <= 4.0, s.name
                assert 17 <= s.gauge <= 21, s.name
    assert min(s.target_cr for s in test if s.needle) <= 2.0
    assert any(s.needle and s.vessel is not None for s in test)


def test_a_model_of_another_modality_is_refused_for_a_volume_set(tmp_path, capsys):
    from importlib import resources

    from needlenet.cli import main

    seq = _labelled([[0.0, 0.0, 20.0]] * 2, [True, True])
    synth.save_sequence(seq, tmp_path / "x.npz")
    model = str(resources.files("needlenet").joinpath("models", "inplane.onnx"))
    assert main(["bench", "external", "--data", str(tmp_path), "--model", model]) == 2
    assert "is a 'inplane' model, not 'volume'" in capsys.readouterr().err


def test_the_bench_runs_a_volume_set_through_the_default_tracker(committed):
    # two volumes of each sequence (a needle one and the needle-free one), both features
    _, _, seqs = committed
    short = []
    for n, s in seqs:
        keep = {k: v[:2] for k, v in s.as_dict().items()
                if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == s.n_frames}
        short.append((n, synth.Sequence(**{**s.as_dict(), **keep})))
    pick = [next(x for x in short if x[1].meta["needle"]),
            next(x for x in short if not x[1].meta["needle"])]
    rows = []
    out = run_volume_set(pick, 0, lambda m: None, rows, None, ["classical", "learned"])
    kinds = {r["features"] for r in rows}
    assert "classical" in kinds
    for kind in kinds:
        mine = [r for r in rows if r["features"] == kind]
        assert [r["sequence"] for r in mine] == [pick[0][0], pick[1][0], "pooled"]
        assert all(r["tracker"] == "volume" and r["method"] == "roi-rk" for r in mine)
        pooled = mine[-1]
        assert (pooled["needle_frames"], pooled["needle_free_frames"]) == (2, 2)
        assert mine[1]["failure_rate"] is None and mine[0]["failure_rate"] is not None
    assert set(out["traces"]) == {(n, k) for n, _ in pick for k in kinds}


# -- the generator (PyMUST) ----------------------------------------------------------------

def _tiny(tmp_path, name):
    """Three 11 x 4 x 11 P4-2v volumes of a narrow sector with a sparse cloud (seconds)."""
    pytest.importorskip("pymust")
    from needlenet.bench.external.volume_generate import generate_volume

    base = VOLUME_PROBES["P4-2v"]
    vp = VolumeProbe(replace(base.setup, tilts_deg=(0.0,), scatterers_per_cell=0.3,
                             sector_half_angle_deg=10.0), x_mm=(-2.5, 2.5), z_mm=(19.5, 24.5),
                     n_slices=4, elevation_aperture_mm=14.0, elevation_focus_mm=30.0,
                     fine_factor=2, band_mm=8.0)
    spec = VolumeSpec(name, "P4-2v", 7, tip_mm=(0.5, 0.4, 22.0), alpha_deg=20.0,
                      beta_deg=70.0, step_mm=1.0, n_volumes=3, gauge=16, target_cr=2.5)
    out = generate_volume(spec, tmp_path, log=lambda m: None, vp=vp, cell_mm2=0.3)
    return synth.load_sequence(out), spec, vp


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return _tiny(tmp_path_factory.mktemp("v"), "tiny")


def test_the_generator_is_deterministic_per_seed(tiny, tmp_path):
    again, _, _ = _tiny(tmp_path, "tiny")
    assert np.array_equal(tiny[0].images, again.images)
    assert np.array_equal(tiny[0].tip_mm, again.tip_mm)


def test_a_tiny_volume_follows_the_contract(tiny):
    seq, spec, vp = tiny
    assert seq.modality == "volume" and seq.images.shape == (3, 11, 4, 11)
    np.testing.assert_allclose(seq.origin_mm, [19.5, -0.75, -2.5])
    u = needle_direction(20.0, 70.0)
    np.testing.assert_allclose(seq.tip_mm[0], np.array(spec.tip_mm) - 2.0 * u, atol=1e-12)
    assert seq.visible.all() and np.isfinite(seq.contrast_ratio).all()
    # the entry lies where the axis crosses the volume's face x = -2.75 (half a voxel out)
    assert seq.entry_mm[0, 0] == pytest.approx(-2.75, abs=0.02)
    # outside the 10-degree sector (a voxel's margin) the volume is black, inside it is not
    x, z = seq.grid().axis_coords(2), seq.grid().axis_coords(0)
    angle = np.abs(np.arctan2(x[None], z[:, None]))
    by_y = seq.images.transpose(0, 2, 1, 3)  # (T, Y, Z, X)
    assert not by_y[..., angle > np.deg2rad(11.5)].any()
    assert by_y[..., angle < np.deg2rad(8.5)].min() > 0
