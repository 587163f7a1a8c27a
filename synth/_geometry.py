"""Grids, poses and the one place where array order and point order meet.

Array order is ``[z, x]`` for 2D images and ``[z, y, x]`` for volumes (depth first); point
order is physical ``(x, z)`` or ``(x, y, z)`` in millimetres in the probe frame (x lateral,
y elevation, z depth). Every conversion between the two goes through :class:`Grid`;
nothing else in the project reorders axes on its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Grid",
    "distance_to_polyline",
    "rotation_matrix",
    "rigid_transform",
    "invert_rigid",
    "apply_transform",
]


@dataclass(frozen=True)
class Grid:
    """A regular grid: ``position(index) = origin_mm + index * spacing_mm`` per array axis.

    ``shape``, ``spacing_mm`` and ``origin_mm`` are in array order ([z, x] or [z, y, x]).
    """

    shape: tuple[int, ...]
    spacing_mm: tuple[float, ...]
    origin_mm: tuple[float, ...]

    def __post_init__(self) -> None:
        nd = len(self.shape)
        if nd not in (2, 3):
            raise ValueError(f"Grid: shape must have 2 or 3 axes, got {self.shape}")
        if len(self.spacing_mm) != nd or len(self.origin_mm) != nd:
            raise ValueError(
                f"Grid: spacing_mm {self.spacing_mm} and origin_mm {self.origin_mm} must have "
                f"{nd} entries like shape {self.shape}"
            )
        if any(int(s) < 1 for s in self.shape):
            raise ValueError(f"Grid: shape must be positive, got {self.shape}")
        sp = np.asarray(self.spacing_mm, dtype=float)
        if not np.all(np.isfinite(sp)) or np.any(sp <= 0):
            raise ValueError(
                f"Grid: spacing_mm must be positive and finite, got {self.spacing_mm}")
        if not np.all(np.isfinite(np.asarray(self.origin_mm, dtype=float))):
            raise ValueError(f"Grid: origin_mm must be finite, got {self.origin_mm}")
        object.__setattr__(self, "shape", tuple(int(s) for s in self.shape))
        object.__setattr__(self, "spacing_mm", tuple(float(s) for s in self.spacing_mm))
        object.__setattr__(self, "origin_mm", tuple(float(s) for s in self.origin_mm))

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def extent_mm(self) -> tuple[float, ...]:
        """Physical length covered by each array axis (first to last sample)."""
        return tuple((n - 1) * d for n, d in zip(self.shape, self.spacing_mm, strict=True))

    # -- the conversions -------------------------------------------------------------
    def points_to_index(self, points_mm: np.ndarray) -> np.ndarray:
        """Physical points ``(..., D)`` in point order -> fractional indices in array order."""
        p = np.asarray(points_mm, dtype=float)
        if p.shape[-1] != self.ndim:
            raise ValueError(f"points_mm must have {self.ndim} coordinates, got shape {p.shape}")
        arr = p[..., ::-1]  # (x, z) -> (z, x); (x, y, z) -> (z, y, x)
        return (arr - np.asarray(self.origin_mm)) / np.asarray(self.spacing_mm)

    def index_to_points(self, index: np.ndarray) -> np.ndarray:
        """Fractional indices ``(..., D)`` in array order -> physical points in point order."""
        i = np.asarray(index, dtype=float)
        if i.shape[-1] != self.ndim:
            raise ValueError(f"index must have {self.ndim} entries, got shape {i.shape}")
        arr = np.asarray(self.origin_mm) + i * np.asarray(self.spacing_mm)
        return arr[..., ::-1]

    def axis_coords(self, axis: int) -> np.ndarray:
        """Physical coordinate of every sample along one array axis."""
        return self.origin_mm[axis] + np.arange(self.shape[axis]) * self.spacing_mm[axis]

    def point_grids(self) -> tuple[np.ndarray, ...]:
        """Broadcastable physical coordinate arrays in point order ((x, z) or (x, y, z))."""
        axes = [self.axis_coords(a) for a in range(self.ndim)]
        grids = np.meshgrid(*axes, indexing="ij", sparse=True)
        return tuple(grids[::-1])

    def contains(self, points_mm: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Whether points (point order) lie inside the grid, ``margin_px`` from its edge."""
        idx = self.points_to_index(points_mm)
        lo = margin_px
        hi = np.asarray(self.shape) - 1 - margin_px
        return np.all((idx >= lo) & (idx <= hi), axis=-1)

    def to_dict(self) -> dict:
        return {"shape": list(self.shape), "spacing_mm": list(self.spacing_mm),
                "origin_mm": list(self.origin_mm)}


def rotation_matrix(axis: np.ndarray | tuple[float, float, float], angle_rad: float) -> np.ndarray:
    """Rotation by ``angle_rad`` about ``axis`` (Rodrigues' formula)."""
    a = np.asarray(axis, dtype=float)
    n = np.linalg.norm(a)
    if n == 0:
        raise ValueError("rotation_matrix: axis must be non-zero")
    kx, ky, kz = a / n
    K = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1.0 - np.cos(angle_rad)) * (K @ K)


def rigid_transform(R: np.ndarray | None = None, t: np.ndarray | None = None) -> np.ndarray:
    """4x4 homogeneous transform from a rotation and a translation."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def invert_rigid(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform without a general matrix inverse."""
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def apply_transform(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to ``(..., 3)`` points."""
    p = np.asarray(points)
    return p @ T[:3, :3].T + T[:3, 3]


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray, chunk: int = 8192) -> np.ndarray:
    """Distance of points (N, D) to a polyline (K, D), vectorised over points and segments."""
    pts = np.asarray(points, float)
    poly = np.asarray(polyline, float)
    if len(poly) == 1:
        return np.linalg.norm(pts - poly[0], axis=1)
    a, ab = poly[:-1], np.diff(poly, axis=0)
    denom = np.maximum((ab * ab).sum(1), 1e-12)
    out = np.empty(len(pts))
    for s in range(0, len(pts), chunk):
        ap = pts[s:s + chunk, None, :] - a[None]
        t = np.clip(np.einsum("nkd,kd->nk", ap, ab) / denom, 0.0, 1.0)
        out[s:s + chunk] = np.linalg.norm(ap - t[..., None] * ab[None], axis=-1).min(axis=1)
    return out
