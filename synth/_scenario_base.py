"""What every scenario shares: the parameter checks, the base class (``draw`` and ``build``),
the random scattering map of a background, and small trajectory helpers."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields

import numpy as np

from ._scanner import ImagingParams
from ._world import NeedleSpec, ScatteringMap, needle_radius_mm

__all__ = ["BACKGROUNDS", "MAX_FRAME_PIXELS", "random_scattering_map"]


BACKGROUNDS = ("homogeneous", "inhomogeneous")


def random_scattering_map(rng: np.random.Generator, lo, hi, background: str,
                          plane_bias: bool = True, distractors: bool = True) -> ScatteringMap:
    """An inhomogeneous scattering map over the box lo-hi (tissue frame), or a homogeneous one.

    Smooth log-normal inhomogeneity, interfaces between layers, line-like structures, anechoic
    cysts and bright needle-like distractors; Zhao 2013 used a breast scattering map that
    "contains complicated patterns such as line-like structures".
    """
    if background not in BACKGROUNDS:
        raise ValueError(f"background must be one of {BACKGROUNDS}, got {background!r}")
    if background == "homogeneous":
        return ScatteringMap()
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    size = hi - lo
    K = 16
    dirs = rng.normal(size=(K, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    wavelengths = rng.uniform(6.0, 30.0, K)
    wave_vectors = dirs * (2 * np.pi / wavelengths)[:, None]

    def point(n):
        return lo + rng.random((n, 3)) * size

    n_int = int(rng.integers(1, 4))
    normals = np.tile([0.0, 0.0, 1.0], (n_int, 1)) + rng.normal(0, 0.25, (n_int, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    offsets = np.einsum("nd,nd->n", normals, point(n_int))
    n_line = int(rng.integers(2, 6))
    n_dist = int(rng.integers(1, 3))
    a = point(n_line + n_dist)
    d = rng.normal(size=(n_line + n_dist, 3))
    if plane_bias:
        d[:, 1] *= 0.15  # mostly across the image plane, so they show as lines
        a[:, 1] = rng.normal(0.0, 0.5, n_line + n_dist)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    length = np.concatenate([rng.uniform(10, 40, n_line), rng.uniform(10, 30, n_dist)])
    b = a + d * length[:, None]
    radius = np.concatenate([rng.uniform(0.2, 0.6, n_line), rng.uniform(0.25, 0.45, n_dist)])
    gain = np.concatenate([rng.uniform(1.8, 3.5, n_line), rng.uniform(5.0, 9.0, n_dist)])
    if not distractors:  # the same draws (a seed gives the same tissue), without the needle-like
        gain[n_line:] = 1.0  # bright lines
    n_cyst = int(rng.integers(0, 3))
    return ScatteringMap(
        smooth_sigma=float(rng.uniform(0.2, 0.45)), wave_vectors=wave_vectors,
        wave_phases=rng.uniform(0, 2 * np.pi, K),
        interface_normals=normals, interface_offsets=offsets,
        interface_factors=rng.uniform(0.5, 1.8, n_int),
        interface_brightness=rng.uniform(0.3, 1.5, n_int),
        line_a=a, line_b=b, line_radius=radius, line_gain=gain,
        cyst_centers=point(n_cyst), cyst_radii=rng.uniform(1.5, 4.5, n_cyst),
    )


def _with_structures(smap: ScatteringMap, **extra) -> ScatteringMap:
    """``smap`` with structures appended: each keyword names a ScatteringMap array field and
    gives the rows to add to it."""
    return dataclasses.replace(smap, **{
        k: np.concatenate([np.asarray(getattr(smap, k), float).reshape(
            (-1,) + np.shape(v)[1:]), np.asarray(v, float)]) for k, v in extra.items()})


def interface_along(point, u, v, offset_mm: float, brightness: float, factor: float) -> dict:
    """A bright interface (fascia, a tendon's or an organ's boundary): the plane spanned by
    directions ``u`` and ``v`` through ``point``, moved by ``offset_mm`` along its normal
    taken to point deeper (+z). The ScatteringMap rows to append (:func:`_with_structures`)."""
    n = np.cross(np.asarray(u, float), np.asarray(v, float))
    n /= np.linalg.norm(n)
    n = n if n[2] >= 0 else -n
    return {"interface_normals": [n],
            "interface_offsets": [float(n @ np.asarray(point, float)) + float(offset_mm)],
            "interface_factors": [float(factor)], "interface_brightness": [float(brightness)]}


def _check_positive(name: str, v) -> None:
    if v is not None and (not np.isfinite(v) or v <= 0):
        raise ValueError(f"{name} must be positive, got {v}")


MAX_FRAME_PIXELS = 1 << 24  # 4096 x 4096: beyond any scanner's frame


def _check_frame_size(p) -> None:
    """A 2D scenario's frame (width and depth over the pixel spacing) must stay within
    :data:`MAX_FRAME_PIXELS`: a 1e-6 mm spacing asks for 10^15 pixels."""
    sp, w, d = (getattr(p, k, None) for k in ("spacing_mm", "width_mm", "depth_mm"))
    if not all(isinstance(v, (int, float)) for v in (sp, w, d)):
        return
    pixels = (w / sp) * (d / sp)
    if pixels > MAX_FRAME_PIXELS:
        raise ValueError(f"spacing_mm={sp:g} over {w:g} x {d:g} mm makes frames of {pixels:.3g} "
                         f"pixels (at most {MAX_FRAME_PIXELS}); use a coarser spacing_mm")


def _check_cr(cr) -> None:
    if cr is not None and (not np.isfinite(cr) or not 1.05 <= cr <= 10.0):
        raise ValueError(f"cr (contrast ratio, Zhao eq. 9) must be in [1.05, 10], got {cr}")


@dataclass(frozen=True)
class _Base:
    """Parameters shared by every scenario."""

    frames: int | None = None
    background: str = "inhomogeneous"
    cr: float | None = None
    gauge: int = 18
    needle_echo: float = 60.0
    noise_db: float = -45.0
    dynamic_range_db: float = 70.0
    scatterers_per_cell: float = 40.0
    # any ImagingParams / NeedleSpec field, e.g. {"center_frequency_mhz": 7.5}: training
    # randomises the imaging through these
    imaging_overrides: dict = field(default_factory=dict)
    needle_overrides: dict = field(default_factory=dict)
    distractors: bool = True  # bright needle-like lines in an inhomogeneous background

    modality = "inplane"
    paper = ""

    def validate(self) -> None:
        if self.frames is not None and (int(self.frames) != self.frames or self.frames < 1):
            raise ValueError(f"frames must be a positive integer, got {self.frames}")
        if self.background not in BACKGROUNDS:
            raise ValueError(f"background must be one of {BACKGROUNDS}, got {self.background!r}")
        _check_cr(self.cr)
        needle_radius_mm(self.gauge)
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name.endswith(("_mm_s", "_hz", "spacing_mm", "width_mm", "depth_mm")) and \
                    isinstance(v, (int, float)):
                _check_positive(f.name, v)
        _check_positive("scatterers_per_cell", self.scatterers_per_cell)
        _check_positive("dynamic_range_db", self.dynamic_range_db)
        _check_frame_size(self)
        a, b = getattr(self, "start_length_mm", None), getattr(self, "stop_length_mm", None)
        if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not (
                np.isfinite(a) and np.isfinite(b) and 0.0 <= a < b):
            raise ValueError(f"need 0 <= start_length_mm < stop_length_mm (finite), got "
                             f"{a} and {b}")

    def imaging(self) -> ImagingParams:
        return self._with_overrides(ImagingParams(
            noise_db=self.noise_db, dynamic_range_db=self.dynamic_range_db,
            scatterers_per_cell=self.scatterers_per_cell))

    def _with_overrides(self, params: ImagingParams) -> ImagingParams:
        try:
            return dataclasses.replace(params, **self.imaging_overrides)
        except TypeError as exc:
            raise ValueError(f"imaging_overrides: {exc}") from None

    def needle_spec(self, rng) -> NeedleSpec:
        try:
            return dataclasses.replace(NeedleSpec(gauge=self.gauge, echo=self.needle_echo),
                                       **self.needle_overrides)
        except TypeError as exc:
            raise ValueError(f"needle_overrides: {exc}") from None


def _n_frames(p, default: int) -> int:
    return int(p.frames) if p.frames is not None else default


def _const_pose(T: int, pose=None) -> np.ndarray:
    return np.repeat((np.eye(4) if pose is None else pose)[None], T, axis=0)


def _breathing(T, dt, amp_mm, rng) -> np.ndarray:
    """Rigid tissue motion: breathing-like sinusoids (period 3-5 s) along a random direction."""
    poses = _const_pose(T)
    if amp_mm <= 0:
        return poses
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    period = rng.uniform(3.0, 5.0)
    ph = rng.uniform(0, 2 * np.pi)
    t = np.arange(T) * dt
    poses[:, :3, 3] = amp_mm * np.sin(2 * np.pi * t / period + ph)[:, None] * d
    return poses
