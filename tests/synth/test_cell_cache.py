"""A moving 3D probe images the tissue from cached cells: the same volumes as imaging every
scatterer directly, to float rounding; and the compiled blur, scan conversion and fast
arctangent/sine agree with the formulations they replace."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

import synth
from synth._blur import SPLAT_VAR, blur_axis
from synth._cell_cache import CellCache, near_cells
from synth._cell_kernels import _atan2, _cos_sin
from synth._geometry import invert_rigid, rigid_transform, rotation_matrix
from synth._render import render_sequence
from synth._scenarios import random_scattering_map, scenario_params


def _moving_phantom(cell_cache_mb=256.0, frames=4, seed=0):
    p = scenario_params("volume-motion", frames=frames, output_size=64,
                        scatterers_per_cell=3.0)
    scanner, traj = p.build(p.draw(np.random.default_rng(seed)))
    scanner.cell_cache_mb = cell_cache_mb
    return scanner, traj


def _transforms(traj):
    return np.stack([invert_rigid(pp) @ tp for pp, tp in
                     zip(traj.probe_pose, traj.tissue_pose, strict=True)])


def _rel_err(a, b):
    return float(np.abs(a - b).max() / np.sqrt(np.mean(b.astype(np.float64) ** 2)))


@pytest.fixture(scope="module")
def moving_sequences():
    out = []
    for mb in (256.0, 0.0):
        scanner, traj = _moving_phantom(mb)
        seq = render_sequence(scanner, traj, "volume", np.random.default_rng(5), {})
        out.append((scanner, traj, seq))
    return out


def test_moving_phantom_volumes_match_direct_imaging(moving_sequences):
    (cached, traj, a), (direct, _, b) = moving_sequences
    assert cached._cell_caches and not direct._cell_caches
    assert len(np.unique(_transforms(traj).round(6), axis=0)) == 4  # the phantom moves
    diff = np.abs(a.images.astype(int) - b.images.astype(int))
    assert diff.max() <= 1  # log compression to 8 bits may round the other way
    assert np.count_nonzero(diff) <= 1e-4 * diff.size
    np.testing.assert_array_equal(a.tip_mm, b.tip_mm)
    np.testing.assert_allclose(a.contrast_ratio, b.contrast_ratio, rtol=1e-3)


def test_cached_tissue_echo_matches_direct_echo():
    cached, traj = _moving_phantom()
    direct, _ = _moving_phantom(0.0)
    Ms = _transforms(traj)
    cached.prepare(Ms)
    for M in Ms[::-1]:  # any order: the cache holds every view of the trajectory
        assert _rel_err(cached.tissue_iq(M), direct.tissue_iq(M)) < 1e-5
    assert not direct._cell_caches


def test_cache_memory_is_bounded():
    cached, traj = _moving_phantom()
    cached.prepare(_transforms(traj))
    cache = cached._cell_caches[0]
    assert cache.nbytes <= cached.cell_cache_mb * 2**20
    # 16 bytes a scatterer and a small slot map
    assert cache.nbytes < 16 * cache.n_cells * cache.n_per_cell * 1.05 + 2**20
    small, _ = _moving_phantom(1.0)  # 1 MB holds too few cells: every volume is direct
    small.prepare(_transforms(traj))
    M = _transforms(traj)[2]
    small.tissue_iq(_transforms(traj)[1])
    iq = small.tissue_iq(M)
    assert not small._cell_caches
    ref, _ = _moving_phantom(0.0)
    np.testing.assert_array_equal(iq, ref.tissue_iq(M))
    with pytest.raises(ValueError, match="cell_cache_mb"):
        synth.Scanner(small.probe, small.params, small.world, cell_cache_mb=-1.0)


def test_static_probe_builds_no_cache():
    scanner, traj = _moving_phantom()
    M = _transforms(traj)[0]
    scanner.prepare(np.stack([M, M, M]))
    scanner.tissue_iq(M)
    assert not scanner._cell_caches


def _matrix_world(seed=1):
    p = synth.ImagingParams(center_frequency_mhz=3.5, scatterers_per_cell=3.0)
    probe = synth.MatrixProbe(shape=(40, 32, 32), spacing_mm=(0.5, 0.5, 0.5),
                              depth_start_mm=10.0)
    smap = random_scattering_map(np.random.default_rng(seed), [-20, -20, 0], [20, 20, 40],
                                 "inhomogeneous", plane_bias=False)
    dens = p.scatterer_density(probe.range_of_rows())
    return probe, p, synth.World(synth.Tissue(dens, seed, smap), None)


def test_matrix_probe_cache_follows_a_moving_view_without_prepare():
    """A servo loop does not know its poses in advance: the cache is built around the view
    once the probe moves, and moves with it (cells entered are generated, cells left are
    reused)."""
    probe, p, world = _matrix_world()
    cached = synth.Scanner(probe, p, world)
    direct = synth.Scanner(probe, p, world, cell_cache_mb=0.0)
    Ms = []
    for k, (shift, deg) in enumerate([(0.0, 0.0), (0.7, 2.0), (1.5, 4.0), (9.0, -3.0),
                                      (9.5, -6.0)]):
        R = rotation_matrix([0.2, 0.1, 1.0], np.deg2rad(deg))
        Ms.append(rigid_transform(R, [shift, -0.5 * k, 0.3 * k]))
    for i, M in enumerate(Ms):
        a = cached.tissue_iq(M)
        assert bool(cached._cell_caches) == (i > 0)  # the first view is imaged directly
        assert _rel_err(a, direct.tissue_iq(M)) < 1e-5
    cache = cached._cell_caches[0]
    # every held cell holds the scatterers the tissue generates for it, map applied
    held = cache.slot_cell[cache.lookup(cache.slot_cell) >= 0][::97]
    m = cache.n_per_cell
    pos, amp = world.tissue.cell_scatterers(held)
    slots = cache.lookup(held)
    np.testing.assert_array_equal(cache.xyz.reshape(3, -1, m)[:, slots], pos.T.reshape(3, -1, m))
    np.testing.assert_allclose(cache.amp.reshape(-1, m)[slots],
                               world.tissue.modulate(pos, amp).reshape(-1, m), rtol=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_near_cells_hold_every_scatterer_the_sector_sees(seed):
    rng = np.random.default_rng(seed)
    probe = synth.SectorProbe(output_shape=(32, 32, 32))
    tissue = synth.Tissue(2.0, seed)
    R = rotation_matrix(rng.normal(size=3), np.deg2rad(rng.uniform(0, 30)))
    M = rigid_transform(R, rng.uniform(-5, 5, 3))
    lo, hi = probe.region_box(1.0)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    ct = synth.apply_transform(invert_rigid(M), corners)
    cells = tissue.cells_in_box(ct.min(0), ct.max(0))
    near = near_cells(probe, tissue, cells, M, lo, hi)
    assert 0 < len(near) < len(cells)
    pos, _ = tissue.cell_scatterers(cells)
    idx = probe.to_beam_index(synth.apply_transform(M, pos.astype(np.float64)))
    q_z = synth.apply_transform(M, pos.astype(np.float64))[:, 2]
    seen = np.all((idx >= 0) & (idx < np.asarray(probe.beam_grid.shape) - 1), axis=1) & (q_z > 0)
    seen_cells = np.unique(np.floor(pos[seen] / tissue.cell_mm).astype(np.int64), axis=0)
    held = CellCache(tissue, near)
    assert np.all(held.lookup(seen_cells) >= 0)


def _anchor_blur(arr, axis, sigma_rows):
    """The depth-band blur as one Gaussian filter per anchor sigma, blended row by row."""
    s = np.sqrt(np.maximum(np.asarray(sigma_rows, float) ** 2 - SPLAT_VAR, 0.0))
    if axis == 0 or s.max() - s.min() < 0.05 * s.max():
        sig = float(np.median(s))
        return gaussian_filter1d(arr, sig, axis=axis, mode="constant", truncate=3.0)
    anchors = np.unique(np.round(np.linspace(s.min(), s.max(), 4), 3))
    pos = np.interp(s, anchors, np.arange(len(anchors)))
    out = np.zeros_like(arr)
    for k, a in enumerate(anchors):
        w = np.clip(1.0 - np.abs(pos - k), 0.0, 1.0).astype(np.float32)
        b = gaussian_filter1d(arr, a, axis=axis, mode="constant", truncate=3.0) \
            if a >= 0.05 else arr
        out += b * w.reshape((-1,) + (1,) * (arr.ndim - 1))
    return out


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_volume_blur_matches_anchor_blur(axis):
    rng = np.random.default_rng(axis)
    arr = rng.normal(size=(60, 21, 17, 2)).astype(np.float32)
    sigma = np.linspace(6.0, 0.6, 60) if axis else np.full(60, 0.8)
    out = blur_axis(arr, axis, sigma)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, _anchor_blur(arr, axis, sigma), atol=2e-6, rtol=0)


def test_scan_conversion_matches_corner_by_corner_sum():
    probe = synth.SectorProbe(output_shape=(48, 40, 44))
    data = np.random.default_rng(0).integers(0, 256, probe.beam_grid.shape).astype(np.uint8)
    out_index, base, f, strides = probe._scan_table
    flat = data.reshape(-1).astype(np.float32)
    acc = np.zeros(len(out_index), np.float32)
    for dz in (0, 1):
        for dy in (0, 1):
            for dx in (0, 1):
                w = ((f[:, 0] if dz else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1])
                     * (f[:, 2] if dx else 1 - f[:, 2]))
                acc += flat[base + dz * strides[0] + dy * strides[1] + dx] * w
    ref = np.zeros(int(np.prod(probe.output_shape)), np.float32)
    ref[out_index] = acc
    np.testing.assert_array_equal(probe.scan_convert(data), ref.reshape(probe.output_shape))


def test_fast_arctangent_and_sine_within_an_ulp_of_libm():
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(1e-9, 60.0, 20000), [1e-300, 1.0, 0.66, 2.414213562373095]])
    y = np.concatenate([rng.uniform(-60.0, 60.0, 20000), [0.0, -0.0, 0.66, 1.0]])
    got = np.array([_atan2(a, b) for a, b in zip(y, x, strict=True)])
    assert np.abs(got - np.arctan2(y, x)).max() <= 4.5e-16
    ph = np.concatenate([rng.uniform(-3000.0, 3000.0, 20000), np.pi / 4 * np.arange(16)])
    cs = np.array([_cos_sin(v) for v in ph])
    assert np.abs(cs[:, 0] - np.cos(ph)).max() <= 4.5e-16
    assert np.abs(cs[:, 1] - np.sin(ph)).max() <= 4.5e-16
