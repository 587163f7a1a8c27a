"""The whole-frame line search (needlenet/backends/_line_search.py): the weighted Hough transform
against scikit-image's, the total-least-squares refinement, and the supported segment."""

import numpy as np
import pytest
from scipy import ndimage
from skimage.transform import hough_line, hough_line_peaks

from needlenet.backends._line_search import (
    _VOTE_BLOCK,
    LineSearchParams,
    WorkingMap,
    _best_run,
    _box3,
    extend_end,
    find_needle_line,
    hough_peaks,
    line_segment,
    refine_line,
)


def _draw_segment(shape, a, b, step, value=1.0, width_px=1):
    """A map with the segment a-b (mm, (x, z)) drawn at ``value`` on a grid of ``step`` mm."""
    m = np.zeros(shape, np.float32)
    n = int(np.ceil(np.linalg.norm(np.subtract(b, a)) / step * 4)) + 1
    pts = np.linspace(a, b, n) / step
    for o in range(-(width_px // 2), width_px // 2 + 1):
        r = np.clip(np.rint(pts[:, 1]).astype(int) + o, 0, shape[0] - 1)
        c = np.clip(np.rint(pts[:, 0]).astype(int), 0, shape[1] - 1)
        m[r, c] = value
    return m


def test_hough_peak_agrees_with_scikit_image():
    rng = np.random.default_rng(0)
    mask = np.zeros((120, 160), bool)
    mask[rng.integers(0, 120, 150), rng.integers(0, 160, 150)] = True  # clutter
    line = _draw_segment(mask.shape, (10, 100), (140, 20), 1.0) > 0  # the strong line
    mask |= line
    thetas = np.deg2rad(np.arange(0.0, 180.0, 1.0))
    rows, cols = np.nonzero(mask)
    pts = np.stack([cols, rows], -1).astype(float)
    th, rho, votes = hough_peaks(pts, np.ones(len(pts)), thetas, 1.0, 1)[0]
    # scikit-image: x cos(phi) + y sin(phi) = r with the normal angle phi in (-pi/2, pi/2]
    acc, angles, dists = hough_line(mask, theta=np.deg2rad(np.arange(-90.0, 90.0, 1.0)))
    sk_votes, phi, r = hough_line_peaks(acc, angles, dists, num_peaks=1)
    # our normal (-sin th, cos th) is skimage's (cos phi, sin phi) up to sign
    n_ours = np.array([-np.sin(th), np.cos(th)])
    n_sk = np.array([np.cos(phi[0]), np.sin(phi[0])])
    sign = np.sign(n_ours @ n_sk)
    assert abs(n_ours @ n_sk) == pytest.approx(1.0, abs=2e-4)
    assert sign * rho == pytest.approx(r[0], abs=1.5)
    # the line drawn: direction (130, -80) / |.|
    d = np.array([130.0, -80.0]) / np.hypot(130, 80)
    assert abs(np.array([np.cos(th), np.sin(th)]) @ d) > np.cos(np.deg2rad(1.0))
    # ours sums three 1-pixel rho bins: the whole rasterised line (scikit-image's single bin
    # holds part of it) and the little clutter within the band
    assert votes >= sk_votes[0]
    assert votes == pytest.approx(line.sum(), rel=0.05)


def test_refine_line_recovers_a_noisy_line_by_total_least_squares():
    rng = np.random.default_rng(1)
    theta = np.deg2rad(23.0)
    d = np.array([np.cos(theta), np.sin(theta)])
    n = np.array([-d[1], d[0]])
    t = rng.uniform(-20, 20, 400)
    pts = np.array([5.0, 12.0]) + t[:, None] * d + rng.normal(0, 0.1, 400)[:, None] * n
    outliers = rng.uniform(-30, 30, (100, 2))
    allp = np.vstack([pts, outliers])
    c, dd = refine_line(allp, np.ones(len(allp)), theta + np.deg2rad(2.0),
                        float(np.array([5.0, 12.0]) @ n) + 0.5, (1.5, 0.5))
    assert abs(dd @ d) > np.cos(np.deg2rad(0.2))
    assert abs((c - np.array([5.0, 12.0])) @ n) < 0.05


def test_refine_line_agrees_with_numpys_weighted_covariance():
    """Each pass is the weighted principal axis of the points in its band: numpy's cov with
    those weights (another normalisation, the same axis) on the points the band selects."""
    rng = np.random.default_rng(7)
    theta = np.deg2rad(128.0)
    d = np.array([np.cos(theta), np.sin(theta)])
    n = np.array([-d[1], d[0]])
    t = rng.uniform(-15, 15, 300)
    pts = np.vstack([np.array([20.0, 9.0]) + t[:, None] * d
                     + rng.normal(0, 0.3, 300)[:, None] * n, rng.uniform(0, 40, (700, 2))])
    w = rng.uniform(0.1, 1.0, len(pts))
    rho = float(np.array([20.0, 9.0]) @ n) + 0.3
    c, dd = refine_line(pts, w, theta, rho, (1.5,))
    sel = np.abs(pts @ n - rho) <= 1.5
    want_c = np.average(pts[sel], axis=0, weights=w[sel])
    want_d = np.linalg.eigh(np.cov(pts[sel].T, aweights=w[sel]))[1][:, 1]
    np.testing.assert_allclose(c, want_c, atol=1e-9)
    assert abs(dd @ want_d) == pytest.approx(1.0, abs=1e-12)
    assert refine_line(pts[:1], w[:1], theta, rho, (1.5,)) is None  # one point: no line


def test_a_line_meets_the_map_box_where_its_slabs_overlap():
    wm = WorkingMap(np.zeros((51, 101), np.float32), -10.0, 0.0, 0.2)  # x -10..10, z 0..10
    for c, d, want in [((0.0, 5.0), (1.0, 0.0), (-10.0, 10.0)),     # across, along x only
                       ((3.0, 2.0), (0.0, -1.0), (-8.0, 2.0)),      # along z only, upwards
                       ((0.0, 0.0), (0.6, 0.8), (0.0, 12.5)),       # corner to the far edge
                       ((0.0, 20.0), (1.0, 0.0), None)]:             # below the map
        seg = line_segment(wm, np.array(c), np.array(d), 0.5, LineSearchParams())
        if want is None:
            assert seg.reason == "the line misses the image"
            continue
        profile_mm = (len(seg.profile) - 1) * 0.2 if seg.profile is not None else None
        assert not seg and profile_mm == pytest.approx(want[1] - want[0], abs=0.2 + 1e-9)


def test_segment_ends_where_the_evidence_ends():
    step = 0.2
    m = _draw_segment((200, 200), (5.0, 6.0), (30.0, 21.0), step, value=0.9, width_px=3)
    m[np.rint(15.0 / step).astype(int), :] = 0.0  # a gap of one pixel row: bridged
    wm = WorkingMap(m, 0.0, 0.0, step)
    d = np.array([25.0, 15.0]) / np.hypot(25, 15)
    seg = line_segment(wm, np.array([5.0, 6.0]), d, 0.5, LineSearchParams())
    ends = sorted([seg.start_mm, seg.end_mm], key=lambda p: p[0])
    assert np.linalg.norm(ends[0] - [5.0, 6.0]) < 2 * step
    assert np.linalg.norm(ends[1] - [30.0, 21.0]) < 2 * step
    assert seg.support == pytest.approx(0.9, abs=0.1)


@pytest.mark.parametrize("dip_mm,reach_mm", [(0.0, 20.0), (1.4, 20.0), (3.0, 12.0)])
def test_a_segment_continues_on_weaker_evidence_until_a_gap_wider_than_gap_mm(dip_mm, reach_mm):
    # strong 0.9 from x = 2 to 10 mm, weak 0.35 on to 20 mm, with a dip to 0.1 at x = 12 mm;
    # a dip within gap_mm (2 mm) is bridged, a wider one ends the continuation
    step = 0.2
    m = _draw_segment((60, 150), (2.0, 5.0), (10.0, 5.0), step, value=0.9, width_px=3)
    m = np.maximum(m, _draw_segment(m.shape, (10.0, 5.0), (20.0, 5.0), step, 0.35, 3))
    if dip_mm:
        m[:, int(round(12.0 / step)):int(round((12.0 + dip_mm) / step))] = 0.1
    wm = WorkingMap(m, 0.0, 0.0, step)
    p = LineSearchParams()
    seg = line_segment(wm, np.array([2.0, 5.0]), np.array([1.0, 0.0]), 0.5, p)
    assert seg.end_mm[0] == pytest.approx(10.0, abs=2 * step)
    longer = extend_end(wm, seg, 0.25, p)
    assert longer.end_mm[0] == pytest.approx(reach_mm, abs=2 * step)
    assert np.allclose(longer.start_mm, seg.start_mm)
    assert (longer.support, longer.score) == (seg.support, seg.score)
    assert extend_end(wm, seg, 0.4, p).end_mm[0] == pytest.approx(10.0, abs=2 * step)


@pytest.mark.parametrize("a,b", [((2.0, 0.0), (30.0, 25.0)), ((38.0, 0.0), (10.0, 4.0)),
                                 ((0.0, 10.0), (36.0, 12.5)), ((20.0, 0.0), (21.0, 35.0))])
def test_finds_a_needle_at_any_direction_among_clutter(a, b):
    step = 0.2
    rng = np.random.default_rng(2)
    m = rng.uniform(0.0, 0.45, (200, 200)).astype(np.float32)  # below the needle level
    m += _draw_segment(m.shape, a, b, step, value=0.5, width_px=3)
    seg = find_needle_line(WorkingMap(m, 0.0, 0.0, step), 0.5, LineSearchParams())
    assert seg
    ends = {tuple(np.round(seg.start_mm, 1)), tuple(np.round(seg.end_mm, 1))}
    for p in (a, b):
        assert min(np.linalg.norm(np.subtract(p, e)) for e in ends) < 1.0


def test_nothing_found_on_a_map_below_the_level():
    rng = np.random.default_rng(3)
    m = rng.uniform(0.0, 0.2, (100, 100)).astype(np.float32)
    seg = find_needle_line(WorkingMap(m, 0.0, 0.0, 0.2), 0.5, LineSearchParams())
    assert not seg and "fewer than two pixels" in seg.reason


def test_a_needle_beside_a_broad_interface_is_found_on_a_later_vote():
    """A bright band running edge to edge (an interface, 2.2 mm thick) holds every one of the
    strongest pixels, so every peak of the first vote lies on it and is rejected; the needle
    (a 15 mm segment, weaker, 6 mm away) is found once the band's pixels are set aside."""
    step = 0.2
    m = np.zeros((200, 200), np.float32)
    m = np.maximum(m, _draw_segment(m.shape, (0.0, 10.0), (39.8, 30.0), step, 1.0, 11))
    a, b = (4.0, 0.0), (16.0, 9.0)  # a needle entering through the top edge
    m = np.maximum(m, _draw_segment(m.shape, a, b, step, 0.7, 3))
    wm = WorkingMap(m, 0.0, 0.0, step)

    def is_valid(seg):  # the tracker rejects the interface (it shows no tip)
        d = np.array([39.8, 20.0]) / np.hypot(39.8, 20.0)
        n = np.array([-d[1], d[0]])
        off = [abs(n @ np.subtract(e, (0.0, 10.0))) for e in (seg.start_mm, seg.end_mm)]
        return "interface" if max(off) < 1.5 else ""

    first_only = find_needle_line(wm, 0.5, LineSearchParams(max_points=400, votes=1),
                                  is_valid=is_valid)
    assert not first_only and first_only.reason == "interface"
    seg = find_needle_line(wm, 0.5, LineSearchParams(max_points=400), is_valid=is_valid)
    assert seg
    ends = [seg.start_mm, seg.end_mm]
    for p in (a, b):
        assert min(np.linalg.norm(np.subtract(p, e)) for e in ends) < 1.0


def test_votes_on_the_edge_of_a_rho_window_stay_in_the_accumulator():
    """Points whose offset lies within float32 rounding of the window's upper end, where a test
    on the offset and the bin index computed from it could disagree, are counted in the last
    bin or dropped, never put past the accumulator (a window found by a search over seeded
    windows; the bin index once overflowed on it)."""
    rng = np.random.default_rng(0)
    thetas = np.deg2rad(np.arange(0.0, 9.0))
    lo, hi, bin_mm = -8.000053025193367, -0.7068962525368749, 0.4
    n_bins = int(np.ceil((hi - lo) / bin_mm)) + 1
    edge = np.float32(lo + n_bins * bin_mm)
    for _ in range(200):
        rho = (edge - rng.uniform(0, 3e-6, 50)).astype(np.float32)
        pts = np.stack([np.zeros_like(rho), rho], -1).astype(float)  # theta 0: rho = z
        out = hough_peaks(pts, np.ones(len(pts)), thetas, bin_mm, 1, (lo, hi))
        assert np.all((out[:, 1] >= lo) & (out[:, 1] <= lo + n_bins * bin_mm))


def test_best_run_agrees_with_scipys_binary_closing_and_label_sums():
    """The best run of a thresholded profile with gaps of up to ``gap`` samples bridged: of
    the labelled runs of scipy's binary closing with a (gap + 1)-sample element, the one
    with the largest profile sum over it (the first of equal sums), and that sum."""
    rng = np.random.default_rng(3)
    for _ in range(500):
        n, gap = int(rng.integers(1, 120)), int(rng.integers(1, 12))
        prof = rng.random(n).astype(np.float32)
        level = np.float32(rng.random())
        on = prof >= level
        i0, i1, total = _best_run(prof, level, gap)
        if not on.any():
            assert (i0, i1) == (-1, -1)
            continue
        closed = ndimage.binary_closing(np.pad(on, gap), np.ones(gap + 1, bool))[gap:-gap]
        labels, k = ndimage.label(closed)
        sums = ndimage.sum_labels(prof.astype(float), labels, np.arange(1, k + 1))
        best = int(np.argmax(sums)) + 1
        run = np.flatnonzero(labels == best)
        assert (i0, i1) == (int(run[0]), int(run[-1]))
        assert total == pytest.approx(sums[best - 1], rel=1e-12)


def test_votes_counted_in_blocks_of_directions_equal_one_accumulator():
    """More (point, direction) votes than one block holds: the peaks of the blocked count
    equal those of one bincount over every vote, and a line's votes are its points' weights."""
    rng = np.random.default_rng(4)
    n = 2 * _VOTE_BLOCK // 90 + 7  # three blocks of the 90 directions
    pts = rng.uniform(0, 40, (n, 2))
    pts[:200] = np.linspace([5.0, 5.0], [35.0, 25.0], 200)  # a line among the clutter
    w = rng.uniform(0.5, 1.0, n)
    thetas = np.deg2rad(np.arange(0.0, 180.0, 2.0))
    out = hough_peaks(pts, w, thetas, 0.4, 3)
    normals = np.stack([-np.sin(thetas), np.cos(thetas)], -1).astype(np.float32)
    rho = pts.astype(np.float32) @ normals.T
    lo, hi = float(rho.min()), float(rho.max())
    n_bins = int(np.ceil((hi - lo) / 0.4)) + 1
    b = np.floor((rho - lo) * (1.0 / 0.4)).astype(int) + np.arange(90) * n_bins
    acc = np.bincount(b.ravel(), np.repeat(w.astype(np.float32), 90), 90 * n_bins)
    acc = ndimage.uniform_filter1d(acc.reshape(90, n_bins), 3, axis=1, mode="constant") * 3
    ia, ib = np.unravel_index(np.argmax(acc), acc.shape)
    assert out[0, 0] == pytest.approx(thetas[ia])
    assert out[0, 1] == pytest.approx(lo + (ib + 0.5) * 0.4)
    assert out[0, 2] == pytest.approx(acc.max(), rel=1e-6)
    assert out[0, 2] >= w[:200].sum() * 0.9


def test_the_rho_neighbours_are_summed_as_scipys_uniform_filter():
    """The accumulator's three-bin sums equal scipy's ``uniform_filter1d(..., 3) * 3`` to the
    bit (its running sum's rounding), on rows of 1 to 300 bins holding sums of float32
    weights as the votes do."""
    rng = np.random.default_rng(11)
    for _ in range(300):
        n, m = int(rng.integers(1, 30)), int(rng.integers(1, 300))
        acc = np.zeros((n, m))
        for _ in range(int(rng.integers(1, 1500))):
            acc[rng.integers(n), rng.integers(m)] += np.float64(np.float32(rng.random()))
        want = ndimage.uniform_filter1d(acc, 3, axis=1, mode="constant") * 3.0
        np.testing.assert_array_equal(_box3(acc), want)
