"""Tests of the volume trackers' parameters (groups, the names users set, their checks), of
``VolumeTracker`` making each method's tracker, and of the trackers' named state layouts."""

import math
from dataclasses import fields, is_dataclass, replace

import numpy as np
import pytest

from needlenet.backends import chatelain_control_points_model, zhao_model
from needlenet.features import Frame
from needlenet.trackers import make_tracker, tracker_class, tracker_params
from needlenet.trackers.volume import (
    ChatelainParams,
    ChatelainTracker,
    LearnedPlacementParams,
    MeasurementParams,
    RansacTracker,
    RoiRkParams,
    RoiRkTracker,
    VolumeTracker,
    VolumeTrackerParams,
    roi_rk,
)
from needlenet.trackers.volume.chatelain import ControlPoints
from synth import Grid

# Every name VolumeTrackerParams took before its fields were grouped, and every field added
# since: each sets and reads its field (``--param NAME=VALUE``,
# ``VolumeTrackerParams(NAME=...)``, ``p.NAME``).
FLAT_NAMES = (
    "threshold_percentile intensity_threshold percentile_stride inlier_radius_mm "
    "min_sample_distance_mm max_trials init_max_trials init_attempts init_min_likelihood "
    "init_min_contrast init_max_sheet init_tip_margin_mm entry_margin_mm "
    "success_probability batch_size refine_iterations min_inliers min_length_mm max_gap_mm "
    "profile_radius_mm tip_cap_mm likelihood_threshold likelihood_floor likelihood_relative "
    "max_candidates tip_window_mm tip_min init_select init_select_ratio image_refine "
    "image_refine_radii_mm image_refine_percentile image_refine_keep_depth image_tip_radius_mm "
    "image_tip_window_mm image_tip_search_mm image_tip_track_search_mm image_tip_cap_mm "
    "image_tip_min_effect image_tip_background_mm roi_radius_mm max_axis_jump_deg "
    "max_axis_shift_mm frangi speckle_kernel_mm speckle_search_mm q_angle q_tip r_angle "
    "r_position r_velocity p0_angle_rate p0_velocity rival_check_volumes rival_advance_mm "
    "prove_within_s "
    "insertion insertion_candidates_mm3 "
    "n_control_points voi_radius_mm voi_margin_mm voi_candidates_mm3 init_voi_radius_mm "
    "max_angle_deg detection_window start_length_mm start_min_likelihood start_tip_margin_mm "
    "start_min_contrast start_max_sheet q_control r_control p0_control_velocity "
    "max_coast_volumes default_dt_s"
).split()
GROUPS = {"measurement": MeasurementParams, "placement": LearnedPlacementParams,
          "roi_rk": RoiRkParams, "chatelain": ChatelainParams}


def _text(value) -> str:
    """A default as ``--param`` text."""
    if isinstance(value, tuple):
        return ",".join(repr(v) for v in value)
    if value is None or isinstance(value, (bool, str)):
        return str(value).lower()
    return repr(value)


def test_every_old_name_belongs_to_one_group_and_still_sets_and_reads_its_field():
    assert len(FLAT_NAMES) == 75
    owners = {f.name: g for g, cls in GROUPS.items() for f in fields(cls)}
    assert sorted([*owners, "default_dt_s"]) == sorted(FLAT_NAMES)
    assert [f.name for f in fields(VolumeTrackerParams)] == [*GROUPS, "default_dt_s"]
    base = VolumeTrackerParams()
    for name, group in owners.items():
        default = getattr(getattr(base, group), name)
        assert getattr(base, name) == default
        if isinstance(default, bool):
            changed = not default
        elif isinstance(default, (int, float)) and default is not None:
            changed = type(default)(default + 1)
        else:
            continue
        if name in ("threshold_percentile", "success_probability", "likelihood_threshold",
                    "n_control_points", "likelihood_floor"):
            continue  # bounded fields: +1 leaves their range
        p = VolumeTrackerParams(**{name: changed})
        assert getattr(getattr(p, group), name) == changed and getattr(p, name) == changed
        # only that field changed
        assert replace(p, **{name: default}) == base
    with pytest.raises(AttributeError):
        _ = base.no_such_field


def test_groups_and_their_fields_combine():
    p = VolumeTrackerParams(measurement=MeasurementParams(max_trials=9), batch_size=4,
                            n_control_points=3)
    assert p.measurement == MeasurementParams(max_trials=9, batch_size=4)
    assert p.chatelain.n_control_points == 3 and p.roi_rk == RoiRkParams()
    q = replace(p, image_tip_min_effect=2.5)
    assert q.placement.image_tip_min_effect == 2.5 and q.max_trials == 9
    assert q == VolumeTrackerParams(q.measurement, q.placement, q.roi_rk, q.chatelain)
    assert hash(q) == hash(replace(q))
    with pytest.raises(TypeError, match="max_trails"):
        VolumeTrackerParams(max_trails=3)
    with pytest.raises(ValueError, match="measurement must be a MeasurementParams"):
        VolumeTrackerParams(measurement=RoiRkParams())
    with pytest.raises(ValueError, match="default_dt_s"):
        VolumeTrackerParams(default_dt_s=0.0)


def test_tracker_params_read_old_and_grouped_names():
    base = VolumeTrackerParams()
    for name in FLAT_NAMES:
        value = getattr(base, name)
        if not is_dataclass(value):  # every field's default, given as text, is the default
            assert tracker_params("volume", [f"{name}={_text(value)}"]) == base, name
    p = tracker_params("volume", ["measurement.max_trials=7", "max_candidates=300",
                                  "chatelain.insertion.variance_threshold_mm2=90",
                                  "insertion.n_candidates=50", "roi_rk.frangi.alpha=0.3",
                                  "frangi.beta=0.4", "placement.image_refine=false"])
    assert p == VolumeTrackerParams(
        max_trials=7, max_candidates=300, image_refine=False,
        insertion=replace(base.insertion, variance_threshold_mm2=90.0, n_candidates=50),
        frangi=replace(base.frangi, alpha=0.3, beta=0.4))
    for setting, msg in [
        ("measurement.max_trails=1", "unknown MeasurementParams parameter 'max_trails' of "
                                     "measurement"),
        ("chatelain.insertion.tau=1", "unknown InsertionParams parameter 'tau' of "
                                      "chatelain.insertion"),
        ("chatelain.n_control_points.x=1", "parameter chatelain.n_control_points has no "
                                           "fields"),
        ("roi_rk=1", "set its fields instead (roi_rk.FIELD=VALUE)"),
        ("roi_rk.frangi=1", "set its fields instead (roi_rk.frangi.FIELD=VALUE)"),
        ("chatelain.n_control_points=4", "n_control_points must be 2 or 3"),
    ]:
        with pytest.raises(ValueError) as exc:
            tracker_params("volume", [setting])
        assert msg in str(exc.value), str(exc.value)


def test_volume_tracker_makes_each_methods_tracker():
    assert tracker_class("volume") is VolumeTracker
    assert VolumeTracker.methods == ("ransac", "roi-rk", "chatelain")
    for method, cls in (("ransac", RansacTracker), ("roi-rk", RoiRkTracker),
                        ("chatelain", ChatelainTracker)):
        for tracker in (VolumeTracker(method, rng=0), make_tracker("volume", method),
                        cls(method)):
            assert type(tracker) is cls and isinstance(tracker, VolumeTracker)
            assert tracker.method == method and tracker.modality == "volume"
    with pytest.raises(ValueError, match="unknown method"):
        RansacTracker("roi-rk")


def test_state_layouts_are_the_papers_states():
    # Zhao's H = [[I_2, 0], [0, I_6]] measures the angles, the tip and its velocity; F moves
    # the angles by their rates and the tip by its velocity
    dt = 0.2
    model = zhao_model(dt)
    assert roi_rk.STATE_SIZE == model.F.shape[0]
    z = np.arange(8.0)
    x = model.H.T @ z
    np.testing.assert_array_equal(
        np.r_[x[roi_rk.ANGLES], x[roi_rk.TIP], x[roi_rk.TIP_VELOCITY]], z)
    np.testing.assert_array_equal(model.F[roi_rk.ANGLES, roi_rk.ANGLE_RATES], dt * np.eye(2))
    np.testing.assert_array_equal(model.F[roi_rk.TIP, roi_rk.TIP_VELOCITY], dt * np.eye(3))
    # Chatelain's C = [I_3n 0] measures the control points; the tip is the last of them
    for n in (2, 3):
        layout = ControlPoints(n)
        model = chatelain_control_points_model(n, 3, dt=dt, q=1.0, r=1.0)
        assert layout.size == model.F.shape[0]
        np.testing.assert_array_equal(model.H[:, layout.positions], np.eye(3 * n))
        np.testing.assert_array_equal(model.F[layout.positions, layout.velocities],
                                      dt * np.eye(3 * n))
        assert list(range(layout.size)[layout.tip]) == list(range(3 * n - 3, 3 * n))


def test_params_and_method_are_checked():
    with pytest.raises(ValueError, match="unknown method"):
        VolumeTracker("hough")
    with pytest.raises(ValueError, match="max_trials"):
        VolumeTrackerParams(max_trials=0)
    with pytest.raises(ValueError, match="n_control_points"):
        VolumeTrackerParams(n_control_points=4)
    with pytest.raises(ValueError, match="roi_radius_mm"):
        VolumeTrackerParams(roi_radius_mm=-1.0)
    with pytest.raises(ValueError, match="threshold_percentile"):
        VolumeTrackerParams(threshold_percentile=100.0)
    tracker = VolumeTracker("ransac")
    with pytest.raises(ValueError, match="3D volumes"):
        tracker.update(Frame(np.arange(16, dtype=np.uint8).reshape(4, 4),
                             Grid((4, 4), (1.0, 1.0), (0.0, 0.0))))


def test_image_refinement_params_are_checked():
    with pytest.raises(ValueError, match="image_refine_radii_mm"):
        VolumeTrackerParams(image_refine_radii_mm=(1.5, -1.0))
    with pytest.raises(ValueError, match="image_refine_radii_mm"):
        VolumeTrackerParams(image_refine_radii_mm=[1.5])
    with pytest.raises(ValueError, match="image_refine_percentile"):
        VolumeTrackerParams(image_refine_percentile=100.0)
    with pytest.raises(ValueError, match="image_tip_window_mm"):
        VolumeTrackerParams(image_tip_window_mm=0.0)
    with pytest.raises(ValueError, match="image_tip_cap_mm"):
        VolumeTrackerParams(image_tip_cap_mm=-0.1)
    for ring in ((3.0, 2.0), (0.0, 2.0), (2.0,), [2.0, 3.0], (2.0, math.inf)):
        with pytest.raises(ValueError, match="image_tip_background_mm"):
            VolumeTrackerParams(image_tip_background_mm=ring)
