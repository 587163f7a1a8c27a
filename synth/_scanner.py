"""Field-II-style image formation by the convolution model.

RF = scatterers convolved with the pulse-echo point spread function (PSF). We form the
demodulated (IQ) signal directly: every scatterer contributes ``a * exp(-2j k0 z)`` (its exact
two-way phase) times the PSF envelope centred on it. Scatterers are splatted onto the
acquisition grid with multilinear weights and the grid is convolved with a separable Gaussian
PSF: axially a Gaussian pulse of the given centre frequency and fractional bandwidth,
laterally and in elevation a Gaussian beam whose width depends on depth (transmit focus,
receive f-number, elevation lens). The splat kernel's own variance (1/6 px^2 per axis) is
subtracted from the blur so the effective PSF has the requested width. Then: two-way
attenuation (dB/cm/MHz) and time-gain compensation, electronic noise (added before TGC, so it
grows with depth), envelope detection (modulus of IQ), log compression to 8 bits over a stated
dynamic range.

Then what a scanner's display adds (defaults: none of it): spatial compounding (``compound_looks``
decorrelated speckle realisations averaged in intensity, which lowers the speckle's log
standard deviation from 5.57 dB to 3.49 dB for two looks and 2.73 dB for three, see
:func:`synth.speckle_log_std_db`), a TGC slider curve, reverberation bands between the probe
face and the skin, a grey map after log compression (gamma, offset, white level) and, on 2D
frames, black screen-capture margins and a sector (fan) mask.

The needle is a specular reflector, not a diffuse scatterer: its echo depends on the angle
between the beam and the shaft, it reverberates inside the shaft (a comet tail below it),
it shadows the tissue behind it, and its bevel tip reflects strongly.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from ._blur import SPLAT_VAR as _SPLAT_VAR
from ._blur import blur_axis as _blur_axis
from ._cell_cache import CellCache, cache_bytes, near_cells
from ._geometry import apply_transform, invert_rigid
from ._imaging import ImagingParams, display_mask, log_compress, speckle_log_mean_db
from ._kernels import transform_splat_field
from ._needle_echo import NeedleEcho
from ._needle_echo import needle_iq as _needle_iq
from ._world import World

__all__ = ["ImagingParams", "Scanner", "RenderedFrame", "NeedleEcho", "log_compress",
           "display_mask", "speckle_log_mean_db"]


def _key(a) -> bytes:
    """Cache key of a transform (or part of one): rounded to 1e-9 and with -0.0 made 0.0, so
    that the same pose computed two ways (e.g. an inverse of an inverse) gives the same key."""
    return (np.round(np.asarray(a, float), 9) + 0.0).tobytes()


def _field_key(R, tz) -> bytes:
    """Key of a plane probe's tissue field: the rotation and the depth offset it is exact for."""
    return _key(R) + _key(tz)


@dataclass
class RenderedFrame:
    """One frame: the 8-bit image and the scanner internals that labels and tests use."""

    image: np.ndarray  # uint8 on the probe's image grid
    envelope: np.ndarray  # float32 envelope on the beam grid (unit speckle RMS 1)
    needle_gain: float


class Scanner:
    """Images a :class:`World` with a probe, from any probe pose, frame after frame.

    The tissue echo of a given tissue-to-probe transform is cached: when neither the probe
    nor the tissue moved since the last frame (a static probe watching an insertion), only
    the needle, the shadow and the electronic noise are formed again.

    ``field_cache_size``: how many 3D tissue fields of a plane probe (see :meth:`prepare`)
    are kept, most recently built first; a field built on demand pushes the oldest out. A
    servo loop that prepares many fields along a long path raises it (the attribute may be
    changed at any time; it applies at the next on-demand build).

    A 3D probe whose tissue-to-probe transform changes (a moving phantom, a probe servo)
    keeps the tissue cells near its view (:class:`synth._cell_cache.CellCache`): their
    scatterers, with the scattering map applied, are generated once and only moved and
    splatted for each volume. ``cell_cache_mb`` bounds the memory of those cells (MiB, over
    all compounding looks; 0: image every volume directly).
    """

    # a 3D probe that moves without a prepared trajectory holds the cells within this
    # distance of its view; a view that moves further takes in the cells it enters
    _CELL_PAD_MM = 4.0

    def __init__(self, probe, params: ImagingParams, world: World, zhao_mode: bool = False,
                 field_cache_size: int = 8, cell_cache_mb: float = 256.0):
        self.probe = probe
        self.field_cache_size = field_cache_size
        if not np.isfinite(cell_cache_mb) or cell_cache_mb < 0:
            raise ValueError(f"cell_cache_mb must be >= 0, got {cell_cache_mb!r}")
        self.cell_cache_mb = float(cell_cache_mb)
        self._cell_caches: dict[int, CellCache] = {}
        self.params = params
        self.world = world
        self.zhao_mode = zhao_mode
        bg = probe.beam_grid
        self._rows_mm = probe.range_of_rows()
        self._px = probe.pixel_size_mm()
        p = params
        self._sig_ax_mm = np.full(len(self._rows_mm), p.sigma_axial_mm)
        self._sig_lat_mm = p.sigma_lateral_mm(self._rows_mm)
        self._sig_el_mm = p.sigma_elevation_mm(self._rows_mm)
        # PSF sigma per row in beam-grid pixels, per axis
        if probe.ndim == 2:
            self._sig_px = (self._sig_ax_mm / self._px[0], self._sig_lat_mm / self._px[1])
        else:
            self._sig_px = (self._sig_ax_mm / self._px[0], self._sig_el_mm / self._px[1],
                            self._sig_lat_mm / self._px[2])
        self._shape = bg.shape
        self._cache_key = None
        self._cache_iq = None
        self._last_M = None
        self._fields: list[dict] = []
        self._field_dy = float(min(0.25, 0.5 * self._sig_el_mm.min()))
        # Expected |IQ|^2 of unit tissue per row: n * voxel * integral of the squared kernel
        # (and, for a plane, the integral of the squared elevation profile).
        n = self.world.tissue.density_per_mm3
        eff = [np.sqrt(np.maximum(s**2, _SPLAT_VAR)) for s in self._sig_px]
        vox = np.prod(np.stack(self._px), axis=0)
        ksq = 1.0 / np.prod(np.stack([2.0 * np.sqrt(np.pi) * e for e in eff]), axis=0)
        if probe.ndim == 2:
            ref2 = n * vox * ksq * self._sig_el_mm * np.sqrt(np.pi)
        else:
            ref2 = n * vox * ksq
        self._ref = np.sqrt(ref2)
        att = p.two_way_attenuation(self._rows_mm)
        tgc = att ** (-p.tgc_compensation)
        if p.tgc_curve_db:
            z = self._rows_mm
            knots = np.linspace(z.min(), z.max(), len(p.tgc_curve_db))
            tgc = tgc * 10.0 ** (np.interp(z, knots, p.tgc_curve_db) / 20.0)
        # tissue and needle are scaled by att * tgc / ref; noise by tgc
        self._row_gain_signal = (att * tgc / self._ref).astype(np.float32)
        self._row_gain_noise = tgc.astype(np.float32)
        self._noise_sigma = 10.0 ** (p.noise_db / 20.0) / np.sqrt(2.0)
        self._noise_row_scale = self._rows_view(
            (self._noise_sigma * self._row_gain_noise).astype(np.float32))
        # compounding: look k > 0 images the same tissue (map) with its own scatterers
        t = self.world.tissue
        self._look_tissues = [t] + [dataclasses.replace(t, seed=(int(t.seed) * 7919 + k)
                                                        & 0x7FFFFFFFFFFFFFFF)
                                    for k in range(1, p.compound_looks)]
        self._look_cache: dict = {}
        self._face_reverb = self._face_reverb_iq()
        self._mask = display_mask(probe.grid, p)  # None for 3D grids

    @property
    def field_cache_size(self) -> int:
        return self._field_cache_size

    @field_cache_size.setter
    def field_cache_size(self, n: int) -> None:
        if isinstance(n, bool) or int(n) != n or n < 1:
            raise ValueError(f"field_cache_size must be a positive integer, got {n!r}")
        self._field_cache_size = int(n)

    # -- tissue -------------------------------------------------------------------------
    def _rows_view(self, v: np.ndarray) -> np.ndarray:
        return v.reshape((-1,) + (1,) * (len(self._shape) - 1) + (1,))

    def tissue_iq(self, tissue_to_probe: np.ndarray) -> np.ndarray:
        """Normalised tissue IQ on the beam grid (H, W[, D], 2).

        Three paths, all the same convolution model: an exact repeat of the last transform
        reuses the last image (static probe and tissue); a plane probe that only translated
        laterally or in elevation since the last frame samples a cached 3D field of the
        tissue echo (the field is exact for such translations, so stepping the probe along
        the needle, as Carriere 2016 and Ye 2025 do, costs one slice per frame); anything
        else is imaged from the scatterers (a moving 3D probe's from its cached cells).
        """
        M = np.asarray(tissue_to_probe, float)
        key = _key(M)
        if key == self._cache_key:
            return self._cache_iq
        last = self._last_M
        self._last_M = M
        if (self.probe.field_sliceable and last is not None
                and np.allclose(M[:3, :3], last[:3, :3], atol=1e-9)
                and abs(M[2, 3] - last[2, 3]) < 1e-9):
            iq = self._field_slice(M)
        else:
            iq = self._render_tissue(M, moved=last is not None)
            iq *= self._rows_view(self._row_gain_signal)
        self._cache_key, self._cache_iq = key, iq
        return iq

    def look_iq(self, tissue_to_probe: np.ndarray, look: int) -> np.ndarray:
        """Normalised tissue IQ of compounding look ``look`` (0: :meth:`tissue_iq`); other
        looks are imaged from the scatterers and the last one of each is kept."""
        if look == 0:
            return self.tissue_iq(tissue_to_probe)
        M = np.asarray(tissue_to_probe, float)
        key = _key(M)
        hit = self._look_cache.get(look)
        if hit is not None and hit[0] == key:
            return hit[1]
        iq = self._render_tissue(M, look, moved=hit is not None)
        iq *= self._rows_view(self._row_gain_signal)
        self._look_cache[look] = (key, iq)
        return iq

    def _face_reverb_iq(self) -> tuple[int, np.ndarray] | None:
        """The probe-face reverberation bands: (rows, IQ of those top rows), laterally
        uniform, one pulse (the axial PSF) per band, coherent (zero phase); None when off."""
        p = self.params
        if p.face_reverb_gain <= 0:
            return None
        z = self._rows_mm
        n_bands = int(np.ceil(np.log(0.02) / np.log(max(p.face_reverb_decay, 1e-3)))) + 1
        zk = p.face_reverb_spacing_mm * np.arange(1, n_bands + 1)
        amp = p.face_reverb_gain * p.face_reverb_decay ** np.arange(n_bands)
        rows = int(np.searchsorted(z, zk[-1] + 4.0 * p.sigma_axial_mm)) + 1
        rows = min(rows, len(z))
        if rows < 1:
            return None
        prof = (amp[None] * np.exp(-0.5 * ((z[:rows, None] - zk[None]) / p.sigma_axial_mm)
                                   ** 2)).sum(1)
        if prof.max() < 1e-6:
            return None
        iq = np.zeros((rows, *self._shape[1:], 2), np.float32)
        iq[..., 0] = prof.reshape((-1,) + (1,) * (len(self._shape) - 1)).astype(np.float32)
        return rows, iq

    # A plane probe's tissue echo as a 3D field over (depth, elevation, lateral), exact for
    # translations of the probe in x and y (the PSF and the phase depend on depth only).
    _CHUNK_MM = 10.0  # elevation length of a field built on demand
    _PAD_MM = 5.0  # lateral travel a field built on demand allows

    def prepare(self, tissue_to_probe: np.ndarray) -> None:
        """Set the world up for a whole trajectory of tissue-to-probe transforms (T, 4, 4).

        When a plane probe only translates laterally and in elevation relative to the tissue
        (stepping along the needle, following a tip), one field covering every frame is built
        here, so that imaging a frame afterwards costs a slice of it. When a 3D probe's
        transform changes over the trajectory, the tissue cells near any of its views are
        cached here (within ``cell_cache_mb``).
        """
        Ms = np.asarray(tissue_to_probe, float)
        if self.probe.ndim == 3:
            self._prepare_cells(Ms)
            return
        if not self.probe.field_sliceable or len(Ms) < 2:
            return
        R0, tz0 = Ms[0, :3, :3], Ms[0, 2, 3]
        if not (np.allclose(Ms[:, :3, :3], R0, atol=1e-9) and np.allclose(Ms[:, 2, 3], tz0)):
            return
        if np.ptp(Ms[:, 0, 3]) < 1e-9 and np.ptp(Ms[:, 1, 3]) < 1e-9:
            return  # static: the first frame is imaged directly and reused
        g = self.probe.grid
        x0, w = g.origin_mm[1], g.shape[1] * g.spacing_mm[1]
        self._fields.insert(0, self._build_field(
            R0, tz0, x0 - Ms[:, 0, 3].max(), x0 + w - Ms[:, 0, 3].min(),
            -Ms[:, 1, 3].max(), -Ms[:, 1, 3].min()))
        self._last_M = Ms[0]

    def _field_slice(self, M: np.ndarray) -> np.ndarray:
        g = self.probe.grid
        dx = g.spacing_mm[1]
        nx = g.shape[1]
        tx, ty = M[0, 3], M[1, 3]
        rkey = _field_key(M[:3, :3], M[2, 3])
        x_need = (g.origin_mm[1] - tx, g.origin_mm[1] - tx + nx * dx)
        y = -ty  # the image plane sits at elevation -t_y of the reference field
        f = None
        for rec in self._fields:
            if (rec["key"] == rkey and rec["x_lo"] <= x_need[0] + 1e-9
                    and rec["x_hi"] >= x_need[1] - 1e-9 and rec["y_lo"] <= y <= rec["y_hi"]):
                f = rec
                break
        if f is None:
            y0 = np.floor(y / self._CHUNK_MM) * self._CHUNK_MM
            f = self._build_field(M[:3, :3], M[2, 3], x_need[0] - self._PAD_MM,
                                  x_need[1] + self._PAD_MM, y0, y0 + self._CHUNK_MM)
            self._fields.insert(0, f)
            del self._fields[self.field_cache_size:]
        data, dy = f["data"], f["dy"]
        # elevation: linear interpolation between the two nearest planes
        fy = (y - f["y_plane0"]) / dy
        j = min(int(np.floor(fy)), data.shape[1] - 2)
        a = np.float32(fy - j)
        plane = data[:, j] * (1 - a) + data[:, j + 1] * a
        # lateral: image column 0 sees the field at x_need[0]
        x0 = (x_need[0] - f["x_col0"]) / dx
        i = int(np.floor(x0))
        b = np.float32(x0 - i)
        out = plane[:, i:i + nx] * (1 - b) + plane[:, i + 1:i + 1 + nx] * b
        return np.ascontiguousarray(out)

    def _build_field(self, R, tz, x_lo, x_hi, y_lo, y_hi) -> dict:
        """The field covering lateral [x_lo, x_hi] and elevation [y_lo, y_hi] (reference frame),
        with margins so scatterers just outside still reach it through the PSF."""
        probe, p = self.probe, self.params
        g = probe.grid
        dz, dx = g.spacing_mm
        nz = g.shape[0]
        dy = self._field_dy
        el = 3.0 * float(self._sig_el_mm.max())
        lat = 3.0 * float(self._sig_lat_mm.max())
        my = int(np.ceil(el / dy)) + 1
        mx = int(np.ceil(lat / dx)) + 1
        # column/plane grids aligned with the image's lateral sampling
        c0 = int(np.floor((x_lo - g.origin_mm[1]) / dx)) - mx
        c1 = int(np.ceil((x_hi - g.origin_mm[1]) / dx)) + mx + 1
        x_col0 = g.origin_mm[1] + c0 * dx
        nxf = c1 - c0 + 1
        p0 = int(np.floor(y_lo / dy)) - my
        p1 = int(np.ceil(y_hi / dy)) + my + 1
        y_plane0 = p0 * dy
        nyf = p1 - p0 + 1
        shape = (nz, nyf, nxf)
        data = np.zeros((*shape, 2), np.float32)
        M = np.eye(4)
        M[:3, :3] = R
        M[2, 3] = tz
        inv = invert_rigid(M)
        z_lo = max(g.origin_mm[0] - 3 * p.sigma_axial_mm, 0.0)
        z_hi = g.origin_mm[0] + nz * dz + 3 * p.sigma_axial_mm
        slab = max(int(round(8.0 / dy)), 4)  # build in 8 mm slabs to bound memory
        for s0 in range(0, nyf - 1, slab):
            s1 = min(s0 + slab, nyf - 1)
            lo = np.array([x_col0, y_plane0 + s0 * dy, z_lo])
            hi = np.array([x_col0 + (nxf - 1) * dx, y_plane0 + s1 * dy, z_hi])
            corners = np.array([[x, yy, z] for x in (lo[0], hi[0]) for yy in (lo[1], hi[1])
                                for z in (lo[2], hi[2])])
            ct = apply_transform(inv, corners)
            pos, amp = self.world.tissue.scatterers_in_box(ct.min(0), ct.max(0))
            amp = self.world.tissue.modulate(pos, amp)
            transform_splat_field(pos, amp, np.ascontiguousarray(M[:3, :3]),
                                  np.ascontiguousarray(M[:3, 3]), lo, hi,
                                  np.array([g.origin_mm[0], y_plane0, x_col0]),
                                  np.array([dz, dy, dx]), 2.0 * p.k0_per_mm, data)
        data = _blur_axis(data, 0, self._sig_px[0])
        data = _blur_axis(data, 1, self._sig_el_mm / dy)
        data = _blur_axis(data, 2, self._sig_px[1])
        # the same normalisation as a directly imaged plane (elevation profile peak 1)
        gain = self._row_gain_signal * np.sqrt(2.0 * np.pi) * np.sqrt(
            np.maximum((self._sig_el_mm / dy) ** 2, _SPLAT_VAR))
        data *= gain.reshape(-1, 1, 1, 1).astype(np.float32)
        return {"key": _field_key(R, tz), "data": data,
                "dy": dy, "y_plane0": y_plane0, "x_col0": x_col0,
                "x_lo": x_col0 + mx * dx, "x_hi": x_col0 + (nxf - 1 - mx) * dx,
                "y_lo": y_plane0 + my * dy, "y_hi": y_plane0 + (nyf - 1 - my) * dy}

    # -- tissue of a 3D probe that moves: cached cells ----------------------------------
    def _view(self, M: np.ndarray):
        """The probe-frame box that reaches the image (PSF margins included) and the
        tissue-frame box that holds it under the tissue-to-probe transform ``M``."""
        p = self.params
        el_half = 3.0 * float(self._sig_el_mm.max())
        margin = 3.0 * float(max(self._sig_lat_mm.max(), p.sigma_axial_mm))
        lo, hi = self.probe.region_box(margin, el_half)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])])
        ct = apply_transform(invert_rigid(M), corners)
        return lo, hi, ct.min(0), ct.max(0)

    def _view_cells(self, M: np.ndarray, tissue, pad_mm: float = 0.0) -> np.ndarray:
        """The tissue cells whose scatterers (moved ``pad_mm`` or less) can reach the image
        under ``M``, in the order the direct path images them."""
        lo, hi, tlo, thi = self._view(M)
        cells = tissue.cells_in_box(tlo - pad_mm, thi + pad_mm)
        return near_cells(self.probe, tissue, cells, M, lo, hi, pad_mm)

    def _cell_budget(self) -> int:
        """Bytes one look's cell cache may hold."""
        return int(self.cell_cache_mb * 2**20) // self.params.compound_looks

    def _prepare_cells(self, Ms: np.ndarray) -> None:
        """Cache, for every look, the cells near any of the views ``Ms`` (T, 4, 4), if the
        transform changes and they fit the budget."""
        if len(Ms) < 2 or np.allclose(Ms, Ms[0], atol=1e-9) or self.cell_cache_mb <= 0:
            return
        tissue = self.world.tissue
        cells = np.unique(np.concatenate([self._view_cells(M, tissue) for M in Ms]), axis=0)
        if cache_bytes(len(cells), tissue.n_per_cell) > self._cell_budget():
            return  # each volume is imaged directly
        for look, t in enumerate(self._look_tissues):
            self._cell_caches[look] = CellCache(t, cells, max_cells=len(cells))

    def _render_cells(self, M: np.ndarray, look: int, moved: bool) -> np.ndarray | None:
        """Splatted (unblurred, float64) tissue IQ from the look's cell cache, built around
        this view when the probe moved and no cache covers it; None when the direct path is
        to be taken (a static probe without a cache, or a view too large for the budget)."""
        cache = self._cell_caches.get(look)
        if cache is None and not moved:
            return None
        tissue = self._look_tissues[look]
        cells = self._view_cells(M, tissue)
        slots = cache.slots(cells) if cache is not None else None
        if slots is None:
            if not moved:
                self._cell_caches.pop(look, None)
                return None
            around = self._view_cells(M, tissue, self._CELL_PAD_MM)
            max_cells = self._cell_budget() // cache_bytes(1, tissue.n_per_cell)
            if len(around) > max_cells:
                self._cell_caches.pop(look, None)
                return None
            if cache is None:
                cache = self._cell_caches[look] = CellCache(tissue, around, max_cells)
            else:
                cache.hold(around, max_cells)  # only the cells the view enters are generated
            slots = cache.slots(cells)
        lo, hi, _, _ = self._view(M)
        iq = np.zeros((*self._shape, 2))  # float64: the sum of ~10^6 phasors; the blur rounds
        cache.splat(self.probe, slots, M, lo, hi, 2.0 * self.params.k0_per_mm, iq)
        return iq

    def _render_tissue(self, M: np.ndarray, look: int = 0, moved: bool = False) -> np.ndarray:
        """Tissue IQ (blurred, before the row gains) of look ``look`` under ``M``: from the
        cell cache for a 3D probe that moves, otherwise from scatterers generated here."""
        iq = self._render_cells(M, look, moved) if self.probe.ndim == 3 else None
        if iq is None:
            iq = self._render_direct(M, self._look_tissues[look])
        for axis, s in enumerate(self._sig_px):
            iq = _blur_axis(iq, axis, s)
        return iq.astype(np.float32, copy=False)

    def _render_direct(self, M: np.ndarray, tissue) -> np.ndarray:
        """Splatted (unblurred) tissue IQ from the scatterers of the cells around the view."""
        probe, p = self.probe, self.params
        lo, hi, tlo, thi = self._view(M)
        pos, amp = tissue.scatterers_in_box(tlo, thi)
        R = np.ascontiguousarray(M[:3, :3], dtype=np.float64)
        t = np.ascontiguousarray(M[:3, 3], dtype=np.float64)
        sig_el = self._sig_el_mm.astype(np.float64)
        # keep what the probe can see before evaluating the scattering map on it
        keep = probe.keep_scatterers(pos, R, t, lo, hi, sig_el)
        pos = pos[keep]
        amp = tissue.modulate(pos, amp[keep])
        iq = np.zeros((*self._shape, 2), np.float32)
        two_k = 2.0 * p.k0_per_mm  # exact two-way phase of every scatterer
        probe.splat_scatterers(pos, amp, R, t, lo, hi, two_k, sig_el, iq)
        return iq

    # -- needle ---------------------------------------------------------------------------
    def needle_iq(self, pts: np.ndarray, tan: np.ndarray, step_mm: float) -> NeedleEcho | None:
        """Normalised needle IQ and the tissue's shadow multiplier, in a crop of the beam grid
        (:func:`synth._needle_echo.needle_iq`)."""
        return _needle_iq(self, pts, tan, step_mm)

    # -- frame ----------------------------------------------------------------------------
    def render(self, tissue_to_probe: np.ndarray, needle_pts: np.ndarray,
               needle_tan: np.ndarray, rng: np.random.Generator, step_mm: float,
               needle_gain: float = 1.0) -> RenderedFrame:
        iq = self.tissue_iq(tissue_to_probe)
        echo = None
        if not self.zhao_mode and len(needle_pts):
            echo = self.needle_iq(needle_pts, needle_tan, step_mm)
        others = self.reflector_echoes(tissue_to_probe, step_mm)
        env = self.envelope(iq, echo, rng, needle_gain, others)
        if self.params.compound_looks > 1:
            inten = env * env
            for k in range(1, self.params.compound_looks):
                e = self.envelope(self.look_iq(tissue_to_probe, k), echo, rng, needle_gain,
                                  others)
                inten += e * e
            env = np.sqrt(inten / np.float32(self.params.compound_looks))
        img = self.probe.to_image(log_compress(env, self.params))
        if self._mask is not None:
            img[~self._mask] = 0
        return RenderedFrame(image=img, envelope=env, needle_gain=needle_gain)

    def reflector_echoes(self, tissue_to_probe: np.ndarray, step_mm: float) -> list:
        """The echoes of the world's specular boundaries (:class:`~._world.SpecularLine`)
        seen from ``tissue_to_probe``; none in Zhao's mode (its volumes draw no echoes)."""
        out = []
        if self.zhao_mode:
            return out
        R = np.asarray(tissue_to_probe, float)[:3, :3]
        for line in self.world.reflectors:
            pts, tan = line.samples(step_mm)
            e = _needle_iq(self, apply_transform(tissue_to_probe, pts), tan @ R.T, step_mm,
                           spec=line.spec)
            if e is not None:
                out.append(e)
        return out

    @property
    def display_mask(self) -> np.ndarray | None:
        """The frame's display mask (see :func:`display_mask`), or None."""
        return self._mask

    def envelope(self, iq, echo: NeedleEcho | None, rng, needle_gain: float = 1.0,
                 others: list | None = None) -> np.ndarray:
        """|tissue * shadow + gain * needle + other reflectors + noise| with the noise scaled
        by TGC per row."""
        noise = np.empty(iq.shape, np.float32)
        # OpenCV's generator is 3x faster than numpy's here; it is seeded from ``rng`` for
        # every frame, so the noise is reproducible from the scenario's seed.
        cv2.setRNGSeed(int(rng.integers(2**31 - 1)))
        cv2.randn(noise.reshape(noise.shape[0], -1), 0.0, 1.0)
        noise *= self._noise_row_scale
        noise += iq
        if self._face_reverb is not None:
            rows, band = self._face_reverb
            noise[:rows] += band
        for e in others or ():  # specular boundaries: their gain is their own
            noise[e.region][:len(e.iq)] += e.iq
        if echo is not None:
            sl = echo.region
            noise[sl] += iq[sl] * (echo.shadow[..., None] - np.float32(1.0))
            noise[sl][:len(echo.iq)] += np.float32(needle_gain) * echo.iq
        if noise.ndim == 3:
            return cv2.magnitude(noise[..., 0], noise[..., 1])
        return np.sqrt(noise[..., 0] ** 2 + noise[..., 1] ** 2)
