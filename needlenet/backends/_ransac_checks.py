"""The papers' constraints on RANSAC hypotheses, as validity checks for :func:`~._ransac.ransac`.

Each constructor returns a :class:`Check`, a named callable vectorised over a batch:

* on minimal samples, ``check(samples) -> (B,) bool`` for samples of shape (B, m, D):
  :func:`min_sample_distance` (Zhao 2013 Appendix B: reject ``kappa(N) < d_min``);
* on hypotheses, ``check(models) -> (B,) bool`` for a batch of B models:
  :func:`max_curvature` (Uhercik's constraint, quoted by Chatelain 2013 II-D) and
  :func:`within_angle` (the angle to the predicted direction, Chatelain 2013 eq. (22)).

:func:`~._ransac.ransac` takes them as ``is_sample_valid`` and ``is_model_valid`` (one check or
a sequence of checks, all of which must hold), as scikit-image's ``ransac`` does; any callable
with the same signature works as well.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ._fit_checks import _as_vector, _check_positive

__all__ = ["Check", "max_curvature", "min_sample_distance", "within_angle"]


@dataclass(frozen=True)
class Check:
    """A named validity test of a batch: ``check(batch)`` is a (B,) bool mask.

    Attributes
    ----------
    name : str
        How the check reads in a failure reason, e.g. ``min_sample_distance(2)``.
    test : callable
        The test itself, vectorised over the batch.
    """

    name: str
    test: Callable[..., np.ndarray]

    def __call__(self, batch) -> np.ndarray:
        return self.test(batch)

    def __str__(self) -> str:
        return self.name


def min_pairwise_distance(samples: np.ndarray) -> np.ndarray:
    """Zhao's ``kappa(N) = min_{i != j} ||N_i - N_j||`` for (B, m, D) samples: shape (B,)."""
    m = samples.shape[1]
    iu = np.triu_indices(m, 1)
    diffs = samples[:, iu[0]] - samples[:, iu[1]]
    return np.linalg.norm(diffs, axis=-1).min(axis=1)


def min_sample_distance(d_min: float) -> Check:
    """Reject minimal samples whose closest two points are nearer than ``d_min``.

    Zhao 2013, Appendix B: a sample N with ``kappa(N) < d_min`` is drawn again; points close
    together define the axis direction poorly.

    Parameters
    ----------
    d_min : float
        Smallest distance between two points of a sample, in the units of the points (>= 0).
    """
    d_min = _check_positive(d_min, "min_sample_distance", allow_zero=True)

    def test(samples: np.ndarray) -> np.ndarray:
        return min_pairwise_distance(samples) >= d_min  # Zhao: reject kappa(N) < d_min

    return Check(f"min_sample_distance({d_min:g})", test)


def max_curvature(limit: float) -> Check:
    """Reject hypotheses more curved than ``limit`` over the span of their control points.

    Uhercik's constraint, quoted by Chatelain 2013 II-D: a needle bends only so much. Uses the
    model's ``max_curvature()``; lines (curvature 0) always pass.

    Parameters
    ----------
    limit : float
        Largest curvature (1 / length unit of the points), >= 0.
    """
    limit = _check_positive(limit, "max_curvature", allow_zero=True)

    def test(models) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            return models.max_curvature() <= limit  # Uhercik's curvature constraint

    return Check(f"max_curvature({limit:g})", test)


def within_angle(predicted_direction, max_angle_deg: float) -> Check:
    """Reject hypotheses whose axis is farther than ``max_angle_deg`` from a predicted direction.

    Chatelain 2013, eq. (22): ``|alpha| <= alpha_0`` with ``alpha`` the angle between the
    hypothesis' principal direction k0 and the direction k0^- predicted by the Kalman filter.
    The angle is sign-agnostic, ``acos(|k0 . k0^-|)``: a minimal sample has no order, so the
    sign of its direction is arbitrary and a needle axis is an unoriented line.

    Parameters
    ----------
    predicted_direction : array, shape (D,)
        k0^-, finite and non-zero (normalised here); D must match the points'.
    max_angle_deg : float
        alpha_0, in [0, 90] degrees.
    """
    k = np.asarray(predicted_direction, dtype=float)
    if k.ndim != 1:
        raise ValueError(f"predicted_direction must have shape (D,), got {k.shape}")
    k_pred = _as_vector(k, k.size, "predicted_direction")
    if not 0.0 <= float(max_angle_deg) <= 90.0:
        raise ValueError(f"max_angle_deg must be in [0, 90], got {max_angle_deg}")
    cos_min = math.cos(math.radians(float(max_angle_deg)))

    def test(models) -> np.ndarray:
        if k_pred.shape != (models.ndim,):
            raise ValueError(
                f"predicted_direction must have shape ({models.ndim},), got {k_pred.shape}"
            )
        cos_alpha = np.abs(models.principal_direction @ k_pred)  # Chatelain eq. (22)
        return cos_alpha >= cos_min  # |alpha| <= alpha_0

    return Check(f"within_angle({float(max_angle_deg):g} deg)", test)
