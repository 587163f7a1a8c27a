"""In-plane worlds beyond Mathiassen's protocol: either side, side entry, display masks,
image-formation options and needle-free worlds; labels stay where the needle is drawn."""

import numpy as np
import pytest

import synth
from synth._render import tube_distances


def _mean_near(img, grid, pts, radius):
    idx, _ = tube_distances(grid, pts, radius)
    return float(img.reshape(-1)[idx].mean())


def _shaft(seq, i, a_mm, b_mm, shift_mm=0.0):
    """Points along the labelled shaft from a_mm to b_mm behind the tip, moved shift_mm
    across it (positive: shallower)."""
    tip, u = seq.tip_mm[i], seq.direction[i]  # (x, z)
    nb = np.array([u[1], -u[0]])
    nb = nb if nb[1] < 0 else -nb  # across the shaft, towards the skin
    t = np.linspace(a_mm, b_mm, 40)[:, None]
    return tip[None] - t * u[None] + shift_mm * nb[None]


@pytest.mark.parametrize("kw", [
    {"side": "left", "angle_deg": 30.0},
    {"side": "right", "entry_edge": "side", "angle_deg": 8.0,
     "entry_depth_range_mm": (10.0, 12.0)},
    {"side": "left", "entry_edge": "side", "angle_deg": 20.0, "gauge": 24,
     "entry_depth_range_mm": (6.0, 8.0)},
])
def test_labels_follow_the_needle_from_either_side(kw):
    s = synth.generate("inplane", seed=1, frames=3, width_mm=30.0, depth_mm=30.0,
                       start_length_mm=18.0, speed_mm_s=10.0, background="homogeneous", **kw)
    g, i = s.grid(), s.n_frames - 1
    assert s.visible[i]
    # the needle points away from its side: x decreases entering from the right
    assert np.sign(s.direction[i][0]) == (-1.0 if kw["side"] == "right" else 1.0)
    if kw.get("entry_edge") == "side":  # it enters through the lateral border, at depth
        assert abs(s.entry_mm[i][0]) >= 15.0 and s.entry_mm[i][1] > 5.0
    r = s.meta["needle"]["radius_mm"]  # the echo is the wall facing the probe
    on = _mean_near(s.images[i], g, _shaft(s, i, 1.0, 8.0, shift_mm=r), 0.3)
    beside = _mean_near(s.images[i], g, _shaft(s, i, 1.0, 8.0, shift_mm=r + 2.5), 0.3)
    ahead = _mean_near(s.images[i], g, _shaft(s, i, -6.0, -1.5, shift_mm=r), 0.3)
    assert on > 1.5 * beside and on > 1.5 * ahead


def test_needle_free_world_has_no_needle():
    kw = dict(seed=2, frames=3, width_mm=25.0, depth_mm=25.0, start_length_mm=15.0,
              angle_deg=30.0, background="homogeneous")
    free = synth.generate("inplane", needle_free=True, **kw)
    assert not free.visible.any()
    lengths = np.linalg.norm(np.diff(free.centerline_mm, axis=1), axis=2).sum(1)
    assert np.all(lengths == 0.0)
    # the same world with its needle: the needle's pixels are bright there, not here
    with_needle = synth.generate("inplane", **kw)
    g = free.grid()
    cl = with_needle.centerline_mm[-1][:, [0, 2]]
    cl = cl[g.contains(cl)]
    assert _mean_near(with_needle.images[-1], g, cl, 0.2) > 1.5 * _mean_near(
        free.images[-1], g, cl, 0.2)


def test_display_masks_black_out_pixels_not_labels():
    kw = dict(seed=3, frames=2, width_mm=25.0, depth_mm=25.0, start_length_mm=12.0,
              angle_deg=35.0, speed_mm_s=10.0)
    plain = synth.generate("inplane", **kw)
    im = {"margin_mm": (2.0, 0.0, 3.0, 1.0), "sector_half_angle_deg": 30.0,
          "sector_apex_mm": 20.0}
    masked = synth.generate("inplane", imaging_overrides=im, **kw)
    mask = synth.display_mask(masked.grid(), synth.ImagingParams(**im))
    assert mask is not None and 0.3 < mask.mean() < 0.95
    assert np.all(masked.images[:, ~mask] == 0)
    np.testing.assert_array_equal(masked.images[:, mask], plain.images[:, mask])
    np.testing.assert_array_equal(masked.tip_mm, plain.tip_mm)  # the grid is unchanged
    g = masked.grid()
    assert not mask[:20].any() and not mask[:, :30].any()  # 2 mm top, 3 mm left at 0.1 mm
    # a tip under the black border is not visible
    hidden = synth.generate("inplane", imaging_overrides={"margin_mm": (0.0, 0.0, 0.0, 20.0)},
                            **kw)
    assert plain.visible.all() and g.contains(plain.tip_mm).all()
    assert not hidden.visible.any()


def test_gray_map_and_face_reverberation():
    p = synth.ImagingParams(gray_gamma=2.0, gray_offset=10.0, gray_white=200.0,
                            dynamic_range_db=60.0, tissue_gray=100.0)
    env = np.float32([1e-9, 10 ** (-2.507 / 20), 1e3])  # black, unit speckle's log mean, hot
    # 100 -> 255 (100 / 200)^2 + 10 = 73.75; saturated above 200 -> 265 -> 255
    np.testing.assert_array_equal(synth.log_compress(env, p), [10, 74, 255])
    s = synth.generate("inplane", seed=5, frames=1, width_mm=15.0, depth_mm=20.0,
                       start_length_mm=1.0, background="homogeneous",
                       imaging_overrides={"face_reverb_gain": 6.0,
                                          "face_reverb_spacing_mm": 1.5})
    rows = s.images[0].mean(axis=1)
    assert rows[15] > 1.5 * np.median(rows[60:])  # the first band, 1.5 mm under the face
    assert rows[15] > rows[30] > rows[45]  # each band fainter than the one before


def test_vessels_are_anechoic_and_shadows_darken_below():
    s = synth.generate("inplane", seed=6, frames=1, width_mm=30.0, depth_mm=30.0,
                       start_length_mm=1.0, background="homogeneous", vessels=1, shadows=1)
    g, img = s.grid(), s.images[0].astype(float)
    v = s.meta["draw"]["vessels"][0]
    c = np.array(v["center"])[[0, 2]]
    if g.contains(c[None])[0]:
        inside = _mean_near(img, g, c[None], 0.5 * v["radius_mm"])
        assert inside < 0.5 * np.median(img)
    sh = s.meta["draw"]["shadows"][0]
    a, b = np.array(sh["a"]), np.array(sh["b"])
    x = np.linspace(a[0] + 0.3, b[0] - 0.3, 10)
    x = x[(x > g.origin_mm[1]) & (x < -g.origin_mm[1])]
    below = np.stack([np.repeat(x, 5), np.tile(np.linspace(2, 6, 5), len(x))
                      + max(a[2], b[2])], -1)
    below = below[g.contains(below)]
    assert _mean_near(img, g, below, 0.2) < 0.8 * np.median(img)


def test_wide_options_are_deterministic_per_seed():
    kw = dict(frames=2, width_mm=20.0, depth_mm=20.0, start_length_mm=10.0, side=None,
              entry_edge=None, angle_deg=12.0, vessels=1, shadows=1, interface_offset_mm=2.0,
              imaging_overrides={"compound_looks": 2, "face_reverb_gain": 2.0,
                                 "tgc_curve_db": (3.0, -3.0, 0.0)},
              needle_overrides={"diffuse_fraction": 0.6, "diffuse_seed": 4})
    a = synth.generate("inplane", seed=9, **kw)
    b = synth.generate("inplane", seed=9, **kw)
    c = synth.generate("inplane", seed=10, **kw)
    np.testing.assert_array_equal(a.images, b.images)
    np.testing.assert_array_equal(a.tip_mm, b.tip_mm)
    assert a.meta["draw"] == b.meta["draw"]
    assert not np.array_equal(a.images, c.images)


@pytest.mark.parametrize("kw,msg", [
    ({"side": "up"}, "side"), ({"entry_edge": "bottom"}, "entry_edge"),
    ({"angle_deg": 95.0}, "angle_deg"),
    ({"imaging_overrides": {"margin_mm": (1.0, 2.0)}}, "margin_mm"),
    ({"imaging_overrides": {"compound_looks": 0}}, "compound_looks"),
])
def test_bad_wide_parameters_are_named(kw, msg):
    with pytest.raises(ValueError, match=msg):
        synth.generate("inplane", frames=1, **kw)
