"""Argument checks shared by the fitting back ends (RANSAC, its models, the tip search along an
axis): each refuses a bad argument with a message that names it."""

from __future__ import annotations

import numpy as np

__all__: list[str] = []


def _as_points(points, name: str = "points", min_dim: int = 2) -> np.ndarray:
    """Return ``points`` as a finite float array of shape (N, D), D >= ``min_dim``."""
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[1] < min_dim:
        raise ValueError(f"{name} must have shape (N, D) with D >= {min_dim}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def _as_weights(weights, n: int, name: str = "weights") -> np.ndarray:
    """Return ``weights`` as finite non-negative floats of shape (n,); ones when None."""
    if weights is None:
        return np.ones(n)
    w = np.asarray(weights, dtype=float)
    if w.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {w.shape}")
    if not np.all(np.isfinite(w)):
        raise ValueError(f"{name} contains NaN or infinite values")
    if np.any(w < 0):
        raise ValueError(f"{name} must be non-negative")
    return w


def _as_vector(vector, d: int, name: str) -> np.ndarray:
    """Return a finite, non-zero vector of shape (d,), normalised to unit length."""
    v = np.asarray(vector, dtype=float)
    if v.shape != (d,):
        raise ValueError(f"{name} must have shape ({d},), got {v.shape}")
    norm = np.linalg.norm(v)
    if not np.isfinite(norm) or norm == 0:
        raise ValueError(f"{name} must be finite and non-zero, got {v}")
    return v / norm


def _check_positive(value, name: str, allow_zero: bool = False) -> float:
    value = float(value)
    ok = value >= 0 if allow_zero else value > 0
    if not (np.isfinite(value) and ok):
        bound = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be finite and {bound}, got {value}")
    return value


def _check_int(value, name: str, minimum: int) -> int:
    if isinstance(value, bool) or int(value) != value or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)
