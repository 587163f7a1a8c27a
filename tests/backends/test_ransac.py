"""Tests of the batched RANSAC of Chatelain 2013 (II-D) and Zhao 2013 (Appendix B)."""

import math

import numpy as np
import pytest
from skimage.measure import LineModelND
from skimage.measure import ransac as sk_ransac

from needlenet.backends import (
    AxisTip,
    LineModel,
    PolyCurveModel,
    RansacResult,
    adaptive_trial_count,
    max_curvature,
    min_sample_distance,
    ransac,
    sample_along_axis,
    tip_along_axis,
    within_angle,
)
from needlenet.backends._ransac import _draw_samples


def _line_points(rng, origin, direction, n, half_length, noise):
    u = np.asarray(direction, float) / np.linalg.norm(direction)
    t = rng.uniform(-half_length, half_length, n)
    return np.asarray(origin, float) + t[:, None] * u + rng.normal(0, noise, (n, len(u)))


def _angle_between_lines(u, v):
    cos = abs(np.dot(u, v)) / (np.linalg.norm(u) * np.linalg.norm(v))
    return math.degrees(math.acos(min(cos, 1.0)))


@pytest.fixture
def line_with_outliers():
    rng = np.random.default_rng(20130001)
    inliers = _line_points(rng, [1.0, 2.0, 3.0], [1.0, 2.0, 2.0], 100, 20.0, 0.01)
    outliers = rng.uniform(-30, 30, (60, 3))
    return np.vstack([inliers, outliers]), np.r_[np.ones(100, bool), np.zeros(60, bool)]


# ------------------------------------------------------------------------------------------
# Models
# ------------------------------------------------------------------------------------------


def test_line_residuals_match_skimage():
    rng = np.random.default_rng(1)
    origin, direction = rng.normal(size=3), rng.normal(size=3)
    points = rng.normal(size=(50, 3)) * 10
    ours = LineModel(origin, direction).residuals(points)
    theirs = LineModelND(origin, direction / np.linalg.norm(direction)).residuals(points)
    np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-12)


def test_line_from_inliers_matches_skimage_total_least_squares():
    rng = np.random.default_rng(2)
    points = _line_points(rng, [0, 1, 2], [3, -1, 1], 80, 10, 0.3)
    ours = LineModel.from_inliers(points)
    theirs = LineModelND.from_estimate(points)
    np.testing.assert_allclose(ours.origin, theirs.origin, atol=1e-10)
    assert abs(ours.direction @ theirs.direction) == pytest.approx(1.0, abs=1e-12)


def test_weighted_line_fit_equals_repeated_points():
    rng = np.random.default_rng(3)
    points = _line_points(rng, [0, 0, 0], [1, 1, 0], 30, 5, 0.5)
    counts = rng.integers(1, 4, len(points))
    weighted = LineModel.from_inliers(points, counts.astype(float))
    repeated = LineModel.from_inliers(np.repeat(points, counts, axis=0))
    np.testing.assert_allclose(weighted.origin, repeated.origin, atol=1e-12)
    assert abs(weighted.direction @ repeated.direction) == pytest.approx(1.0, abs=1e-12)


def test_line_from_samples_is_zhao_b4_and_batched_residuals_match_single():
    rng = np.random.default_rng(4)
    samples = rng.normal(size=(5, 2, 3))
    lines = LineModel.from_samples(samples)
    # Zhao eq. (B4): origin N1, unit direction towards N2; both points at distance 0.
    np.testing.assert_allclose(lines.origin, samples[:, 0])
    np.testing.assert_allclose(np.linalg.norm(lines.direction, axis=1), 1.0)
    # distances come from |p - o|^2 - ((p - o) . u)^2: a point on the line is at 0 to within
    # sqrt(machine epsilon) of the coordinates
    np.testing.assert_allclose(lines.residuals(samples[2])[2], 0.0, atol=1e-7)
    points = rng.normal(size=(40, 3))
    batch = lines.residuals(points)
    assert batch.shape == (5, 40)
    for i in range(5):
        np.testing.assert_allclose(batch[i], lines[i].residuals(points), rtol=1e-12)


def test_line_residuals_are_the_distance_of_the_projection():
    """Against the distance of each point to its orthogonal projection on the line, at
    millimetre coordinates of a 128^3 volume."""
    rng = np.random.default_rng(8)
    lines = LineModel(rng.uniform(0, 60, (16, 3)), rng.normal(size=(16, 3)))
    points = rng.uniform(0, 60, (500, 3))
    d = points[None] - lines.origin[:, None]
    t = np.einsum("bnd,bd->bn", d, lines.direction)
    direct = np.linalg.norm(d - t[..., None] * lines.direction[:, None], axis=-1)
    np.testing.assert_allclose(lines.residuals(points), direct, atol=1e-9)


def test_curve_from_samples_interpolates_control_points():
    rng = np.random.default_rng(5)
    samples = rng.normal(size=(6, 3, 3)) * 5
    curves = PolyCurveModel.from_samples(samples)
    assert curves.coefficients.shape == (6, 3, 3)
    a = curves.parameter(samples[0])[0]
    np.testing.assert_allclose(curves[0].points_at(a), samples[0], atol=1e-9)
    # eq. (18) distance of the control points to their own curve is zero
    for i in range(6):
        np.testing.assert_allclose(curves[i].residuals(samples[i]), 0.0, atol=1e-9)


def test_curve_of_order_two_is_the_line_through_the_sample():
    rng = np.random.default_rng(6)
    samples = rng.normal(size=(4, 2, 3))
    points = rng.normal(size=(30, 3)) * 4
    np.testing.assert_allclose(
        PolyCurveModel.from_samples(samples).residuals(points),
        LineModel.from_samples(samples).residuals(points),
        atol=1e-10,
    )


def test_curve_curvature_of_a_parabola():
    # C(a) = a u + c a^2 with c orthogonal to u: curvature 2|c| at the vertex, its maximum.
    u = np.array([1.0, 0.0, 0.0])
    c = np.array([0.0, 0.03, 0.0])
    h = np.stack([np.zeros(3), u, c], axis=1)
    curve = PolyCurveModel(h, np.zeros(3), u, np.array([-10.0, 10.0]))
    assert curve.max_curvature() == pytest.approx(0.06, rel=1e-12)
    assert LineModel(np.zeros(3), u).max_curvature() == 0.0


def test_degenerate_curve_sample_is_invalid():
    samples = np.array([[[0.0, 0, 0], [0, 0, 0], [1, 1, 1]], [[0, 0, 0], [1, 0, 0], [2, 1, 0]]])
    assert PolyCurveModel.from_samples(samples).is_valid().tolist() == [False, True]


def test_oriented_flips_direction_and_keeps_geometry():
    rng = np.random.default_rng(7)
    points = rng.normal(size=(20, 3))
    curve = PolyCurveModel.from_samples(rng.normal(size=(1, 3, 3)))[0]
    reference = -curve.axis
    flipped = curve.oriented(reference)
    assert flipped.axis @ reference > 0
    np.testing.assert_allclose(flipped.residuals(points), curve.residuals(points), atol=1e-12)
    assert flipped.max_curvature() == pytest.approx(curve.max_curvature(), rel=1e-9)
    line = LineModel(np.zeros(3), [1.0, 0, 0]).oriented([-1.0, 0.2, 0])
    np.testing.assert_allclose(line.direction, [-1.0, 0, 0])


# ------------------------------------------------------------------------------------------
# Adaptive trial count
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("outlier_share", "n", "expected"),
    [
        # Hartley & Zisserman, Multiple View Geometry, 2nd ed., Table 4.3 (p = 0.99)
        (0.05, 2, 2),
        (0.10, 2, 3),
        (0.30, 2, 7),
        (0.50, 2, 17),
        (0.50, 4, 72),
        (0.05, 8, 5),
        (0.50, 8, 1177),
    ],
)
def test_adaptive_trial_count_hartley_zisserman(outlier_share, n, expected):
    assert adaptive_trial_count(1 - outlier_share, n, 0.99) == expected


def test_adaptive_trial_count_zhao_figures():
    # Zhao 2013 (results): inlier ratio 0.05 in the whole volume -> J_R "about 1840", 0.4 in
    # the ROI -> J_P "about 26", with n = 2. eta = 0.99 reproduces both: the unrounded values
    # are 1839.8 and 26.4; rounded up, as RANSAC must be, they are 1840 and 27.
    assert adaptive_trial_count(0.05, 2, 0.99) == 1840
    assert math.log(0.01) / math.log(1 - 0.4**2) == pytest.approx(26.4, abs=0.05)
    assert adaptive_trial_count(0.4, 2, 0.99) == 27
    # another eta would not: 0.95 gives 1197
    assert adaptive_trial_count(0.05, 2, 0.95) == 1197


def test_adaptive_trial_count_limits():
    assert adaptive_trial_count(0.0, 2, 0.99) == math.inf
    assert adaptive_trial_count(1.0, 2, 0.99) == 1
    assert adaptive_trial_count(0.5, 2, 0.0) == 0
    with pytest.raises(ValueError, match="inlier_ratio"):
        adaptive_trial_count(1.5, 2, 0.99)
    with pytest.raises(ValueError, match="success_probability"):
        adaptive_trial_count(0.5, 2, 1.0)
    with pytest.raises(ValueError, match="n_samples"):
        adaptive_trial_count(0.5, 0, 0.99)


# ------------------------------------------------------------------------------------------
# RANSAC loop
# ------------------------------------------------------------------------------------------


def test_ransac_agrees_with_skimage(line_with_outliers):
    points, truth = line_with_outliers
    ours = ransac(points, residual_threshold=0.5, rng=1)
    theirs, theirs_inliers = sk_ransac(
        points, LineModelND, 2, 0.5, max_trials=1000, stop_probability=0.99, rng=1
    )
    assert ours and isinstance(ours, RansacResult)
    np.testing.assert_array_equal(ours.inliers, theirs_inliers)
    np.testing.assert_array_equal(ours.inliers, truth)
    assert _angle_between_lines(ours.model.direction, theirs.direction) < 1e-4
    assert LineModelND(theirs.origin, theirs.direction).residuals(ours.model.origin[None]) < 1e-6
    assert ours.inlier_ratio == pytest.approx(100 / 160)


def test_ransac_stops_at_adaptive_count(line_with_outliers):
    points, _ = line_with_outliers
    result = ransac(points, residual_threshold=0.5, batch_size=1, rng=2)
    # batches of one: the loop stops exactly when the trials reach eq. (21)'s count
    assert result.n_trials == adaptive_trial_count(100 / 160, 2, 0.99) == 10
    capped = ransac(points, residual_threshold=0.5, max_trials=5, batch_size=2, rng=2)
    assert capped.n_trials == 5


def test_ransac_is_reproducible_with_seed(line_with_outliers):
    points, _ = line_with_outliers
    a = ransac(points, residual_threshold=0.5, rng=11)
    b = ransac(points, residual_threshold=0.5, rng=np.random.default_rng(11))
    np.testing.assert_array_equal(a.sample, b.sample)
    np.testing.assert_array_equal(a.model.direction, b.model.direction)


def _true_and_decoy(seed):
    rng = np.random.default_rng(seed)
    true = _line_points(rng, [0, 0, 0], [1, 0, 0], 60, 20, 0.05)
    decoy = _line_points(rng, [0, 8, 5], [0, 1, 0.3], 150, 20, 0.05)
    clutter = rng.uniform(-25, 25, (40, 3))
    return np.vstack([true, decoy, clutter])


def test_angle_constraint_rejects_decoy():
    points = _true_and_decoy(8)
    free = ransac(points, residual_threshold=0.3, rng=3)
    assert free.inliers[60:210].sum() > 140  # the longer decoy wins unconstrained
    for predicted in ([1.0, 0.05, 0.0], [-1.0, -0.05, 0.0]):  # sign-agnostic, eq. (22)
        result = ransac(
            points,
            residual_threshold=0.3,
            is_model_valid=within_angle(predicted, 10.0),
            predicted_direction=predicted,
            rng=3,
        )
        assert result.inliers[:60].sum() >= 58 and result.inliers[60:210].sum() < 5
        assert _angle_between_lines(result.model.direction, [1, 0, 0]) < 1.0
        assert result.model.direction @ predicted > 0  # oriented along the prediction


def test_weighted_sampling_finds_marked_line():
    points = _true_and_decoy(9)
    weights = np.full(len(points), 0.02)
    weights[:60] = 1.0
    unweighted = ransac(points, residual_threshold=0.3, rng=4)
    assert unweighted.inliers[60:210].sum() > 140
    result = ransac(points, residual_threshold=0.3, weights=weights, rng=4)
    assert result.inliers[:60].sum() >= 58
    assert _angle_between_lines(result.model.direction, [1, 0, 0]) < 1.0
    assert np.all(result.sample < 60)
    expected_ratio = weights[result.inliers].sum() / weights.sum()
    assert result.inlier_ratio == pytest.approx(expected_ratio)


def test_draw_samples_law_is_sequential_weighted_without_replacement():
    rng = np.random.default_rng(10)
    w = np.array([0.4, 0.3, 0.2, 0.1, 0.0])
    idx = _draw_samples(w, 40000, 2, rng)
    assert np.all(idx[:, 0] != idx[:, 1])
    assert not np.any(idx == 4)  # weight 0 is never drawn
    # P(i in sample) = w_i + sum_{j != i} w_j w_i / (1 - w_j)
    p = w / w.sum()
    expected = p + p * (p / (1 - p)).sum() - p * p / (1 - p)
    observed = np.bincount(idx.ravel(), minlength=5) / len(idx)
    np.testing.assert_allclose(observed, expected, atol=0.01)


def test_min_sample_distance_respected():
    rng = np.random.default_rng(12)
    points = _line_points(rng, [0, 0, 0], [0, 1, 1], 200, 5, 0.01)  # length about 10
    for seed in range(5):
        result = ransac(
            points, residual_threshold=0.1, is_sample_valid=min_sample_distance(6.0), rng=seed
        )
        assert result
        i, j = result.sample
        assert np.linalg.norm(points[i] - points[j]) >= 6.0
    impossible = ransac(
        points, residual_threshold=0.1, is_sample_valid=min_sample_distance(50.0), rng=0
    )
    assert not impossible
    assert "no hypothesis passed the constraints" in impossible.reason
    assert impossible.model is None and not impossible.inliers.any()
    assert impossible.n_trials == 1000


def test_curve_model_recovers_quadratic_3d_curve():
    rng = np.random.default_rng(13)
    p0 = np.array([5.0, -3.0, 2.0])
    u = np.array([2.0, 1.0, 2.0]) / 3
    # orthogonal to u: curvature 0.01 / mm at the vertex, a 100 mm radius, 4.5 mm sagitta
    c = np.array([1.0, 0.0, -1.0]) / np.sqrt(2) * 0.005
    s = rng.uniform(-30, 30, 150)
    curve = p0 + s[:, None] * u + (s**2)[:, None] * c
    points = np.vstack([curve + rng.normal(0, 0.05, curve.shape), rng.uniform(-40, 40, (80, 3))])
    result = ransac(points, "curve", residual_threshold=0.4, order=3, rng=4)
    assert result.inliers[:150].all() and not result.inliers[150:].any()
    dense = np.linspace(-30, 30, 61)
    truth = p0 + dense[:, None] * u + (dense**2)[:, None] * c
    assert result.model.residuals(truth).max() < 0.05
    assert result.model.max_curvature() == pytest.approx(0.01, rel=0.05)
    line = ransac(points, "line", residual_threshold=0.4, rng=4)
    assert line.inliers[:150].sum() < 100  # a line cannot hold the whole curve


def test_curvature_constraint_rejects_tight_arc():
    rng = np.random.default_rng(5)
    theta = rng.uniform(0, np.pi / 3, 200)
    arc = np.c_[10 * np.cos(theta), 10 * np.sin(theta), np.full(200, 5.0)]  # curvature 0.1
    t = rng.uniform(-15, 15, 80)
    straight = np.c_[t, np.full(80, 3.0), np.full(80, -5.0)]
    points = np.vstack([arc, straight]) + rng.normal(0, 0.03, (280, 3))
    free = ransac(points, "curve", residual_threshold=0.3, rng=5)
    assert free.inliers[:200].sum() > 190
    constrained = ransac(
        points, "curve", residual_threshold=0.3, is_model_valid=max_curvature(0.02), rng=5
    )
    assert constrained.inliers[200:].sum() >= 78 and constrained.inliers[:200].sum() < 10


def test_ransac_2d():
    rng = np.random.default_rng(14)
    points = np.vstack(
        [_line_points(rng, [10, 10], [3, 4], 50, 10, 0.02), rng.uniform(0, 20, (30, 2))]
    )
    result = ransac(points, residual_threshold=0.2, rng=0)
    assert result.inliers[:50].all()
    assert _angle_between_lines(result.model.direction, [3, 4]) < 0.5


def test_failures_are_falsy_with_reason():
    one = ransac(np.zeros((1, 3)), residual_threshold=1.0)
    assert not one and "too few points" in one.reason and one.inliers.shape == (1,)
    two = ransac(np.eye(3)[:2], "curve", residual_threshold=1.0, order=3)
    assert not two and "too few points" in two.reason
    weights = np.array([1.0, 0.0, 0.0])
    zero = ransac(np.eye(3), residual_threshold=1.0, weights=weights)
    assert not zero and "positive weight" in zero.reason


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"points": np.zeros((5, 3, 1))}, "points must have shape"),
        ({"points": np.zeros((5, 1))}, "points must have shape"),
        ({"points": np.array([[0.0, np.nan], [1, 1], [2, 2]])}, "NaN"),
        ({"residual_threshold": 0.0}, "residual_threshold"),
        ({"residual_threshold": np.nan}, "residual_threshold"),
        ({"model": "circle"}, "model must be one of"),
        ({"weights": np.ones(3)}, r"weights must have shape \(6,\)"),
        ({"weights": -np.ones(6)}, "non-negative"),
        ({"is_model_valid": within_angle([1.0, 0.0], 10.0)}, "predicted_direction"),
        ({"predicted_direction": [1.0, 0.0]}, "predicted_direction"),
        ({"predicted_direction": [0.0, 0.0, 0.0]}, "non-zero"),
        ({"is_sample_valid": [min_sample_distance(1.0), 2.0]}, "is_sample_valid"),
        ({"success_probability": 1.0}, "success_probability"),
        ({"max_trials": 0}, "max_trials"),
        ({"batch_size": 2.5}, "batch_size"),
        ({"model": "curve", "order": 1}, "order"),
    ],
)
def test_ransac_bad_input(kwargs, message):
    args = {"points": np.arange(18.0).reshape(6, 3), "residual_threshold": 1.0} | kwargs
    points = args.pop("points")
    with pytest.raises(ValueError, match=message):
        ransac(points, **args)


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: min_sample_distance(-1.0), "min_sample_distance"),
        (lambda: max_curvature(np.nan), "max_curvature"),
        (lambda: within_angle([0.0, 0.0, 0.0], 10.0), "non-zero"),
        (lambda: within_angle([[1.0, 0.0, 0.0]], 10.0), "predicted_direction"),
        (lambda: within_angle([1.0, 0, 0], 120.0), "max_angle_deg"),
    ],
)
def test_constraint_bad_input(build, message):
    with pytest.raises(ValueError, match=message):
        build()


def test_constraints_match_their_definitions():
    rng = np.random.default_rng(15)
    samples = rng.normal(size=(200, 3, 3))
    pairs = samples[:, [0, 0, 1]] - samples[:, [1, 2, 2]]
    kappa = np.linalg.norm(pairs, axis=-1).min(axis=1)  # Zhao's kappa(N)
    np.testing.assert_array_equal(min_sample_distance(1.0)(samples), kappa >= 1.0)
    lines = LineModel.from_samples(samples[:, :2])
    k = np.array([1.0, 2.0, 2.0])
    angle = np.degrees(np.arccos(np.abs(lines.direction @ k) / 3.0))
    np.testing.assert_array_equal(within_angle(-k, 30.0)(lines), angle <= 30.0)
    curves = PolyCurveModel.from_samples(samples)
    np.testing.assert_array_equal(max_curvature(0.5)(curves), curves.max_curvature() <= 0.5)
    assert str(min_sample_distance(2.0)) == "min_sample_distance(2)"


def test_model_estimation_bad_input():
    with pytest.raises(ValueError, match="too few points"):
        LineModel.from_inliers(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="distinct positions"):
        PolyCurveModel.from_inliers(np.array([[0.0, 0], [1, 1], [1, 1], [0, 0]]), order=3)
    with pytest.raises(ValueError, match="samples must have shape"):
        LineModel.from_samples(np.zeros((4, 3, 3)))
    with pytest.raises(ValueError, match="same shape"):
        LineModel(np.zeros(3), np.ones(2))


# ------------------------------------------------------------------------------------------
# Tip along the axis
# ------------------------------------------------------------------------------------------


def test_tip_along_axis_finds_tip_and_bridges_short_gap():
    positions = np.arange(40) * 0.5  # mm
    values = np.zeros(40)
    values[:20] = 100.0  # needle up to 9.5 mm
    values[8:10] = 5.0  # a 1 mm gap in the shaft (two dark samples)
    tip = tip_along_axis(values, positions, threshold=50.0, max_gap=2.0)
    assert isinstance(tip, AxisTip) and tip
    assert tip.index == 19 and not tip.reaches_end
    # crossing of 50 between 100 at 9.5 mm and 0 at 10 mm
    assert tip.position == pytest.approx(9.75)
    # the same gap is a real break when max_gap is shorter than it
    early = tip_along_axis(values, positions, threshold=50.0, max_gap=1.0)
    assert early.index == 7


def test_tip_along_axis_skips_dark_entry_and_reports_end():
    positions = np.linspace(0, 10, 11)
    values = np.r_[0.0, 0.0, np.full(9, 3.0)]
    tip = tip_along_axis(values, positions, threshold=1.0, max_gap=0.0)
    assert tip and tip.reaches_end and tip.position == 10.0
    none = tip_along_axis(np.zeros(5), np.arange(5.0), threshold=1.0, max_gap=1.0)
    assert not none and math.isnan(none.position) and "threshold" in none.reason


def test_tip_along_axis_treats_nan_as_dark():
    values = np.array([5.0, 5.0, 5.0, np.nan, np.nan])
    tip = tip_along_axis(values, np.arange(5.0), threshold=1.0, max_gap=10.0)
    assert tip.index == 2 and tip.position == 2.0 and not tip.reaches_end


def test_tip_along_axis_bad_input():
    with pytest.raises(ValueError, match="positions_along_axis must have the shape"):
        tip_along_axis(np.zeros(5), np.arange(4.0), 1.0, 1.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        tip_along_axis(np.zeros(3), np.array([0.0, 2.0, 1.0]), 1.0, 1.0)
    with pytest.raises(ValueError, match="max_gap"):
        tip_along_axis(np.zeros(3), np.arange(3.0), 1.0, -1.0)


def test_sample_along_axis_is_exact_on_linear_volume():
    spacing = np.array([0.5, 1.0, 2.0])
    i, j, k = np.indices((20, 15, 10), dtype=float)
    volume = 2 * i + 3 * j - k
    origin = np.array([1.0, 2.0, 3.0])
    direction = np.array([2.0, 1.0, 2.0])
    t = np.linspace(0, 6, 13)
    values = sample_along_axis(volume, origin, direction, spacing, t)
    idx = (origin + t[:, None] * direction / 3) / spacing
    np.testing.assert_allclose(values, idx @ [2, 3, -1], atol=1e-9)
    outside = sample_along_axis(volume, origin, direction, spacing, np.array([100.0]))
    assert np.isnan(outside[0])


def test_sample_then_tip_on_synthetic_volume():
    rng = np.random.default_rng(15)
    volume = rng.normal(0, 1, (30, 30, 30))
    entry = np.array([0.0, 12.0, 15.0])
    u = np.array([1.0, 0.3, 0.0]) / np.linalg.norm([1.0, 0.3, 0.0])
    t_true = 18.0
    grid = np.indices(volume.shape).reshape(3, -1).T - entry
    along = grid @ u
    dist = np.linalg.norm(grid - along[:, None] * u, axis=1)
    volume[((along >= 0) & (along <= t_true) & (dist <= 1.0)).reshape(volume.shape)] += 20
    t = np.arange(0, 40, 0.5)
    profile = sample_along_axis(volume, entry, u, 1.0, t)
    tip = tip_along_axis(profile, t, threshold=10.0, max_gap=2.0)
    assert abs(tip.position - t_true) < 1.0


def test_sample_along_axis_bad_input():
    with pytest.raises(ValueError, match="image must be 2D or 3D"):
        sample_along_axis(np.zeros(5), [0.0], [1.0], 1.0, [0.0])
    with pytest.raises(ValueError, match="origin"):
        sample_along_axis(np.zeros((4, 4)), [0.0, 0, 0], [1.0, 0], 1.0, [0.0])
    with pytest.raises(ValueError, match="spacing"):
        sample_along_axis(np.zeros((4, 4)), [0.0, 0], [1.0, 0], 0.0, [0.0])
    with pytest.raises(ValueError, match="direction"):
        sample_along_axis(np.zeros((4, 4)), [0.0, 0], [0.0, 0], 1.0, [0.0])
