"""Tests of the DF baseline, Ding and Fenster's Hough method as Mathiassen 2017 section III-C
ran it (needlenet/features/_hough.py)."""

import numpy as np
import pytest
from skimage.draw import line as draw_line

from needlenet.features._hough import (
    DFParams,
    ding_fenster,
    first_gap_tip,
    hough_axis,
    peak_centre,
    segment,
)
from synth import Grid

GRID = Grid((300, 384), (0.1, 0.1), (0.0, -19.2))


def _needle(theta_deg, entry_px, length_px, gap=None, noise=0.05, seed=0):
    """A 3-px-thick bright segment from ``entry_px`` (col, row) down-left at ``theta_deg`` to
    the skin, optionally with a gap (start, stop) in px along it, on seeded noise."""
    rng = np.random.default_rng(seed)
    image = 0.2 + noise * rng.standard_normal(GRID.shape)
    t = np.deg2rad(theta_deg)
    d = np.array([-np.cos(t), np.sin(t)])
    for s in np.arange(0.0, length_px, 0.25):
        if gap is not None and gap[0] <= s < gap[1]:
            continue
        c, r = np.asarray(entry_px) + s * d
        for k in (-1, 0, 1):
            image[int(round(r + k * d[0])), int(round(c - k * d[1]))] = 1.0
    tip = np.asarray(entry_px) + (length_px - 1) * d
    return image.astype(np.float32), tip


def test_segment_keeps_pixels_above_mean_plus_k_sd():
    image = np.zeros((10, 10), np.float32)
    image[2, 3] = 10.0
    image[5, 5] = 1.0
    mask = segment(image, DFParams(threshold_sd=2.0))  # mean 0.11, sd 1.0: threshold 2.1
    assert mask[2, 3] and not mask[5, 5] and mask.sum() == 1


def test_hough_axis_uses_the_insertion_angle_convention():
    mask = np.zeros(GRID.shape, bool)
    rr, cc = draw_line(10, 370, 10 + int(round(300 * np.tan(np.deg2rad(30.0)))), 70)
    keep = (rr < GRID.shape[0]) & (cc >= 0)
    mask[rr[keep], cc[keep]] = True
    theta, _, votes = hough_axis(mask, GRID, np.arange(25.0, 35.01, 0.1))
    assert theta == pytest.approx(30.0, abs=0.2)
    assert votes > 200


def test_hough_axis_runs_along_the_middle_of_a_thick_band():
    # every line through a band parallel to it gets about the same vote: the axis is the
    # band's middle, not the first maximal bin at its edge
    mask = np.zeros(GRID.shape, bool)
    rows, cols = np.mgrid[0:GRID.shape[0], 0:GRID.shape[1]]
    t = np.deg2rad(40.0)
    d = np.array([-np.cos(t), np.sin(t)])  # (col, row) down-left
    n = np.array([d[1], -d[0]])
    foot = np.array([300.0, 20.0])
    across = (cols - foot[0]) * n[0] + (rows - foot[1]) * n[1]
    along = (cols - foot[0]) * d[0] + (rows - foot[1]) * d[1]
    mask[(np.abs(across) <= 7.0) & (along >= 0) & (along <= 250)] = True  # 15 px thick
    theta, rho, _ = hough_axis(mask, GRID, [40.0])
    assert theta == 40.0
    from needlenet.features._hough import _line_samples

    pts, _ = _line_samples(GRID, theta, rho)
    off = (pts[:, 0] - foot[0]) * n[0] + (pts[:, 1] - foot[1]) * n[1]
    assert np.abs(off).max() < 1.0


def test_peak_centre_is_the_middle_of_the_half_maximum_run():
    dists = np.arange(20.0)
    votes = np.zeros(20)
    votes[5:12] = [10, 100, 50, 100, 50, 100, 10]  # alternating bins of a digital line
    votes[16] = 90  # another line, apart from the peak's run
    assert peak_centre(votes, dists) == pytest.approx(8.0)


def test_first_gap_tip_closes_small_gaps():
    profile = np.zeros(40, bool)
    profile[3:12] = True
    profile[14:20] = True  # a 2-sample gap: closed by a 3-sample element
    profile[30:35] = True  # a 10-sample gap: the first gap
    assert first_gap_tip(profile, 3) == (3, 19)
    assert first_gap_tip(profile, 1) == (3, 11)  # no closing
    assert first_gap_tip(np.zeros(5, bool), 3) is None


def test_df_finds_the_line_and_its_first_gap():
    # entry at the top right, a 1.2 mm gap in the shaft (closed by the 2.1 mm element), then
    # nothing beyond the tip
    image, tip = _needle(40.0, (380.0, 2.0), 250, gap=(100, 112))
    res = ding_fenster(image, GRID, expected_angle_deg=42.0)
    assert res
    assert res.theta_deg == pytest.approx(40.0, abs=0.3)
    tip_mm = GRID.index_to_points(tip[::-1])
    assert np.linalg.norm(res.tip_mm - tip_mm) < 0.3
    np.testing.assert_allclose(res.direction, [-np.cos(np.deg2rad(40)), np.sin(np.deg2rad(40))],
                               atol=0.005)
    # a gap longer than the structuring element ends the needle there
    image, _ = _needle(40.0, (380.0, 2.0), 250, gap=(100, 140))
    res = ding_fenster(image, GRID, expected_angle_deg=42.0)
    assert res
    assert np.linalg.norm(res.tip_mm - GRID.index_to_points(
        (np.array([380.0, 2.0]) + 99 * np.array([-np.cos(np.deg2rad(40)),
                                                 np.sin(np.deg2rad(40))]))[::-1])) < 0.3


def test_df_searches_only_around_the_expected_angle():
    image, _ = _needle(40.0, (380.0, 2.0), 250)
    res = ding_fenster(image, GRID, expected_angle_deg=55.0)  # 50-60 degrees only
    assert 49.9 <= res.theta_deg <= 60.1
    res = ding_fenster(image, GRID)  # no expectation: 20-70 degrees
    assert res.theta_deg == pytest.approx(40.0, abs=0.3)


def test_df_reports_why_it_found_nothing():
    res = ding_fenster(np.full(GRID.shape, 0.5, np.float32), GRID, 40.0)
    assert not res and "empty" in res.reason
    with pytest.raises(ValueError, match="2-D"):
        ding_fenster(np.zeros((4, 4, 4)), Grid((4, 4, 4), (1, 1, 1), (0, 0, 0)))
