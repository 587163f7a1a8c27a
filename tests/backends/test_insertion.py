"""Tests of the insertion detection of Chatelain 2013, section II-B."""

import numpy as np
import pytest
from scipy.optimize import minimize

from needlenet.backends._insertion import (
    Detection,
    InsertionDetector,
    InsertionParams,
    candidate_set,
    detect_insertion,
    geometric_median,
)

# ------------------------------------------------------------------------------------------
# Geometric median (eq. (2), Weiszfeld)
# ------------------------------------------------------------------------------------------


def _sum_of_distances(y, points, weights):
    return weights @ np.linalg.norm(points - y, axis=1)


def test_median_of_square_vertices_is_centre():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    np.testing.assert_allclose(geometric_median(square), [0.5, 0.5], atol=1e-9)


def test_median_of_odd_collinear_points_is_middle_point():
    u = np.array([1.0, -2.0, 2.0]) / 3
    t = np.array([0.0, 1.0, 2.0, 3.0, 10.0])
    points = np.array([4.0, 5.0, 6.0]) + t[:, None] * u
    np.testing.assert_allclose(geometric_median(points), points[2], atol=1e-9)


@pytest.mark.filterwarnings("error")
def test_median_when_the_mean_is_a_data_point():
    # the mean, where Weiszfeld starts, is the data point 2: a plain step divides by zero
    points = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [4.0, 0.0]])
    np.testing.assert_array_equal(geometric_median(points), [2.0, 0.0])
    # a data point at the mean that is not the median: the iteration must leave it (there
    # ||R|| = 4 > eta = 1) and reach the median (0, 0), which carries 5 of the 7 unit weights
    cluster = np.vstack([np.zeros((5, 2)), [[100.0, 30.0]]])
    points = np.vstack([cluster, cluster.mean(axis=0)])
    np.testing.assert_array_equal(points.mean(axis=0), points[-1])
    np.testing.assert_array_equal(geometric_median(points), [0.0, 0.0])


def test_weighted_median_on_a_line():
    # 1D weighted median: total weight 5, the point 10 carries 3 > 5 / 2
    points = np.array([[0.0], [1.0], [10.0]])
    np.testing.assert_array_equal(geometric_median(points, weights=[1, 1, 3]), [10.0])
    np.testing.assert_allclose(geometric_median(points, weights=[1, 2, 1]), [1.0])


@pytest.mark.parametrize("weighted", [False, True])
def test_median_matches_scipy_minimize(weighted):
    rng = np.random.default_rng(21 + weighted)
    points = rng.normal(size=(40, 3)) * [5.0, 2.0, 1.0] + [3.0, -1.0, 7.0]
    weights = rng.uniform(0.1, 2.0, 40) if weighted else np.ones(40)
    ours = geometric_median(points, weights if weighted else None, tol=1e-10)
    reference = minimize(
        _sum_of_distances,
        points.mean(axis=0),
        args=(points, weights),
        method="BFGS",
        options={"gtol": 1e-10},
    )
    np.testing.assert_allclose(ours, reference.x, atol=1e-4)
    assert _sum_of_distances(ours, points, weights) <= reference.fun + 1e-9


def test_median_is_equivariant_to_rigid_motions():
    rng = np.random.default_rng(23)
    points = rng.normal(size=(25, 3))
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    shift = np.array([10.0, -4.0, 2.0])
    moved = geometric_median(points @ rotation.T + shift, tol=1e-12)
    np.testing.assert_allclose(
        moved, rotation @ geometric_median(points, tol=1e-12) + shift, atol=1e-8
    )


def test_median_is_robust_to_30_percent_outliers():
    rng = np.random.default_rng(24)
    inliers = rng.normal(size=(100, 3))
    outliers = rng.normal(size=(43, 3)) * 5 + 1000  # 43 / 143 = 30 % of the data
    data = np.vstack([inliers, outliers])
    median_shift = np.linalg.norm(geometric_median(data) - geometric_median(inliers))
    mean_shift = np.linalg.norm(data.mean(axis=0) - inliers.mean(axis=0))
    assert median_shift < 1.5  # about one inlier standard deviation
    assert mean_shift > 500


def test_median_bad_input():
    with pytest.raises(ValueError, match="points must have shape"):
        geometric_median(np.zeros(3))
    with pytest.raises(ValueError, match="points must have shape"):
        geometric_median(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="NaN"):
        geometric_median([[0.0, np.nan]])
    with pytest.raises(ValueError, match="weights must have shape"):
        geometric_median(np.zeros((3, 2)), weights=np.ones(2))
    with pytest.raises(ValueError, match="not all zero"):
        geometric_median(np.zeros((3, 2)), weights=np.zeros(3))
    with pytest.raises(ValueError, match="tol"):
        geometric_median(np.zeros((3, 2)), tol=0.0)
    with pytest.raises(ValueError, match="max_iter"):
        geometric_median(np.zeros((3, 2)), max_iter=0)


# ------------------------------------------------------------------------------------------
# Candidate set (eq. (1))
# ------------------------------------------------------------------------------------------


def test_candidate_set_is_the_n_largest():
    rng = np.random.default_rng(25)
    diff = rng.normal(size=(12, 13, 14))
    indices, threshold = candidate_set(diff, 37)
    assert indices.shape == (37, 3)
    assert len({tuple(i) for i in indices}) == 37
    values = diff[tuple(indices.T)]
    largest = np.sort(diff.ravel())[-37:]
    np.testing.assert_array_equal(np.sort(values), largest)
    assert threshold == largest[0]
    assert np.count_nonzero(diff >= threshold) == 37  # eq. (1) with T_t


def test_candidate_set_has_exactly_n_with_ties():
    indices, threshold = candidate_set(np.ones((6, 7)), 10)
    assert indices.shape == (10, 2) and threshold == 1.0


def test_candidate_set_bad_input():
    with pytest.raises(ValueError, match="n_candidates must be in"):
        candidate_set(np.zeros((3, 3)), 10)
    with pytest.raises(ValueError, match="n_candidates must be in"):
        candidate_set(np.zeros((3, 3)), 0)
    with pytest.raises(ValueError, match="n_candidates must be an integer"):
        candidate_set(np.zeros((3, 3)), 2.5)
    with pytest.raises(ValueError, match="NaN"):
        candidate_set(np.array([[0.0, np.nan]]), 1)


# ------------------------------------------------------------------------------------------
# Detector
# ------------------------------------------------------------------------------------------

SPACING_MM = 0.5
SHAPE = (40, 40, 40)
PARAMS = InsertionParams(n_candidates=50, variance_threshold_mm2=25.0, distance_threshold_mm=5.0)


def _needle_mask(shape, entry, direction, length, radius):
    u = np.asarray(direction, float) / np.linalg.norm(direction)
    grid = np.indices(shape).reshape(len(shape), -1).T - np.asarray(entry, float)
    along = grid @ u
    dist = np.linalg.norm(grid - along[:, None] * u, axis=1)
    return ((along >= 0) & (along <= length) & (dist <= radius)).reshape(shape)


@pytest.fixture
def frames():
    rng = np.random.default_rng(26)
    before = rng.normal(size=SHAPE)
    after = rng.normal(size=SHAPE)
    entry = np.array([0.0, 20.0, 15.0])  # on the face of index 0 along axis 0
    after[_needle_mask(SHAPE, entry, [1.0, 0.15, -0.1], 12.0, 1.5)] += 20.0
    return before, after, entry


def test_detector_finds_entering_needle(frames):
    before, after, entry = frames
    detector = InsertionDetector(PARAMS)
    first = detector.update(before, SPACING_MM)
    assert not first and "first frame" in first.reason
    detection = detector.update(after, SPACING_MM)
    assert isinstance(detection, Detection) and detection
    assert detection.face == (0, 0)
    assert detection.entry_point_mm[0] == 0.0
    assert np.linalg.norm(detection.entry_point_mm - entry * SPACING_MM) < 2 * SPACING_MM
    assert detection.variance_mm2 < PARAMS.variance_threshold_mm2
    distance = np.linalg.norm(detection.entry_point_mm - detection.median_mm)
    assert distance == pytest.approx(detection.median_mm[0])


def test_update_difference_accepts_a_precomputed_change(frames):
    before, after, _ = frames
    detector = InsertionDetector(PARAMS)
    detector.update(before, SPACING_MM)
    from_frames = detector.update(after, SPACING_MM)
    from_difference = InsertionDetector(PARAMS).update_difference(
        np.abs(after - before), SPACING_MM
    )
    assert from_difference
    np.testing.assert_array_equal(from_difference.entry_point_mm, from_frames.entry_point_mm)
    assert from_difference.variance_mm2 == from_frames.variance_mm2


def test_detector_refuses_global_brightness_change(frames):
    before, _, _ = frames
    rng = np.random.default_rng(27)
    brighter = before + 5.0 + rng.normal(scale=0.5, size=SHAPE)
    detector = InsertionDetector(PARAMS)
    detector.update(before, SPACING_MM)
    detection = detector.update(brighter, SPACING_MM)
    assert not detection
    assert "variance" in detection.reason and detection.median_mm is None
    # candidates spread over the whole 20 mm cube: about 3 * 20^2 / 12 = 100 mm^2
    assert detection.variance_mm2 > 4 * PARAMS.variance_threshold_mm2


def test_detector_refuses_change_far_from_the_faces():
    rng = np.random.default_rng(28)
    before = rng.normal(size=SHAPE)
    after = before + rng.normal(scale=0.1, size=SHAPE)
    after[_needle_mask(SHAPE, [14.0, 20.0, 20.0], [1.0, 0.0, 0.0], 12.0, 1.5)] += 20.0
    detection = detect_insertion(np.abs(after - before), SPACING_MM, PARAMS)
    assert not detection and "delta" in detection.reason
    assert detection.median_mm is not None
    assert np.linalg.norm(detection.entry_point_mm - detection.median_mm) >= 5.0


def test_detector_2d_anisotropic_spacing():
    rng = np.random.default_rng(29)
    before, after = rng.normal(size=(2, 60, 50))
    after[_needle_mask((60, 50), [30.0, 49.0], [0.1, -1.0], 15.0, 1.0)] += 20.0
    spacing = (0.3, 0.2)
    detection = detect_insertion(np.abs(after - before), spacing, InsertionParams(n_candidates=20))
    assert detection and detection.face == (1, 1)
    assert np.linalg.norm(detection.entry_point_mm - np.array([30.0, 49.0]) * spacing) < 2 * 0.3


def test_no_change_is_not_detected():
    detection = detect_insertion(np.zeros((10, 10, 10)), 1.0, InsertionParams(n_candidates=5))
    assert not detection and "no change" in detection.reason


def test_detector_bad_input(frames):
    before, _, _ = frames
    detector = InsertionDetector(PARAMS)
    detector.update(before, SPACING_MM)
    with pytest.raises(ValueError, match="frame has shape"):
        detector.update(before[:-1], SPACING_MM)
    with pytest.raises(ValueError, match="frame must be a 2D image or a 3D volume"):
        detector.update(np.zeros(5), SPACING_MM)
    with pytest.raises(ValueError, match="NaN"):
        detector.update(np.full(SHAPE, np.nan), SPACING_MM)
    with pytest.raises(ValueError, match="spacing"):
        detector.update_difference(before, -1.0)
    with pytest.raises(ValueError, match="spacing"):
        detector.update_difference(before, (1.0, 1.0))
    with pytest.raises(ValueError, match="n_candidates"):
        detect_insertion(np.zeros((3, 3)), 1.0, InsertionParams(n_candidates=10))
    with pytest.raises(ValueError, match="n_candidates"):
        InsertionParams(n_candidates=0)
    with pytest.raises(ValueError, match="variance_threshold_mm2"):
        InsertionParams(variance_threshold_mm2=-1.0)
    with pytest.raises(ValueError, match="distance_threshold_mm"):
        InsertionParams(distance_threshold_mm=np.nan)
