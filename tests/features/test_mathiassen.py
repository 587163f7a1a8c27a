"""Tests of Mathiassen 2017's axis search and tip features (needlenet/features/_mathiassen.py)
and of the shipped weight file."""

import json

import numpy as np
import pytest

from needlenet.features._mathiassen import (
    AxisEstimate,
    MathiassenParams,
    axis_search_step,
    axis_vectors,
    estimate_axis,
    kernel_gpp,
    kernel_sq,
    load_tip_weights,
    ray_positions_mm,
    ray_profiles,
    ray_scores,
    region_difference,
    roi_anchor_mm,
    tip_features,
    tip_likelihood,
    tip_map_along_axis,
    weights_path,
)
from synth import Grid

GRID = Grid((300, 384), (0.1, 0.1), (0.0, -19.2))


def _needle_image(theta_deg, tip_along_mm, offset_mm, grid=GRID, noise=0.05, seed=0,
                  width_mm=0.15):
    """A clean needle: a bright line of Gaussian profile on the axis {A + offset v_p + x v_n},
    from the ROI corner to ``tip_along_mm``, over seeded Gaussian noise."""
    anchor = roi_anchor_mm(grid, MathiassenParams())
    vn, vp = axis_vectors(theta_deg)
    zz, xx = np.meshgrid(*(grid.axis_coords(a) for a in range(2)), indexing="ij")
    rel = np.stack([xx - anchor[0], zz - anchor[1]], axis=-1)
    along, across = rel @ vn, rel @ vp - offset_mm
    line = np.exp(-0.5 * (across / width_mm) ** 2) * (along <= tip_along_mm)
    rng = np.random.default_rng(seed)
    return (0.2 + 0.6 * line + noise * rng.standard_normal(grid.shape)).astype(np.float32)


# ----------------------------------------------------------------- the ray score, eqs. (1)-(5)


def _scores_by_the_equations(R, w_max):
    """Eqs. (2)-(5) written as Algorithm 1's loops."""
    n = len(R)
    R_delta = np.array([R[y + 1] - R[y] for y in range(n - 1)])  # eq. (2)
    out = []
    for y in range(w_max + 1, n - w_max - 1):
        s_lead = sum(R_delta[y + w] for w in range(w_max + 1))  # eq. (4)
        s_lag = sum(R_delta[y - w - 1] for w in range(w_max + 1))  # eq. (5)
        out.append(s_lag - s_lead - abs(s_lag + s_lead))  # eq. (3)
    return np.array(out)


def test_ray_score_hand_values():
    # one bright sample: S = 2 at the line, -2 beside it (lag 0, lead 1: 0 - 1 - |1|)
    R = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(ray_scores(R, 0), [0.0, -2.0, 2.0, -2.0, 0.0])
    # a line of height 3 on a ramp: S = 2 min(R(y) - R(y-W), R(y) - R(y+W)) = 2 min(4, 2)
    R = np.array([0.0, 1.0, 2.0, 6.0, 4.0, 5.0, 6.0])
    assert ray_scores(R, 0)[2] == pytest.approx(4.0)


def test_ray_score_matches_the_loops_of_algorithm_1():
    R = np.random.default_rng(3).normal(size=40)
    for w_max in (0, 2, 5):
        np.testing.assert_allclose(ray_scores(R, w_max), _scores_by_the_equations(R, w_max),
                                   atol=1e-12)


def test_ray_score_is_not_positive_on_an_edge():
    R = np.r_[np.zeros(20), np.ones(20)]  # a step: an edge, not a line
    assert np.all(ray_scores(R, 4) <= 0.0)


def test_ray_score_rejects_short_rays():
    with pytest.raises(ValueError, match="too short"):
        ray_scores(np.zeros(5), 2)


def test_ray_profile_is_the_mean_along_the_needle():
    # on a linear image the mean of samples placed symmetrically about a point is its value
    rows, cols = np.mgrid[0:GRID.shape[0], 0:GRID.shape[1]]
    image = (0.01 * cols + 0.02 * rows).astype(np.float32)
    p = MathiassenParams()
    anchor = roi_anchor_mm(GRID, p)
    rays = np.array([3.0, 8.0])
    R = ray_profiles(image, GRID, anchor, [40.0], rays, p)
    W = 6  # w_max = 5 samples of 0.1 mm
    y = 0.1 * (np.arange(R.shape[-1]) - W)
    vn, vp = axis_vectors(40.0)
    pts = anchor + rays[:, None, None] * vn + y[None, :, None] * vp
    idx = GRID.points_to_index(pts)
    expected = 0.01 * idx[..., 1] + 0.02 * idx[..., 0]
    inside = GRID.contains(pts - 0.9 * vn) & GRID.contains(pts + 0.9 * vn)  # no border pixels
    assert inside.sum() > 150
    np.testing.assert_allclose(R[0][inside], expected[inside], atol=2e-3)


# ----------------------------------------------------------------- Algorithms 1 and 2


def test_ray_positions_follow_section_iii_b():
    p = MathiassenParams()
    rays = ray_positions_mm(40.0, p, feedback=False)  # 12 rays over the ROI
    assert len(rays) == 12 and rays[0] == pytest.approx(0.9)
    np.testing.assert_allclose(np.diff(rays), (40.0 - 0.9) / 12)
    rays = ray_positions_mm(10.0, p, feedback=True)  # 9.1 mm / 20 px -> 5 rays
    assert len(rays) == 5
    np.testing.assert_allclose(np.diff(rays), 9.1 / 5)
    assert len(ray_positions_mm(2.0, p, feedback=True)) == 3  # at least 3 rays
    rays = ray_positions_mm(100.0, p, feedback=True)  # 12 rays at most 45 px apart
    assert len(rays) == 12
    np.testing.assert_allclose(np.diff(rays), 4.5)


def test_axis_search_recovers_a_line_to_a_fifth_of_a_degree():
    theta, offset = 38.4, 2.0
    image = _needle_image(theta, 25.0, offset)
    coarse_only = MathiassenParams(fine_half_range_deg=0.0)
    est = estimate_axis(image, GRID, coarse_only, theta_centre_deg=36.0, tip_along_mm=25.0)
    assert est.theta_deg == pytest.approx(38.0)  # the 1-degree step alone
    est = estimate_axis(image, GRID, theta_centre_deg=36.0, tip_along_mm=25.0)
    assert abs(est.theta_deg - theta) <= 0.2  # then the 0.1-degree step
    assert est.p_p_mm == pytest.approx(offset, abs=0.1)
    # without feedback the 12 rays span the image; the line still wins
    est = estimate_axis(image, GRID, theta_centre_deg=36.0)
    assert abs(est.theta_deg - theta) <= 0.5


def test_axis_search_over_the_full_range():
    image = _needle_image(55.0, 25.0, 3.0)
    est = estimate_axis(image, GRID, tip_along_mm=25.0)  # 20-70 degrees
    assert abs(est.theta_deg - 55.0) <= 0.2


def test_axis_search_step_on_a_hand_made_image():
    # theta = 0: the rays run straight down from the ROI corner (top edge, 4 mm from the right)
    # and one bright row 3 mm deep crosses all 12 of them. Each ray scores
    # S = 2 min(1 - 0, 1 - 0) = 2 on the row and 0 on the 5 samples either side (eqs. 3-5), so
    # the smoothed histogram peaks at H_max = 12 x 2 = 24 and every p_k sits on the row.
    image = np.zeros(GRID.shape, np.float32)
    image[30, :] = 1.0
    p = MathiassenParams()
    rays = ray_positions_mm(30.0, p, feedback=False)
    st = axis_search_step(image, GRID, [0.0], rays, p)
    assert st.h_max[0] == pytest.approx(24.0, abs=1e-4)
    np.testing.assert_allclose(st.points_mm[0], 3.0, atol=1e-9)
    np.testing.assert_allclose(st.scores[0], 2.0, atol=1e-5)
    assert st.p_p_mm[0] == pytest.approx(3.0)


def test_axis_search_step_batches_angles():
    image = _needle_image(40.0, 25.0, 2.5)
    p = MathiassenParams()
    rays = ray_positions_mm(25.0, p, feedback=True)
    batch = axis_search_step(image, GRID, [38.0, 40.0, 42.0], rays, p)
    single = axis_search_step(image, GRID, [40.0], rays, p)
    assert batch.h_max[1] == pytest.approx(single.h_max[0], rel=1e-5)
    assert np.argmax(batch.h_max) == 1
    np.testing.assert_allclose(batch.points_mm[1], 2.5, atol=0.1)  # every p_k on the line


def test_rotated_axis_keeps_the_needle_points():
    image = _needle_image(40.0, 25.0, 2.5)
    est = estimate_axis(image, GRID, theta_centre_deg=40.0, tip_along_mm=25.0)
    turned = est.rotated(est.theta_deg + 1.0)
    assert turned.theta_deg == pytest.approx(est.theta_deg + 1.0)
    # the new line passes through the centroid of the points
    vn, vp = axis_vectors(est.theta_deg)
    centroid = (est.points_mm[:, None] * vp + est.rays_mm[:, None] * vn).mean(axis=0)
    assert centroid @ axis_vectors(turned.theta_deg)[1] == pytest.approx(turned.p_p_mm)


# ----------------------------------------------------------------- tip features, eqs. (6)-(10)


def test_kernels_of_eqs_9_and_10():
    k = kernel_sq(40, 21)
    assert k.shape == (21, 40)
    assert k.sum() == pytest.approx(0.0, abs=1e-12)
    col = k[:, 0]
    assert np.all(col[6:15] > 0) and np.all(col[:6] < 0) and np.all(col[15:] < 0)
    g = kernel_gpp(89, 10.0)  # s_y = 89, positive on +-s_n/2 = +-10 px
    y = np.arange(89) - 44
    assert np.all(g[np.abs(y) < 10] > 0) and np.all(g[np.abs(y) > 10] <= 0)
    # eq. (10) up to scale: K(y) / K(0) = -(y^2/100 - 1) exp(-y^2/100)
    np.testing.assert_allclose(g / g[44], -((y / 10.0) ** 2 - 1) * np.exp(-((y / 10.0) ** 2)),
                               atol=1e-12)


def test_region_difference_hand_values():
    f = np.array([1.0, 1, 1, 1, 0, 0, 0, 0])
    E = region_difference(f, 2)  # mean of the 2 samples behind minus the 2 from x on
    np.testing.assert_allclose(E, [0.0, 0.0, 0.0, 0.5, 1.0, 0.5, 0.0, 0.0])


def test_h_peaks_at_the_tip_of_a_clean_needle():
    weights = load_tip_weights().weights
    for theta, tip in [(35.0, 15.0), (42.3, 20.0), (50.0, 12.0)]:
        image = _needle_image(theta, tip, 2.0, seed=int(theta))
        axis = estimate_axis(image, GRID, theta_centre_deg=round(theta))
        feats = tip_features(image, None, GRID, axis)
        assert feats.E.shape == (5, feats.x_mm.size)
        h = tip_likelihood(feats, weights)
        assert abs(feats.x_mm[np.argmax(h)] - tip) <= 0.3
        assert feats.shaft_contrast(1.0, tip) > 5.0  # needle against tissue
        assert abs(feats.shaft_contrast(tip + 3.0, tip + 10.0)) < 1.0  # beyond the tip


def test_difference_feature_marks_where_the_needle_moved():
    before = _needle_image(40.0, 12.0, 2.0, seed=1)
    now = _needle_image(40.0, 18.0, 2.0, seed=2)
    axis = estimate_axis(now, GRID, theta_centre_deg=40.0, tip_along_mm=18.0)
    feats = tip_features(now, before, GRID, axis)
    E2 = feats.E[1]
    assert abs(feats.x_mm[np.argmax(E2)] - 18.0) <= 0.3  # new tip: positive
    assert abs(feats.x_mm[np.argmin(E2)] - 12.0) <= 0.3  # old tip: negative
    assert np.all(tip_features(now, None, GRID, axis).E[1] == 0.0)


def test_tip_map_is_h_for_a_learned_source():
    image = _needle_image(40.0, 18.0, 2.0)
    axis = estimate_axis(image, GRID, theta_centre_deg=40.0, tip_along_mm=18.0)
    tip_point = axis.point_mm(14.0)
    zz, xx = np.meshgrid(*(GRID.axis_coords(a) for a in range(2)), indexing="ij")
    tip_map = np.exp(-0.5 * ((xx - tip_point[0]) ** 2 + (zz - tip_point[1]) ** 2) / 0.3**2)
    feats, h = tip_map_along_axis(image, tip_map.astype(np.float32), GRID, axis)
    assert feats.E is None
    assert abs(feats.x_mm[np.argmax(h)] - 14.0) <= 0.1
    with pytest.raises(ValueError, match="tip map"):
        tip_likelihood(feats, np.ones(5))


def test_tip_likelihood_checks_the_weights():
    image = _needle_image(40.0, 18.0, 2.0)
    axis = AxisEstimate(40.0, 2.0, 0.0, roi_anchor_mm(GRID, MathiassenParams()),
                        np.array([0.9]), np.zeros(1), np.zeros(1))
    feats = tip_features(image, None, GRID, axis)
    with pytest.raises(ValueError, match="need 5 weights"):
        tip_likelihood(feats, np.ones(4))


def test_params_are_validated():
    with pytest.raises(ValueError, match="ray_length_mm"):
        MathiassenParams(ray_length_mm=0.0)
    with pytest.raises(ValueError, match="min_rays"):
        MathiassenParams(min_rays=13)
    # the strip across the axis (+-gpp_size_mm / 2) must hold the background band 2-3 mm above
    with pytest.raises(ValueError, match="gpp_size_mm must be at least 6 mm"):
        MathiassenParams(gpp_size_mm=1e-300)


# ----------------------------------------------------------------- the weight file


def test_weight_file_has_five_weights_and_its_command():
    path = weights_path()
    assert path.is_file()
    doc = json.loads(path.read_text())
    w = load_tip_weights()
    assert w.weights.shape == (5,) and np.all(np.isfinite(w.weights))
    np.testing.assert_allclose(np.linalg.norm(w.weights), 1.0, rtol=1e-6)
    assert doc["command"] == "python -m training.mathiassen_fit"
    assert doc["seeds"] == [1000, 1001, 1002, 1003, 1004, 1005]
    assert sorted(map(tuple, doc["combos_angle_deg_speed_mm_s"])) == [
        (35.0, 5.0), (35.0, 10.0), (35.0, 15.0), (45.0, 5.0), (45.0, 10.0), (45.0, 15.0)]
    assert doc["background"] == "inhomogeneous"
    assert 0 < doc["frames_used"] <= doc["frames_total"]
    # the upper-wall echo lies about one 14 G radius (1.05 mm) above the centre line
    assert 0.7 < w.axis_offset_mm < 1.5


def test_missing_weight_file_says_how_to_make_it(tmp_path):
    with pytest.raises(FileNotFoundError, match="mathiassen_fit"):
        load_tip_weights(tmp_path / "none.json")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"weights": [1.0, 2.0]}))
    with pytest.raises(ValueError, match="5 finite"):
        load_tip_weights(bad)
