"""The simulated world: tissue scatterers, the scattering map, the needle and their motion.

Tissue is an unbounded field of point scatterers with Gaussian amplitudes (the Field II
convention). Scatterers are generated lazily, cell by cell, from a seed derived from the world
seed and the cell index, so that any region can be imaged from any probe pose and always holds
the same scatterers: moving the probe decorrelates the speckle physically, and coming back
brings the same speckle back.

The scattering map multiplies scatterer amplitudes (Zhao 2013 assigns each Field II scatterer
the value of a breast scattering map at its position). Ours is built from analytic parts that
can be evaluated anywhere: a smooth log-normal inhomogeneity, interfaces, line-like structures,
anechoic cysts and bright needle-like distractors.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._geometry import apply_transform
from ._kernels import cell_scatterers, scattering_amplitude

__all__ = [
    "GAUGE_OUTER_DIAMETER_MM",
    "ScatteringMap",
    "Tissue",
    "NeedleSpec",
    "NeedlePath",
    "SpecularLine",
    "World",
    "needle_radius_mm",
]

# Nominal outer diameters (mm) of needle gauges (Stubs / ISO 9626 nominal values).
GAUGE_OUTER_DIAMETER_MM = {
    12: 2.769, 13: 2.413, 14: 2.108, 15: 1.829, 16: 1.651, 17: 1.473, 18: 1.270,
    19: 1.067, 20: 0.908, 21: 0.819, 22: 0.718, 23: 0.642, 24: 0.566, 25: 0.515, 27: 0.413,
}


def needle_radius_mm(gauge: int) -> float:
    """Outer radius of a needle of the given gauge."""
    if gauge not in GAUGE_OUTER_DIAMETER_MM:
        raise ValueError(
            f"gauge {gauge!r} unknown; choose one of {sorted(GAUGE_OUTER_DIAMETER_MM)}"
        )
    return GAUGE_OUTER_DIAMETER_MM[gauge] / 2.0


@dataclass(frozen=True)
class ScatteringMap:
    """Amplitude multiplier of the tissue scatterers as a function of position (tissue frame).

    All arrays are small (a handful of structures); evaluation is vectorised over points.
    ``amplitude(points) = exp(sigma * smooth) * interfaces * lines * cysts * distractors
    * vessels * shadows``.
    """

    smooth_sigma: float = 0.0  # std of the log-amplitude of the smooth inhomogeneity
    wave_vectors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # rad/mm
    wave_phases: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # interfaces: unit normal, offset (mm), amplitude factor on the positive side
    interface_normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    interface_offsets: np.ndarray = field(default_factory=lambda: np.zeros(0))
    interface_factors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    interface_brightness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # line-like structures (fascia, vessel walls): segments, radius and amplitude gain
    line_a: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    line_b: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    line_radius: np.ndarray = field(default_factory=lambda: np.zeros(0))
    line_gain: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # cysts: centre, radius, amplitude factor inside (about 0: anechoic)
    cyst_centers: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    cyst_radii: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cyst_factor: float = 0.03
    # vessels: tubes (segment, radius mm) with an amplitude factor inside (about 0: anechoic)
    # and an echogenic wall (amplitude gain at the wall, 0: none)
    tube_a: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    tube_b: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    tube_radius: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tube_factor: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tube_wall: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # acoustic shadows behind occluders (bone, calcification, gas): the tissue deeper than the
    # segment a-b keeps a factor of its amplitude (the beam along +z of the tissue frame, as
    # for a probe at the identity pose); half-width in elevation (mm)
    cast_a: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    cast_b: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    cast_factor: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cast_half_width: np.ndarray = field(default_factory=lambda: np.zeros(0))

    _SMOOTH_STEP_MM = 1.0

    @property
    def is_homogeneous(self) -> bool:
        return (
            self.smooth_sigma == 0
            and len(self.interface_offsets) == 0
            and len(self.line_radius) == 0
            and len(self.cyst_radii) == 0
            and len(self.tube_radius) == 0
            and len(self.cast_factor) == 0
        )

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Amplitude multiplier at ``points`` (N, 3), tissue frame (compiled loop)."""
        p = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 3)

        def f(a, shape):
            return np.ascontiguousarray(np.asarray(a, np.float64).reshape(shape))

        smooth, origin = np.ones((1, 1, 1)), np.zeros(3)
        if self.smooth_sigma > 0 and len(self.wave_phases) and len(p):
            # The smooth field on a global 1 mm lattice (aligned to the origin, so a point
            # gets the same value whatever region is asked for), read by interpolation.
            h = self._SMOOTH_STEP_MM
            # column by column: numpy reduces an (N, 3) array along axis 0 ~25x slower
            p_min = np.array([p[:, k].min() for k in range(3)], np.float32)
            p_max = np.array([p[:, k].max() for k in range(3)], np.float32)
            lo = np.floor(p_min / h) * h
            hi = np.ceil(p_max / h) * h + h
            axes = [np.arange(a, b + 0.5 * h, h) for a, b in zip(lo, hi, strict=True)]
            X, Y, Z = np.meshgrid(*axes, indexing="ij", sparse=True)
            s = np.zeros((len(axes[0]), len(axes[1]), len(axes[2])))
            for k, ph in zip(self.wave_vectors, self.wave_phases, strict=True):
                s += np.cos(k[0] * X + k[1] * Y + k[2] * Z + ph)
            smooth = np.exp(self.smooth_sigma * np.sqrt(2.0 / len(self.wave_phases)) * s)
            origin = lo
        return scattering_amplitude(
            p, smooth, origin.astype(np.float64), float(self._SMOOTH_STEP_MM),
            f(self.interface_normals, (-1, 3)), f(self.interface_offsets, -1),
            f(self.interface_factors, -1), f(self.interface_brightness, -1),
            f(self.line_a, (-1, 3)), f(self.line_b, (-1, 3)), f(self.line_radius, -1),
            f(self.line_gain, -1), f(self.cyst_centers, (-1, 3)), f(self.cyst_radii, -1),
            float(self.cyst_factor), f(self.tube_a, (-1, 3)), f(self.tube_b, (-1, 3)),
            f(self.tube_radius, -1), f(self.tube_factor, -1), f(self.tube_wall, -1),
            f(self.cast_a, (-1, 3)), f(self.cast_b, (-1, 3)), f(self.cast_factor, -1),
            f(self.cast_half_width, -1))


@dataclass(frozen=True)
class Tissue:
    """An unbounded field of point scatterers with Gaussian amplitudes.

    ``density_per_mm3`` scatterers per mm^3, generated lazily in cubic cells of
    ``cell_mm``; the cell with integer index (i, j, k) always holds the same scatterers.
    """

    density_per_mm3: float
    seed: int
    scattering_map: ScatteringMap = field(default_factory=ScatteringMap)
    cell_mm: float = 2.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.density_per_mm3) or self.density_per_mm3 <= 0:
            raise ValueError(f"density_per_mm3 must be positive, got {self.density_per_mm3}")

    @property
    def n_per_cell(self) -> int:
        """Scatterers in every cell."""
        return int(round(self.density_per_mm3 * self.cell_mm**3))

    def cells_in_box(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Integer indices (C, 3) of the cells that touch a tissue-frame box (mm), in
        lexicographic order (the last index fastest)."""
        lo = np.floor(np.asarray(lo, float) / self.cell_mm).astype(np.int64)
        hi = np.floor(np.asarray(hi, float) / self.cell_mm).astype(np.int64)
        return np.stack(
            np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi, strict=True)],
                        indexing="ij"), axis=-1
        ).reshape(-1, 3)

    def cell_scatterers(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (N, 3) and amplitudes (N,), float32, of the scatterers of ``cells``:
        ``n_per_cell`` of them per cell, cell after cell."""
        n_per_cell = self.n_per_cell
        pos = np.empty((len(cells) * n_per_cell, 3), np.float32)
        amp = np.empty(len(cells) * n_per_cell, dtype=np.float32)
        cell_scatterers(np.ascontiguousarray(cells, dtype=np.int64), n_per_cell,
                        float(self.cell_mm), int(self.seed) & 0x7FFFFFFFFFFFFFFF, pos, amp)
        return pos, amp

    def scatterers_in_box(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (N, 3) and amplitudes (N,), float32, of the scatterers in a box.

        The box is given in tissue coordinates (mm); scatterers of every cell that touches it
        are returned (a superset), so callers crop with their own weights, then apply the
        scattering map with :meth:`modulate` to the scatterers they keep.
        """
        return self.cell_scatterers(self.cells_in_box(lo, hi))

    def modulate(self, pos: np.ndarray, amp: np.ndarray) -> np.ndarray:
        """Scatterer amplitudes times the scattering map at their (tissue-frame) positions."""
        if self.scattering_map.is_homogeneous:
            return amp
        return amp * self.scattering_map(pos)


@dataclass(frozen=True)
class NeedleSpec:
    """Acoustic appearance of the needle (the physical mode of the scanner)."""

    gauge: int = 18
    echo: float = 60.0  # shaft echo per mm of shaft in the resolution cell, re unit speckle
    specular_width_deg: float = 14.0  # width of the specular lobe (beam vs shaft normal)
    diffuse_floor: float = 0.35  # fraction of the echo left far from the specular angle
    reverb_decay: float = 0.55  # amplitude ratio of successive reverberation echoes
    reverb_count: int = 6
    reverb_spacing_mm: float | None = None  # defaults to the needle radius
    shadow_factor: float = 0.35  # tissue amplitude left behind the shaft
    tip_gain: float = 2.5  # bevel echo relative to one millimetre of shaft (0: a dark bevel)
    # share of the shaft echo scattered diffusely (random phase along and across the shaft: a
    # speckled band, as a rough or coated needle or a needle in a guide shows) rather than
    # reflected coherently; its mean intensity per mm of shaft equals the coherent echo's
    diffuse_fraction: float = 0.0
    diffuse_seed: int = 0  # the diffuse scatterers' phases (fixed along the shaft)
    # unfocused (plane- or diverging-wave) transmits image a specular shaft's echo on along
    # its axis past the tip: a coherent streak whose level at the tip is streak_db re the
    # shaft's echo when the beam meets the shaft at normal incidence, streak_db_per_deg lower
    # per degree of incidence, fading by streak_fade_db_per_mm past the tip (None: focused
    # imaging, no streak). PyMUST, L11-5v, three plane waves: about -20, -15, -27 and -40 dB
    # at 8, 15, 25 and 45 degrees, fading 0.7-2 dB/mm; P4-2v at 30 degrees: -16 dB, 3-4 dB/mm
    streak_db: float | None = None
    streak_db_per_deg: float = -0.6
    streak_fade_db_per_mm: float = 2.0

    @property
    def radius_mm(self) -> float:
        return needle_radius_mm(self.gauge)


@dataclass(frozen=True)
class NeedlePath:
    """The needle's path in the tissue: straight or a bicycle-model arc (Carriere 2016).

    The path starts at ``entry`` along ``direction`` and bends with curvature 1/R in the
    plane spanned by ``direction`` and ``bend_direction``; the curvature changes sign at every
    arc length in ``turn_lengths_mm`` (a 180-degree bevel rotation, Carriere 2016 eqs. 3-4).
    ``theta0_deg`` is the initial angle of the tip to ``direction`` in the bending plane.
    The needle follows its tip (follow-the-leader), so the shaft at insertion length s is the
    path from 0 to s.
    """

    entry: np.ndarray
    direction: np.ndarray
    radius_of_curvature_mm: float = np.inf
    bend_direction: np.ndarray | None = None
    theta0_deg: float = 0.0
    turn_lengths_mm: tuple[float, ...] = ()
    max_length_mm: float = 250.0
    step_mm: float = 0.05

    def __post_init__(self) -> None:
        d = np.asarray(self.direction, float)
        if d.shape != (3,) or np.linalg.norm(d) == 0:
            raise ValueError(f"NeedlePath.direction must be a non-zero 3-vector, got {d}")
        d = d / np.linalg.norm(d)
        object.__setattr__(self, "direction", d)
        object.__setattr__(self, "entry", np.asarray(self.entry, float).reshape(3))
        b = self.bend_direction
        if b is None:
            helper = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
            b = helper
        b = np.asarray(b, float)
        b = b - (b @ d) * d
        if np.linalg.norm(b) < 1e-9:
            raise ValueError("NeedlePath.bend_direction must not be parallel to direction")
        object.__setattr__(self, "bend_direction", b / np.linalg.norm(b))
        if self.radius_of_curvature_mm <= 0:
            raise ValueError(
                f"radius_of_curvature_mm must be positive, got {self.radius_of_curvature_mm}"
            )
        s = np.arange(0.0, self.max_length_mm + self.step_mm, self.step_mm)
        kappa = np.full(len(s), 0.0 if np.isinf(self.radius_of_curvature_mm)
                        else 1.0 / self.radius_of_curvature_mm)
        for L in sorted(self.turn_lengths_mm):
            kappa[s >= L] *= -1.0  # the bevel turned by 180 degrees: curvature flips
        theta = np.deg2rad(self.theta0_deg) + np.concatenate(
            [[0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * self.step_mm)]
        )
        tangent = np.cos(theta)[:, None] * d + np.sin(theta)[:, None] * self.bend_direction
        pts = self.entry + np.concatenate(
            [[np.zeros(3)], np.cumsum(0.5 * (tangent[1:] + tangent[:-1]) * self.step_mm, 0)]
        )
        object.__setattr__(self, "_s", s)
        object.__setattr__(self, "_points", pts)
        object.__setattr__(self, "_tangent", tangent)

    def point_at(self, s: float | np.ndarray) -> np.ndarray:
        s = np.clip(np.asarray(s, float), 0.0, self.max_length_mm)
        return np.stack([np.interp(s, self._s, self._points[:, k]) for k in range(3)], -1)

    def tangent_at(self, s: float | np.ndarray) -> np.ndarray:
        s = np.clip(np.asarray(s, float), 0.0, self.max_length_mm)
        t = np.stack([np.interp(s, self._s, self._tangent[:, k]) for k in range(3)], -1)
        return t / np.linalg.norm(t, axis=-1, keepdims=True)

    def samples(self, s_tip: float, step_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centreline points, unit tangents and arc lengths from the entry to ``s_tip``."""
        s_tip = float(np.clip(s_tip, 0.0, self.max_length_mm))
        n = max(int(np.ceil(s_tip / step_mm)), 1) + 1
        s = np.linspace(0.0, s_tip, n)
        return self.point_at(s), self.tangent_at(s), s


@dataclass(frozen=True)
class SpecularLine:
    """A specular reflector in the tissue other than the needle: the line from ``a`` to ``b``
    (tissue frame, mm) where a smooth boundary (fascia, a tendon's or an organ's surface)
    crosses the image plane. Its echo follows the needle's physics (:class:`NeedleSpec`
    ``spec``: the specular lobe, the diffuse floor), without the needle's tip; a single
    boundary does not ring as a hollow shaft does unless ``spec`` says so."""

    a: np.ndarray
    b: np.ndarray
    spec: NeedleSpec

    def samples(self, step_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Points every ``step_mm`` from ``a`` to ``b`` and their (equal) unit tangents."""
        a, b = np.asarray(self.a, float), np.asarray(self.b, float)
        length = float(np.linalg.norm(b - a))
        n = max(int(np.ceil(length / step_mm)), 1) + 1
        t = np.linspace(0.0, 1.0, n)[:, None]
        u = (b - a) / max(length, 1e-12)
        return a + t * (b - a), np.repeat(u[None], n, 0)


@dataclass
class World:
    """Tissue, needle and their rigid motions over time.

    ``tissue_pose[i]`` maps tissue coordinates to world coordinates at frame i (breathing,
    phantom motion). The needle path is defined in tissue coordinates when
    ``needle_in_tissue`` (the needle moves with the phantom, as in Chatelain 2013), otherwise
    in world coordinates (held by a robot while the tissue moves under it).
    """

    tissue: Tissue
    needle_path: NeedlePath | None
    needle: NeedleSpec = field(default_factory=NeedleSpec)
    needle_in_tissue: bool = True
    reflectors: tuple[SpecularLine, ...] = ()  # specular boundaries in the tissue

    def needle_to_world(self, tissue_pose: np.ndarray) -> np.ndarray:
        return tissue_pose if self.needle_in_tissue else np.eye(4)

    def needle_world(self, s_tip: float, tissue_pose: np.ndarray, step_mm: float):
        """Centreline points and tangents of the inserted needle in world coordinates."""
        if self.needle_path is None or s_tip <= 0:
            return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
        pts, tan, s = self.needle_path.samples(s_tip, step_mm)
        T = self.needle_to_world(tissue_pose)
        return apply_transform(T, pts), tan @ T[:3, :3].T, s
