"""Scenarios: labels sit on the needle, seeds reproduce files, bad parameters are named."""

import numpy as np
import pytest

import synth
from synth._render import tube_distances


def _mean_near(img, grid, pts, radius):
    idx, _ = tube_distances(grid, pts, radius)
    return float(img.reshape(-1)[idx].mean())


def _segment(p0, d, a, b, n=40):
    t = np.linspace(a, b, n)[:, None]
    return p0[None] + t * d[None]


@pytest.fixture(scope="module")
def inplane():
    return synth.generate("inplane", seed=3, frames=6, width_mm=25.0, depth_mm=30.0,
                          angle_deg=35.0, speed_mm_s=10.0, start_length_mm=20.0,
                          background="homogeneous")


def test_inplane_labels_on_the_needle(inplane):
    s = inplane
    g = s.grid()
    i = s.n_frames - 1
    assert s.visible[i]
    cl = s.centerline_mm[i]
    cl = cl[np.abs(cl[:, 1]) < 0.5][:, [0, 2]]
    on = _mean_near(s.images[i], g, cl, 0.3)
    bg = float(np.median(s.images[i]))
    assert on > 1.5 * bg
    # the labelled tip is where the bright shaft ends
    tip, d = s.tip_mm[i], s.direction[i]
    before = _mean_near(s.images[i], g, _segment(tip, d, -3.0, -0.8), 0.3)
    after = _mean_near(s.images[i], g, _segment(tip, d, 1.0, 3.0), 0.3)
    assert before > 1.5 * after
    # tip advances at the insertion speed along the labelled direction
    step = np.linalg.norm(np.diff(s.tip_mm, axis=0), axis=1)
    assert step == pytest.approx(np.full(s.n_frames - 1, 10.0 / 20.0), abs=1e-6)
    assert np.allclose(np.linalg.norm(s.direction, axis=1), 1.0)


def test_inplane_geometry_matches_mathiassen(inplane):
    s = inplane
    assert s.modality == "inplane"
    assert tuple(s.spacing_mm) == (0.1, 0.1)
    assert np.allclose(np.diff(s.timestamps_s), 0.05)  # 20 frames/s
    d = s.direction[0]
    assert np.degrees(np.arctan2(d[1], -d[0])) == pytest.approx(35.0, abs=1e-6)
    assert s.meta["needle"]["gauge"] == 14
    assert s.meta["needle"]["radius_mm"] == pytest.approx(2.108 / 2)


def test_same_seed_same_file(tmp_path):
    kw = dict(frames=2, width_mm=12.0, depth_mm=15.0, start_length_mm=12.0)
    a = synth.save_sequence(synth.generate("inplane", seed=5, **kw), tmp_path / "a.npz")
    b = synth.save_sequence(synth.generate("inplane", seed=5, **kw), tmp_path / "b.npz")
    c = synth.generate("inplane", seed=6, **kw)
    assert a.read_bytes() == b.read_bytes()
    assert not np.array_equal(synth.load_sequence(a).images, c.images)


def test_axial_cross_section_and_lost_plane():
    s = synth.generate("axial", seed=2, frames=8, width_mm=16.0, depth_mm=30.0,
                       background="homogeneous")
    g = s.grid()
    assert s.modality == "axial" and s.visible.all()
    for i in (0, s.n_frames - 1):
        on = _mean_near(s.images[i], g, s.tip_mm[i][None], 0.3)
        assert on > 1.5 * float(np.median(s.images[i]))
    # the probe is stepped 0.5 mm along the insertion per frame
    assert np.allclose(np.diff(s.probe_pose[:, 1, 3]), 0.5, atol=0.01)
    # slice 1 mm ahead of the tip: the needle is not in the plane, nothing bright there
    ahead = synth.generate("axial", seed=2, frames=3, width_mm=16.0, depth_mm=30.0,
                           background="homogeneous", plane_lag_mm=-1.5)
    assert not ahead.visible.any()
    xz = ahead.tip_3d_mm[-1][[0, 2]]
    near = _mean_near(ahead.images[-1], g, xz[None], 0.3)
    assert near < 1.3 * float(np.median(ahead.images[-1]))


def test_axial_interface_is_a_line_across_every_slice():
    """A bright interface along the insertion axis, 4 mm under the needle and tilted 15
    degrees: every slice shows it as a line through the point 4 mm under the needle along the
    plane's normal, rising with the tilt; 3 mm off that line, only speckle."""
    kw = dict(frames=4, width_mm=20.0, depth_mm=30.0, background="homogeneous",
              needle_depth_mm=10.0, interface_offset_mm=4.0, interface_tilt_deg=15.0,
              interface_brightness=4.0)
    s = synth.generate("axial", seed=5, **kw)
    g = s.grid()
    t = np.deg2rad(15.0)
    n = np.array([-np.sin(t), np.cos(t)])  # (x, z) normal, pointing deeper
    entry = s.tip_mm[0]  # the needle's crossing, 0.75 mm from its entry: bent < 0.01 mm

    def band(offset):
        x = np.linspace(-8.0, 8.0, 40)
        c = float(n @ entry) + offset
        return np.stack([x, (c - n[0] * x) / n[1]], 1)

    for i in (0, s.n_frames - 1):
        med = float(np.median(s.images[i]))
        assert _mean_near(s.images[i], g, band(4.0), 0.2) > 1.4 * med
        assert _mean_near(s.images[i], g, band(7.0), 0.2) < 1.15 * med
    with pytest.raises(ValueError, match="interface_tilt_deg"):
        synth.generate("axial", seed=5, **{**kw, "interface_tilt_deg": 85.0})


def test_inplane_interface_echo_is_a_specular_line_at_its_offset_and_tilt():
    """An interface 3 mm under a 30-degree needle, turned 10 degrees, with a specular echo:
    a bright line on that boundary 15-30 mm along from the entry (past the needle's tip), as
    the diffuse boundary alone is not; 1 mm either side and along the untilted line, only
    speckle. Bad values are refused by name."""
    kw = dict(frames=2, width_mm=30.0, depth_mm=30.0, angle_deg=30.0,
              background="homogeneous", interface_offset_mm=3.0, interface_brightness=1.0,
              interface_tilt_deg=10.0, start_length_mm=8.0)
    reads = {}
    for echo in (0.0, 40.0):
        s = synth.generate("inplane", seed=4, interface_echo=echo, **kw)
        g, img = s.grid(), s.images[-1]
        med = float(np.median(img))
        entry = s.centerline_mm[0][0][[0, 2]]
        u0 = np.asarray(s.direction[0], float)
        u0 /= np.linalg.norm(u0)
        t = np.deg2rad(10.0)
        u = np.array([u0[0] * np.cos(t) - u0[1] * np.sin(t),
                      u0[0] * np.sin(t) + u0[1] * np.cos(t)])

        def line(direction, offset, a0=15.0, a1=30.0, entry=entry):
            n = np.array([-direction[1], direction[0]])
            n = n if n[1] >= 0 else -n
            return _segment(entry + offset * n, direction, a0, a1)

        reads[echo] = [_mean_near(img, g, line(u, off), 0.15) / med for off in (3.0, 2.0, 4.0)]
        reads[echo].append(_mean_near(img, g, line(u0, 3.0, 25.0, 30.0), 0.15) / med)
    on, below, above, untilted = reads[40.0]
    assert on > 1.8 and on > 1.4 * reads[0.0][0]
    assert max(below, above, untilted) < 1.15
    for bad in (dict(interface_echo=-1.0), dict(interface_roughness=1.5),
                dict(interface_tilt_deg=90.0)):
        with pytest.raises(ValueError, match=next(iter(bad))):
            synth.generate("inplane", seed=4, **{**kw, **bad})


def test_a_boundary_echo_above_the_needles_crop_renders():
    """A training world whose boundary lies 6.4 mm above a shallow needle near the skin: its
    echo crop started below the echo itself, and OpenCV was asked to blur an empty image."""
    kw = dict(background="inhomogeneous", noise_db=-49.3, dynamic_range_db=62.3,
              scatterers_per_cell=12.8, gauge=20, needle_echo=19.8,
              imaging_overrides={"center_frequency_mhz": 4.3, "fractional_bandwidth": 0.44,
                                 "f_number": 2.68, "tx_focus_mm": 18.2, "tx_f_number": 2.17,
                                 "elevation_f_number": 5.46, "elevation_focus_mm": 11.6,
                                 "attenuation_db_cm_mhz": 0.83, "tgc_compensation": 0.81,
                                 "tissue_gray": 65.7},
              needle_overrides={"specular_width_deg": 17.5, "diffuse_floor": 0.33,
                                "reverb_decay": 0.41, "reverb_count": 5, "shadow_factor": 0.27,
                                "tip_gain": 2.46},
              angle_deg=19.7, speed_mm_s=11.7, spacing_mm=0.273, width_mm=32.64,
              depth_mm=31.53, start_length_mm=3.72, stop_length_mm=33.72,
              out_of_plane_deg=2.16, elevation_offset_mm=0.03, interface_offset_mm=-6.44,
              interface_brightness=2.41, interface_factor=1.07, interface_echo=46.8,
              interface_roughness=0.23, interface_tilt_deg=11.97)
    seq = synth.generate("inplane", seed=10_000_031, frames=1, **kw)
    assert seq.images.shape == (1, 115, 120) and seq.images.max() > seq.images.min()


def test_volume_interface_is_a_bright_plane_along_the_needle():
    """A bright interface holding the needle's axis, rolled 10 degrees about it and moved 3 mm
    along its normal: the volume is bright on that plane beside the needle, not 3 mm off it."""
    s = synth.generate("volume", seed=2, frames=1, output_size=64, alpha_deg=30, cr=None,
                       zhao_mode=False, background="homogeneous", interface_offset_mm=3.0,
                       interface_roll_deg=10.0, interface_brightness=4.0)
    g = s.grid()
    u, entry = s.direction[0], s.entry_mm[0]
    across = np.cross(u, [0.0, 0.0, 1.0])
    across /= np.linalg.norm(across)
    roll = np.deg2rad(10.0)
    v = np.cos(roll) * across + np.sin(roll) * np.cross(u, across)
    n = np.cross(u, v)
    n = n if n[2] >= 0 else -n

    def plane(offset):  # points on the plane moved ``offset`` along n, beside the needle
        a, b = np.meshgrid(np.linspace(2.0, 10.0, 9), np.linspace(-4.0, 4.0, 9))
        pts = entry + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v + offset * n
        idx = np.rint(g.points_to_index(pts)).astype(int)
        ok = np.all((idx >= 0) & (idx < np.array(g.shape)), axis=1)
        vals = s.images[0][tuple(idx[ok].T)].astype(float)
        return vals[vals > 0].mean()  # inside the sector

    assert plane(3.0) > 1.3 * plane(6.0)
    with pytest.raises(ValueError, match="interface_roll_deg"):
        synth.generate("volume", seed=2, frames=1, output_size=32, interface_offset_mm=3.0,
                       interface_roll_deg=85.0)


def test_needle_free_volume_has_no_needle_and_the_same_tissue():
    kw = dict(seed=2, frames=2, output_size=40, cr=None, zhao_mode=False)
    empty = synth.generate("volume", needle_free=True, **kw)
    with_needle = synth.generate("volume", **kw)
    assert not empty.visible.any() and with_needle.visible.all()
    # the same tissue: the volumes differ only around the needle (its echo, shadow, tail)
    differ = np.abs(empty.images.astype(int) - with_needle.images.astype(int)) > 2
    assert 0 < differ.mean() < 0.05
    with pytest.raises(ValueError, match="needle_free"):
        synth.generate("volume", seed=2, frames=1, output_size=32, cr=2.5, needle_free=True)


def test_zhao_volume_contrast_ratio_and_labels():
    s = synth.generate("volume", seed=1, frames=3, cr=2.5, alpha_deg=30.0, output_size=96,
                       background="homogeneous")
    assert s.modality == "volume" and s.images.shape[1:] == (96, 96, 96)
    assert s.visible.all()
    assert np.allclose(s.contrast_ratio, 2.5, rtol=0.05)  # Zhao eq. (9), within 5%
    g = s.grid()
    i = s.n_frames - 1
    on = _mean_near(s.images[i], g, s.centerline_mm[i], 0.3)
    roi, d = tube_distances(g, s.centerline_mm[i], 2.5)
    bg = float(s.images[i].reshape(-1)[roi[d > 1.0]].mean())
    assert on > 2.0 * bg
    tip, u = s.tip_mm[i], s.direction[i]
    after = _mean_near(s.images[i], g, _segment(tip, u, 1.0, 3.0), 0.3)
    assert on > 1.8 * after
    # Zhao eq. (4): beta = arccos(u_z) = 73 degrees, alpha = arctan(u_y / u_x) = 30 degrees
    assert np.degrees(np.arccos(u[2])) == pytest.approx(73.0, abs=1e-6)
    assert np.degrees(np.arctan2(u[1], u[0])) == pytest.approx(30.0, abs=1e-6)


def test_zhao_contrast_ratio_on_inhomogeneous_background():
    s = synth.generate("volume", seed=2, frames=2, cr=2.0, output_size=64)
    assert np.allclose(s.contrast_ratio, 2.0, rtol=0.05)


def test_zhao_needle_intensity_default():
    s = synth.generate("volume", seed=4, frames=1, cr=None, output_size=64, alpha_deg=0.0,
                       start_length_mm=20.0)
    g = s.grid()
    idx, _ = tube_distances(g, s.centerline_mm[0], s.meta["needle"]["radius_mm"])
    v = s.images[0].reshape(-1)[idx].astype(float)
    assert v.mean() == pytest.approx(140.0, abs=4.0)  # N(140, 28) on 8 bits
    assert v.std() == pytest.approx(28.0, abs=5.0)


def test_physical_volume_needle_is_bright():
    s = synth.generate("volume-motion", seed=1, frames=4, output_size=64, motion_mm=2.0,
                       scatterers_per_cell=4.0)
    g = s.grid()
    i = s.n_frames - 1
    assert s.visible[i]
    on = _mean_near(s.images[i], g, s.centerline_mm[i], 0.3)
    roi, d = tube_distances(g, s.centerline_mm[i], 3.0)
    bg = float(s.images[i].reshape(-1)[roi[d > 1.5]].mean())
    assert on > 1.5 * bg


def test_servo_follows_ye_profile():
    s = synth.generate("servo", seed=0, frames=12, start_sample=300, width_mm=16.0,
                       depth_mm=30.0)
    v = synth._scenarios.ye_insertion_velocity(2000)
    k = np.arange(2000)
    planned = v - 0.025 * np.sin(2 * np.pi * k / 25.0 / 20.0)  # minus the 20 s perturbation
    assert planned[99] == pytest.approx(1.98) and planned[100:500] == pytest.approx(2.0)
    assert planned[500:1500] == pytest.approx(3.0) and planned[1500:] == pytest.approx(2.0)
    assert s.visible.all()  # the plane trails the tip by 0.5 mm: the shaft crosses it
    assert np.allclose(s.timestamps_s, (300 + np.arange(12)) / 25.0)
    # labels in the probe frame: the cross-section sits near the lateral centre
    assert np.all(np.abs(s.tip_mm[:, 0]) < 1.0)


@pytest.mark.parametrize("name,kw,msg", [
    ("nope", {}, "unknown scenario"),
    ("inplane", {"speed_mm_s": -1.0}, "speed_mm_s must be positive"),
    ("volume", {"cr": 0.5}, "cr"),
    ("inplane", {"background": "noisy"}, "background"),
    ("inplane", {"frames": 0}, "frames"),
    ("inplane", {"gauge": 99}, "gauge"),
    ("axial", {"wobble": 1}, "no parameter 'wobble'"),
])
def test_bad_parameters_are_named(name, kw, msg):
    with pytest.raises(ValueError, match=msg):
        synth.generate(name, **kw)


def test_bicycle_path_is_an_arc_with_a_turn():
    R = 500.0
    path = synth.NeedlePath(entry=np.zeros(3), direction=[0, 1, 0], radius_of_curvature_mm=R,
                            bend_direction=[1, 0, 0], turn_lengths_mm=(40.0,))
    v = np.linspace(0, 30, 31)
    p = path.point_at(v)
    # before the turn: u = R - sqrt(R^2 - v^2) (Carriere 2016 eq. 3 with theta0 = 0)
    expected = R - np.sqrt(R**2 - p[:, 1] ** 2)
    assert np.allclose(p[:, 0], expected, atol=1e-3)
    # after the 180-degree bevel rotation the curvature flips: the slope starts to decrease
    t = path.tangent_at(np.array([39.0, 41.0, 60.0]))
    assert t[1, 0] > t[2, 0]


@pytest.mark.parametrize("name", ["inplane", "axial", "servo"])
def test_a_spacing_that_makes_absurd_frames_is_refused_before_allocating(name):
    """Issue 21: ``synth inplane --param spacing_mm=1e-6`` had reached 7.5 GB."""
    with pytest.raises(ValueError, match=r"spacing_mm=1e-06 over .* makes frames of .* pixels"):
        synth.generate(name, seed=0, frames=2, spacing_mm=1e-6)


@pytest.mark.parametrize("name", ["inplane", "volume"])
def test_insertion_lengths_are_checked_before_building(name):
    with pytest.raises(ValueError, match=r"need 0 <= start_length_mm < stop_length_mm"):
        synth.scenario_params(name, stop_length_mm=-1.0).validate()
