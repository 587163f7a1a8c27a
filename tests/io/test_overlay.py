"""The overlay's 2D frames draw the reported tip's 95% region: the ellipse of Mahalanobis
distance sqrt(chi2_2(0.95)) = 2.448 about the tip, in the frame's millimetres."""

import numpy as np
import pytest
from scipy.stats import chi2

import synth
from needlenet.io import overlay_frames
from needlenet.io._overlay import tip_region_mm
from needlenet.trackers import NeedleEstimate, Status

RED = np.array([40, 40, 255])


@pytest.fixture(scope="module")
def seq():
    # 0.2 mm pixels, depth 20 mm, width 16 mm: 100 x 80 pixels
    return synth.generate("inplane", seed=5, frames=1, width_mm=16.0, depth_mm=20.0,
                          spacing_mm=0.2, background="homogeneous", needle_free=True)


def test_the_region_is_the_95_percent_ellipse_of_the_covariance():
    C = np.array([[4.0, 1.2], [1.2, 1.0]])
    tip = np.array([3.0, 10.0])
    pts = tip_region_mm(tip, C, n=200)
    y = pts - tip
    d2 = np.einsum("ni,ij,nj->n", y, np.linalg.inv(C), y)
    assert np.allclose(d2, chi2.ppf(0.95, 2))  # every point on the 95% boundary
    # its half-axes: 2.448 standard deviations along the covariance's eigenvectors
    far = np.linalg.norm(y, axis=1).max()
    assert far == pytest.approx(np.sqrt(chi2.ppf(0.95, 2) * np.linalg.eigvalsh(C).max()),
                                rel=1e-3)


@pytest.mark.parametrize("cov", [None, np.eye(3), np.array([[1.0, 0], [0, np.nan]]),
                                 np.array([[1.0, 0], [0, -1.0]])])
def test_no_region_for_what_is_no_covariance(cov):
    assert tip_region_mm(np.zeros(2), cov) is None


def _red_pixels(img):
    return np.argwhere(np.all(np.abs(img.astype(int) - RED) < 60, axis=2))


def test_the_overlay_draws_the_region_around_the_tip(seq):
    g = seq.grid()
    tip = np.array([0.0, 10.0])  # the middle of the frame: (row, col) (50, 40)
    sd = 1.0  # mm: a circle of 2.448 mm = 12.2 pixels at 0.2 mm
    # no direction: the line drawn back along the needle would cross the ring
    est = NeedleEstimate(t=0.0, status=Status.TRACKING, tip_mm=tip, covariance=np.eye(2) * sd ** 2)
    img = overlay_frames(seq, [est], max_size=100)[0]
    assert img.shape[:2] == seq.images.shape[1:3]  # 100 x 80, drawn at scale 1
    centre = g.points_to_index(tip) + 0.5
    r = np.hypot(*(_red_pixels(img) - centre).T)
    radius = np.sqrt(chi2.ppf(0.95, 2)) * sd / 0.2
    ring = r[r > 6]  # away from the cross marking the tip (8 pixels wide)
    assert ring.size > 40
    assert np.all(np.abs(ring - radius) < 1.6)  # on the circle, within the line's width
    # without a covariance: the cross and the direction line only, no ring
    bare = NeedleEstimate(t=0.0, status=Status.TRACKING, tip_mm=tip)
    r0 = np.hypot(*(_red_pixels(overlay_frames(seq, [bare], max_size=100)[0]) - centre).T)
    assert r0.size > 0 and r0.max() < 6  # the cross alone
