"""Batched, constrained RANSAC for needle axes in 2D images and 3D volumes.

Implements the needle localisation of Chatelain 2013 (section II-D, eqs. (15)-(22)) and the
model-fitting RANSAC of Zhao 2013 (Appendix B, eqs. (B1)-(B8)):

* two models for N-dimensional points: :class:`LineModel` (a point and a unit direction, Zhao
  eqs. (B2)-(B4)) and :class:`PolyCurveModel`, the polynomial curve of Chatelain eq. (16) scored
  with the approximate point-to-curve distance of eq. (18);
* one generic loop, :func:`ransac`, that draws ``batch_size`` minimal samples at once (uniformly,
  or weighted by a likelihood), rejects samples whose points are too close (Zhao's
  ``kappa(N) < d_min``), hypotheses that are too curved (Uhercik's constraint, quoted by
  Chatelain) or too far from a predicted direction (Chatelain eq. (22)), scores the surviving
  hypotheses as one ``(B, N)`` residual matrix (eq. (19) / eq. (B5), ties broken by the cost
  (B6)), stops with the adaptive trial count of eq. (21) / eq. (B8), and refines the winner by
  least squares on its inliers;
* the tip search along the fitted axis (Zhao Appendix B, Chatelain II-D):
  :func:`sample_along_axis` and :func:`tip_along_axis`.

The layout follows scikit-image's ``skimage/measure/fit.py`` (model classes with ``residuals``
and class-method estimators, ``_dynamic_max_trials``, a falsy result on failure) and the
batching follows Kornia's ``geometry/ransac.py``: the only Python loops run over batches of
hypotheses and over refinement iterations, never over hypotheses or points.

Model classes hold a *batch* of models: every parameter array has leading batch axes
(``origin`` has shape ``(..., D)``), so ``residuals(points)`` returns ``(..., N)``: ``(B, N)``
for the ``B`` hypotheses of a batch and ``(N,)`` for the single model that :func:`ransac`
returns. ``model[i]`` selects hypotheses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy import ndimage

__all__ = [
    "AxisTip",
    "LineModel",
    "PolyCurveModel",
    "RansacResult",
    "adaptive_trial_count",
    "ransac",
    "sample_along_axis",
    "tip_along_axis",
]

# A minimal sample whose curvilinear coordinates are closer than this fraction of their spread
# gives a singular Vandermonde system (Chatelain eq. (16)) and is treated as degenerate.
_DEGENERATE_RELATIVE_GAP = 1e-9
# Number of parameter values at which the curvature of a hypothesis is evaluated.
_CURVATURE_EVALUATIONS = 9


# --------------------------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------------------------


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


def _weighted_principal_direction(points: np.ndarray, weights: np.ndarray):
    """Weighted mean and principal direction of (..., N, D) points: weighted PCA.

    The principal direction is the eigenvector of the largest eigenvalue of the weighted
    covariance; it minimises the weighted sum of squared orthogonal distances to the line
    through the weighted mean (the closed-form least-squares line of Chatelain II-D).
    """
    total = weights.sum(axis=-1)[..., None]
    mean = np.einsum("...n,...nd->...d", weights, points) / total
    centred = points - mean[..., None, :]
    cov = np.einsum("...n,...ni,...nj->...ij", weights, centred, centred) / total[..., None]
    _, vectors = np.linalg.eigh(cov)
    return mean, vectors[..., :, -1]


# --------------------------------------------------------------------------------------------
# Models
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class LineModel:
    """Batch of lines ``x = origin + t * direction`` (Zhao 2013, eq. (B2)).

    Parameters
    ----------
    origin : array, shape (..., D)
        A point on each line.
    direction : array, shape (..., D)
        Direction of each line; normalised to unit length on construction. Zero directions
        (degenerate samples) become NaN.
    """

    origin: np.ndarray
    direction: np.ndarray

    min_samples: ClassVar[int] = 2

    def __post_init__(self):
        origin = np.asarray(self.origin, dtype=float)
        direction = np.asarray(self.direction, dtype=float)
        if origin.ndim < 1 or origin.shape != direction.shape:
            raise ValueError(
                f"origin and direction must have the same shape (..., D), "
                f"got {origin.shape} and {direction.shape}"
            )
        with np.errstate(invalid="ignore", divide="ignore"):
            direction = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "direction", direction)

    # -- estimation ------------------------------------------------------------------------

    @classmethod
    def from_samples(cls, samples) -> LineModel:
        """Lines through minimal samples of shape (B, 2, D), vectorised over the B samples.

        Zhao 2013, eqs. (B3)-(B4): with ``t1 = 0`` and ``t2 = ||N2 - N1||`` the coefficient
        matrix is ``A = [N1, (N2 - N1) / ||N2 - N1||]``, i.e. origin ``N1`` and unit direction.
        Coincident points give NaN directions.
        """
        s = np.asarray(samples, dtype=float)
        if s.ndim != 3 or s.shape[1] != 2 or s.shape[2] < 2:
            raise ValueError(f"samples must have shape (B, 2, D) with D >= 2, got {s.shape}")
        return cls(s[:, 0], s[:, 1] - s[:, 0])  # Zhao 2013, eq. (B4)

    @classmethod
    def from_inliers(cls, points, weights=None) -> LineModel:
        """Weighted total-least-squares line through (N, D) points (weighted PCA).

        Chatelain 2013, II-D: "the closed-form solution of least squares regression to fit a
        line on the set of inliers". The origin is the weighted mean. Needs at least two
        points with positive weight.
        """
        pts = _as_points(points)
        w = _as_weights(weights, len(pts))
        if np.count_nonzero(w) < 2:
            raise ValueError(
                f"points: too few points with positive weight to fit a line "
                f"({np.count_nonzero(w)} < 2)"
            )
        mean, direction = _weighted_principal_direction(pts, w)
        return cls(mean, direction)

    # -- geometry --------------------------------------------------------------------------

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.origin.shape[:-1]

    @property
    def ndim(self) -> int:
        """Dimension D of the space."""
        return self.origin.shape[-1]

    @property
    def principal_direction(self) -> np.ndarray:
        """The unit direction k0 (Chatelain 2013, eq. (22)), shape (..., D)."""
        return self.direction

    def __getitem__(self, index) -> LineModel:
        if not self.batch_shape:
            raise IndexError("cannot index a single (unbatched) LineModel")
        return LineModel(self.origin[index], self.direction[index])

    def __len__(self) -> int:
        if not self.batch_shape:
            raise TypeError("a single (unbatched) LineModel has no len()")
        return self.batch_shape[0]

    def is_valid(self) -> np.ndarray:
        """True where the parameters are finite (False for degenerate samples), shape (...)."""
        return np.isfinite(self.origin).all(-1) & np.isfinite(self.direction).all(-1)

    def parameter(self, points) -> np.ndarray:
        """Coordinate ``t`` of the orthogonal projection of (N, D) points, shape (..., N)."""
        d = np.asarray(points, dtype=float) - self.origin[..., None, :]
        return np.einsum("...nd,...d->...n", d, self.direction)

    def points_at(self, t) -> np.ndarray:
        """Points ``origin + t * direction`` for t of shape (K,) or (..., K): shape (..., K, D)."""
        t = np.asarray(t, dtype=float)
        return self.origin[..., None, :] + t[..., None] * self.direction[..., None, :]

    def residuals(self, points) -> np.ndarray:
        """Distance of (N, D) points to each line, shape (..., N) (Chatelain eq. (17))."""
        d = np.asarray(points, dtype=float) - self.origin[..., None, :]
        t = np.einsum("...nd,...d->...n", d, self.direction)
        return np.linalg.norm(d - t[..., None] * self.direction[..., None, :], axis=-1)

    def max_curvature(self) -> np.ndarray:
        """Curvature of a line: zeros of shape (...)."""
        return np.zeros(self.batch_shape)

    def oriented(self, reference) -> LineModel:
        """Same lines with directions flipped where they point away from ``reference`` (D,)."""
        sign = np.where(self.direction @ np.asarray(reference, dtype=float) < 0, -1.0, 1.0)
        return LineModel(self.origin, self.direction * sign[..., None])


def _poly_eval(coefficients: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Evaluate ``H [1 a ... a^(n-1)]^T`` (Chatelain eq. (16)).

    ``coefficients`` has shape (..., D, n), ``a`` shape (..., K); returns (..., K, D).
    An empty polynomial (n = 0, the derivative of a constant) evaluates to zeros.
    """
    n = coefficients.shape[-1]
    basis = a[..., None] ** np.arange(n)  # (..., K, n)
    return np.einsum("...dk,...jk->...jd", coefficients, basis)


@dataclass(frozen=True, eq=False)
class PolyCurveModel:
    """Batch of polynomial curves ``C(a, H) = H [1 a ... a^(n-1)]^T`` (Chatelain 2013, eq. (16)).

    The curvilinear coordinate of a point ``v`` is approximated by its projection on the
    principal direction ``k0``: ``a_hat = (v - p1) . k0`` (eq. (18)), where ``p1`` is
    :attr:`origin`. Residuals are the approximate point-to-curve distance
    ``||v - C(a_hat, H)||`` (eq. (18)).

    Parameters
    ----------
    coefficients : array, shape (..., D, n)
        The matrix H of eq. (16); column k multiplies ``a**k``. ``n`` is the number of control
        points (2 for a straight needle, 3 for a flexible one).
    origin : array, shape (..., D)
        The point ``p1`` from which ``a_hat`` is measured.
    axis : array, shape (..., D)
        The principal direction ``k0``; normalised to unit length on construction.
    span : array, shape (..., 2)
        Interval of ``a`` covered by the points the curve was estimated from; curvature is
        evaluated on it and :meth:`points_at` is meaningful there.
    """

    coefficients: np.ndarray
    origin: np.ndarray
    axis: np.ndarray
    span: np.ndarray

    def __post_init__(self):
        h = np.asarray(self.coefficients, dtype=float)
        origin = np.asarray(self.origin, dtype=float)
        axis = np.asarray(self.axis, dtype=float)
        span = np.asarray(self.span, dtype=float)
        if h.ndim < 2 or h.shape[-1] < 2:
            raise ValueError(f"coefficients must have shape (..., D, n) with n >= 2, got {h.shape}")
        batch, d = h.shape[:-2], h.shape[-2]
        if origin.shape != (*batch, d) or axis.shape != (*batch, d):
            raise ValueError(
                f"origin and axis must have shape {(*batch, d)}, "
                f"got {origin.shape} and {axis.shape}"
            )
        if span.shape != (*batch, 2):
            raise ValueError(f"span must have shape {(*batch, 2)}, got {span.shape}")
        with np.errstate(invalid="ignore", divide="ignore"):
            axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
        object.__setattr__(self, "coefficients", h)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "axis", axis)
        object.__setattr__(self, "span", span)

    # -- estimation ------------------------------------------------------------------------

    @classmethod
    def from_samples(cls, samples) -> PolyCurveModel:
        """Curves through minimal samples of n control points, shape (B, n, D), vectorised.

        ``k0`` is the principal direction of the straight line fitted to the control points
        (Chatelain eq. (18)), ``p1`` the first control point, and the control points get the
        coordinates ``a_i = (p_i - p1) . k0``; H solves the Vandermonde system
        ``H [1 a_i ... a_i^(n-1)]^T = p_i`` (eq. (16); for n = 2 this is Zhao eq. (B4)).
        Degenerate samples (two control points with the same ``a_i``) give NaN coefficients.
        """
        s = np.asarray(samples, dtype=float)
        if s.ndim != 3 or s.shape[1] < 2 or s.shape[2] < 2:
            raise ValueError(f"samples must have shape (B, n, D) with n, D >= 2, got {s.shape}")
        n = s.shape[1]
        _, k0 = _weighted_principal_direction(s, np.ones(s.shape[:2]))  # Chatelain eq. (18)
        p1 = s[:, 0]
        a = np.einsum("bnd,bd->bn", s - p1[:, None], k0)  # eq. (18): a_i = (p_i - p1) . k0
        vander = a[..., None] ** np.arange(n)  # (B, n, n) rows [1 a_i ... a_i^(n-1)]
        iu = np.triu_indices(n, 1)
        gaps = np.abs(a[:, iu[0]] - a[:, iu[1]]).min(axis=1)
        spread = np.abs(a).max(axis=1)
        ok = gaps > _DEGENERATE_RELATIVE_GAP * spread
        vander = np.where(ok[:, None, None], vander, np.eye(n))
        h = np.linalg.solve(vander, s)  # eq. (16) at the n control points: (B, n, D)
        h[~ok] = np.nan
        span = np.stack([a.min(axis=1), a.max(axis=1)], axis=-1)
        return cls(np.swapaxes(h, -1, -2), p1, k0, span)

    @classmethod
    def from_inliers(cls, points, weights=None, *, order: int = 3) -> PolyCurveModel:
        """Weighted least-squares curve with ``order`` control points through (N, D) points.

        ``k0`` is the weighted principal direction of the points and ``p1`` their weighted
        mean; H minimises ``sum_i w_i ||v_i - C(a_hat_i, H)||^2``, the weighted sum of squared
        eq. (18) distances, in closed form. Needs ``order`` points with positive weight at
        distinct positions along ``k0``.
        """
        order = _check_int(order, "order", 2)
        pts = _as_points(points)
        w = _as_weights(weights, len(pts))
        positive = w > 0
        if np.count_nonzero(positive) < order:
            raise ValueError(
                f"points: too few points with positive weight for a curve of order {order} "
                f"({np.count_nonzero(positive)} < {order})"
            )
        p1, k0 = _weighted_principal_direction(pts, w)
        a = (pts - p1) @ k0  # Chatelain eq. (18)
        sw = np.sqrt(w)[:, None]
        vander = a[:, None] ** np.arange(order)
        h, _, rank, _ = np.linalg.lstsq(vander * sw, pts * sw, rcond=None)
        if rank < order:
            raise ValueError(
                f"points: fewer than {order} distinct positions along the principal direction"
            )
        span = np.array([a[positive].min(), a[positive].max()])
        return cls(h.T, p1, k0, span)

    # -- geometry --------------------------------------------------------------------------

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.origin.shape[:-1]

    @property
    def ndim(self) -> int:
        """Dimension D of the space."""
        return self.origin.shape[-1]

    @property
    def order(self) -> int:
        """Number n of control points (columns of H)."""
        return self.coefficients.shape[-1]

    @property
    def principal_direction(self) -> np.ndarray:
        """The unit principal direction k0 (Chatelain 2013, eqs. (18) and (22)), shape (..., D)."""
        return self.axis

    def __getitem__(self, index) -> PolyCurveModel:
        if not self.batch_shape:
            raise IndexError("cannot index a single (unbatched) PolyCurveModel")
        return PolyCurveModel(
            self.coefficients[index], self.origin[index], self.axis[index], self.span[index]
        )

    def __len__(self) -> int:
        if not self.batch_shape:
            raise TypeError("a single (unbatched) PolyCurveModel has no len()")
        return self.batch_shape[0]

    def is_valid(self) -> np.ndarray:
        """True where all parameters are finite (False for degenerate samples), shape (...)."""
        return (
            np.isfinite(self.coefficients).all(axis=(-1, -2))
            & np.isfinite(self.origin).all(-1)
            & np.isfinite(self.axis).all(-1)
        )

    def parameter(self, points) -> np.ndarray:
        """Approximate curvilinear coordinate ``a_hat`` of (N, D) points (eq. (18)): (..., N)."""
        d = np.asarray(points, dtype=float) - self.origin[..., None, :]
        return np.einsum("...nd,...d->...n", d, self.axis)

    def points_at(self, a) -> np.ndarray:
        """Curve points ``C(a, H)`` (eq. (16)) for a of shape (K,) or (..., K): (..., K, D)."""
        return _poly_eval(self.coefficients, np.asarray(a, dtype=float))

    def residuals(self, points) -> np.ndarray:
        """Approximate point-to-curve distance of (N, D) points, shape (..., N).

        Chatelain 2013, eq. (18): ``d_hat(v, H) = ||v - C(a_hat, H)||``.
        """
        pts = np.asarray(points, dtype=float)
        a_hat = self.parameter(pts)  # eq. (18)
        return np.linalg.norm(pts - self.points_at(a_hat), axis=-1)

    def max_curvature(self) -> np.ndarray:
        """Largest curvature over :attr:`span`, shape (...).

        Curvature in D dimensions: ``sqrt(|C'|^2 |C''|^2 - (C'.C'')^2) / |C'|^3``, evaluated at
        evenly spaced values of ``a``. Stationary points (``C' = 0``) have infinite curvature.
        """
        n = self.order
        grid = np.linspace(0.0, 1.0, _CURVATURE_EVALUATIONS)
        a = self.span[..., :1] + (self.span[..., 1:] - self.span[..., :1]) * grid
        d1 = self.coefficients[..., 1:] * np.arange(1, n)  # H of C'(a)
        d2 = d1[..., 1:] * np.arange(1, n - 1)  # H of C''(a)
        c1 = _poly_eval(d1, a)
        c2 = _poly_eval(d2, a)
        n1 = np.einsum("...d,...d->...", c1, c1)
        n2 = np.einsum("...d,...d->...", c2, c2)
        dot = np.einsum("...d,...d->...", c1, c2)
        with np.errstate(invalid="ignore", divide="ignore"):
            kappa = np.sqrt(np.maximum(n1 * n2 - dot**2, 0.0)) / n1**1.5
        kappa = np.where(n1 > 0, kappa, np.inf)
        return kappa.max(axis=-1)

    def oriented(self, reference) -> PolyCurveModel:
        """Same curves with ``k0`` flipped where it points away from ``reference`` (D,).

        Flipping ``a -> -a`` multiplies column k of H by ``(-1)^k`` and mirrors the span.
        """
        sign = np.where(self.axis @ np.asarray(reference, dtype=float) < 0, -1.0, 1.0)
        powers = sign[..., None, None] ** np.arange(self.order)
        span = np.where(sign[..., None] < 0, -self.span[..., ::-1], self.span)
        axis = self.axis * sign[..., None]
        return PolyCurveModel(self.coefficients * powers, self.origin, axis, span)


# --------------------------------------------------------------------------------------------
# RANSAC loop
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RansacResult:
    """Outcome of :func:`ransac`; truthy on success, falsy on failure.

    Attributes
    ----------
    model : LineModel or PolyCurveModel or None
        The refined model (unbatched), None on failure.
    inliers : bool array, shape (N,)
        Points with residual below the threshold under ``model`` (all False on failure).
    n_trials : int
        Minimal samples drawn, rejected ones included.
    inlier_ratio : float
        Share of inliers, by count, or by weight when weights were given.
    sample : int array or None
        Indices of the minimal sample of the winning hypothesis.
    reason : str or None
        Why the fit failed; None on success.
    """

    model: LineModel | PolyCurveModel | None
    inliers: np.ndarray
    n_trials: int
    inlier_ratio: float
    sample: np.ndarray | None = None
    reason: str | None = None

    def __bool__(self) -> bool:
        return self.reason is None

    @classmethod
    def failure(cls, reason: str, n_points: int, n_trials: int = 0) -> RansacResult:
        return cls(None, np.zeros(n_points, dtype=bool), n_trials, 0.0, None, reason)


def adaptive_trial_count(inlier_ratio: float, n_samples: int, success_probability: float) -> float:
    """Number of minimal samples needed to draw one all-inlier sample with a given probability.

    Chatelain 2013, eq. (21), and Zhao 2013, eq. (B8)::

        J = ln(1 - eta) / ln(1 - zeta**n)

    rounded up (scikit-image's ``_dynamic_max_trials``; Hartley & Zisserman, Table 4.3).

    Parameters
    ----------
    inlier_ratio : float
        zeta in [0, 1], the share of inliers (by weight under weighted sampling).
    n_samples : int
        n, the size of a minimal sample.
    success_probability : float
        eta in [0, 1), the probability that at least one sample is outlier-free
        (Chatelain's failure threshold is ``epsilon = 1 - eta``).

    Returns
    -------
    float
        An integer-valued count; ``inf`` when ``inlier_ratio`` is 0; 0 when
        ``success_probability`` is 0; 1 when ``inlier_ratio`` is 1.
    """
    zeta = float(inlier_ratio)
    eta = float(success_probability)
    n = _check_int(n_samples, "n_samples", 1)
    if not 0.0 <= zeta <= 1.0:
        raise ValueError(f"inlier_ratio must be in [0, 1], got {inlier_ratio}")
    if not 0.0 <= eta < 1.0:
        raise ValueError(f"success_probability must be in [0, 1), got {success_probability}")
    if eta == 0.0:
        return 0.0
    if zeta == 0.0:
        return math.inf
    p_good = zeta**n
    if p_good >= 1.0:
        return 1.0
    trials = math.log1p(-eta) / math.log1p(-p_good)  # eq. (21) / eq. (B8)
    # Guard against rounding pushing an exact integer just above itself (e.g. 2.0000000004).
    return float(max(1, math.ceil(trials - 1e-9)))


def _draw_samples(weights: np.ndarray, n_draws: int, n_samples: int, rng) -> np.ndarray:
    """Indices of ``n_draws`` samples of ``n_samples`` distinct points, shape (n_draws, n_samples).

    Weighted sampling without replacement by exponential keys (Efraimidis & Spirakis 2006):
    each point gets the key ``log(u) / w`` with ``u ~ U(0, 1)`` and each sample keeps its
    ``n_samples`` largest keys. This has the law of drawing points one after the other with
    probability proportional to their weight; equal weights give uniform samples. Points of
    weight 0 get the key -inf and are drawn only if fewer points have positive weight.
    """
    u = rng.random((n_draws, weights.size))
    with np.errstate(divide="ignore"):
        keys = np.log(u) / weights
    return np.argpartition(keys, -n_samples, axis=1)[:, -n_samples:]


def _min_pairwise_distance(samples: np.ndarray) -> np.ndarray:
    """Zhao's ``kappa(N) = min_{i != j} ||N_i - N_j||`` for (B, m, D) samples: shape (B,)."""
    m = samples.shape[1]
    iu = np.triu_indices(m, 1)
    diffs = samples[:, iu[0]] - samples[:, iu[1]]
    return np.linalg.norm(diffs, axis=-1).min(axis=1)


_MODELS = {"line": LineModel, "curve": PolyCurveModel}


def ransac(
    points,
    model: str = "line",
    *,
    residual_threshold: float,
    weights=None,
    min_sample_distance: float = 0.0,
    max_curvature: float | None = None,
    predicted_direction=None,
    max_angle_deg: float | None = None,
    success_probability: float = 0.99,
    max_trials: int = 1000,
    batch_size: int = 64,
    order: int = 3,
    refine_iterations: int = 2,
    rng: np.random.Generator | int | None = None,
) -> RansacResult:
    """Fit a needle axis (line or polynomial curve) to candidate points with batched RANSAC.

    Chatelain 2013, II-D, and Zhao 2013, Appendix B. Each batch:

    1. draws ``batch_size`` minimal samples (uniformly, or with probability proportional to
       ``weights`` without replacement: likelihood-weighted sampling);
    2. rejects samples whose closest two points are nearer than ``min_sample_distance``
       (Zhao: ``kappa(N) < d_min``) or coincide;
    3. fits all hypotheses at once and rejects those with a curvature above
       ``max_curvature`` (Uhercik's constraint, Chatelain II-D) or an angle to
       ``predicted_direction`` above ``max_angle_deg`` (Chatelain eq. (22));
    4. scores the survivors as one (B, N) residual matrix: inliers have residual
       ``< residual_threshold`` (Chatelain eq. (19), Zhao eq. (B5)); the best hypothesis has
       the most inliers (the largest inlier weight when weights are given), ties broken by the
       smaller sum of inlier distances (Zhao eq. (B6));
    5. updates the number of trials needed, eq. (21) / eq. (B8), and stops once that many
       samples (or ``max_trials``) have been drawn.

    The winner is then refined ``refine_iterations`` times by weighted least squares on its
    inliers (closed-form line, Chatelain II-D; least-squares curve for n > 2), keeping a
    refinement only if it does not lose inlier weight. The refined model is not checked
    against the constraints again.

    Every sample drawn counts as a trial, rejected ones included: a rejected sample is not an
    all-inlier sample of an admissible axis, so eq. (21) keeps its meaning.

    Parameters
    ----------
    points : array, shape (N, D)
        Candidate points (voxel positions, in mm or in array indices), D >= 2.
    model : {"line", "curve"}
        :class:`LineModel` (minimal sample of 2) or :class:`PolyCurveModel` with ``order``
        control points (minimal sample of ``order``).
    residual_threshold : float
        f0 of eq. (19), r of eq. (B5): the expected needle radius, in the units of ``points``.
    weights : array, shape (N,), optional
        Non-negative likelihoods. They drive the sampling, the inlier count (sum of inlier
        weights), the inlier ratio of eq. (21) and the least-squares refinement.
    min_sample_distance : float
        d_min of Zhao: samples with two points closer than this are rejected.
    max_curvature : float, optional
        Hypotheses whose curvature (1 / length unit) exceeds this on the span of their
        control points are rejected. Lines always pass.
    predicted_direction : array, shape (D,), optional
        k0^- predicted by the Kalman filter. Also orients the returned model's direction.
    max_angle_deg : float, optional
        alpha_0 of Chatelain eq. (22), in [0, 90]. Requires ``predicted_direction``. The angle
        is sign-agnostic, ``acos(|k0 . k0^-|)``: a minimal sample has no order, so the sign of
        its direction is arbitrary and a needle axis is an unoriented line.
    success_probability : float
        eta of eq. (B8) (1 - epsilon of eq. (21)), in [0, 1).
    max_trials : int
        J_max of Zhao: an upper bound on the number of samples drawn.
    batch_size : int
        Hypotheses drawn and scored together.
    order : int
        Number n of control points of the curve model (ignored for lines).
    refine_iterations : int
        Least-squares refinements of the winner (0 disables).
    rng : numpy.random.Generator or int or None
        Random generator or seed.

    Returns
    -------
    RansacResult
        Truthy with the model, inlier mask, trial count and inlier ratio; falsy with a
        ``reason`` when there are too few points or no hypothesis passed the constraints.
    """
    pts = _as_points(points)
    n_points, dim = pts.shape
    if model not in _MODELS:
        raise ValueError(f"model must be one of {sorted(_MODELS)}, got {model!r}")
    threshold = _check_positive(residual_threshold, "residual_threshold")
    w = _as_weights(weights, n_points)
    d_min = _check_positive(min_sample_distance, "min_sample_distance", allow_zero=True)
    if max_curvature is not None:
        max_curvature = _check_positive(max_curvature, "max_curvature", allow_zero=True)
    k_pred = (
        None
        if predicted_direction is None
        else _as_vector(predicted_direction, dim, "predicted_direction")
    )
    cos_min = None
    if max_angle_deg is not None:
        if k_pred is None:
            raise ValueError("max_angle_deg requires predicted_direction")
        if not 0.0 <= float(max_angle_deg) <= 90.0:
            raise ValueError(f"max_angle_deg must be in [0, 90], got {max_angle_deg}")
        cos_min = math.cos(math.radians(float(max_angle_deg)))
    if not 0.0 <= float(success_probability) < 1.0:
        raise ValueError(f"success_probability must be in [0, 1), got {success_probability}")
    max_trials = _check_int(max_trials, "max_trials", 1)
    batch_size = _check_int(batch_size, "batch_size", 1)
    refine_iterations = _check_int(refine_iterations, "refine_iterations", 0)
    model_cls = _MODELS[model]
    m = 2 if model == "line" else _check_int(order, "order", 2)
    rng = np.random.default_rng(rng)

    if n_points < m:
        return RansacResult.failure(f"too few points: {n_points} < {m} needed", n_points)
    if np.count_nonzero(w) < m:
        return RansacResult.failure(
            f"too few points with positive weight: {np.count_nonzero(w)} < {m} needed", n_points
        )
    total_weight = w.sum()

    best = None  # (model, inliers, sample indices)
    best_score, best_cost = -np.inf, np.inf
    required = float(max_trials)  # Zhao: J starts at J_max
    trials = 0
    while trials < min(required, max_trials):
        n_draws = int(min(batch_size, min(required, max_trials) - trials))
        idx = _draw_samples(w, n_draws, m, rng)  # step 1, all samples of the batch at once
        trials += n_draws
        samples = pts[idx]  # (B, m, D)
        kappa = _min_pairwise_distance(samples)
        keep = (kappa >= d_min) & (kappa > 0)  # Zhao: reject kappa(N) < d_min
        if not keep.any():
            continue
        idx = idx[keep]
        hyp = model_cls.from_samples(samples[keep])  # step 2, vectorised over hypotheses
        ok = hyp.is_valid()
        if max_curvature is not None:
            with np.errstate(invalid="ignore"):
                ok &= hyp.max_curvature() <= max_curvature  # Uhercik's curvature constraint
        if cos_min is not None:
            cos_alpha = np.abs(hyp.principal_direction @ k_pred)  # Chatelain eq. (22)
            ok &= cos_alpha >= cos_min  # |alpha| <= alpha_0
        if not ok.any():
            continue
        hyp, idx = hyp[ok], idx[ok]
        res = hyp.residuals(pts)  # (B, N) residual matrix, Chatelain eq. (17)-(18)
        inl = res < threshold  # step 3: Chatelain eq. (19), Zhao eq. (B5)
        score = inl @ w  # |X_in|, or the inlier weight
        cost = np.where(inl, res, 0.0).sum(axis=1)  # Zhao eq. (B6)
        j = np.lexsort((cost, -score))[0]  # most inliers, then least cost
        if score[j] > best_score or (score[j] == best_score and cost[j] < best_cost):
            best = (hyp[j], inl[j], idx[j])
            best_score, best_cost = score[j], cost[j]
            # Chatelain eq. (21), Zhao eq. (B8): bound p_in by the best inlier ratio so far
            required = adaptive_trial_count(best_score / total_weight, m, success_probability)

    if best is None:
        return RansacResult.failure(
            "no hypothesis passed the constraints (min_sample_distance, max_curvature, "
            "max_angle_deg)",
            n_points,
            trials,
        )

    fitted, inliers, sample = best
    score = best_score
    for _ in range(refine_iterations):  # local optimisation, Chatelain II-D
        try:
            if model == "line":
                refit = LineModel.from_inliers(pts[inliers], w[inliers])
            else:
                refit = PolyCurveModel.from_inliers(pts[inliers], w[inliers], order=m)
        except ValueError:  # degenerate inlier set: keep the current model
            break
        refit_inliers = refit.residuals(pts) < threshold  # eq. (19)
        refit_score = w[refit_inliers].sum()
        if refit_score < score:
            break
        fitted, inliers, score = refit, refit_inliers, refit_score
    if k_pred is not None:
        fitted = fitted.oriented(k_pred)
    return RansacResult(fitted, inliers, trials, float(score / total_weight), np.sort(sample))


# --------------------------------------------------------------------------------------------
# Tip along the axis
# --------------------------------------------------------------------------------------------


def sample_along_axis(image, origin, direction, spacing, t_values, *, cval: float = np.nan):
    """Sample an image or volume along a line by linear interpolation.

    Points are ``origin + t * u`` with ``u = direction / ||direction||``, in physical units
    (mm) and array axis order; they are divided by ``spacing`` to get array indices, so index
    ``i`` along an axis lies at ``i * spacing``. With ``spacing=1`` everything is in array
    index space. Values come from :func:`scipy.ndimage.map_coordinates` (order 1).

    Parameters
    ----------
    image : array, shape (rows, cols) or (d0, d1, d2)
    origin, direction : array, shape (image.ndim,)
    spacing : float or array, shape (image.ndim,)
        Voxel size per axis (> 0).
    t_values : array, shape (K,)
        Distances along the unit direction from ``origin``.
    cval : float
        Value outside the array; NaN by default, which :func:`tip_along_axis` reads as below
        any threshold.

    Returns
    -------
    array, shape (K,)
    """
    img = np.asarray(image, dtype=float)
    if img.ndim not in (2, 3):
        raise ValueError(f"image must be 2D or 3D, got shape {img.shape}")
    o = np.asarray(origin, dtype=float)
    if o.shape != (img.ndim,) or not np.all(np.isfinite(o)):
        raise ValueError(f"origin must be finite with shape ({img.ndim},), got {origin!r}")
    u = _as_vector(direction, img.ndim, "direction")
    sp = np.broadcast_to(np.asarray(spacing, dtype=float), (img.ndim,))
    if not np.all(np.isfinite(sp) & (sp > 0)):
        raise ValueError(f"spacing must be finite and > 0, got {spacing!r}")
    t = np.asarray(t_values, dtype=float)
    if t.ndim != 1 or not np.all(np.isfinite(t)):
        raise ValueError(f"t_values must be a finite 1D array, got shape {t.shape}")
    coords = (o + t[:, None] * u) / sp  # (K, ndim) array indices
    return ndimage.map_coordinates(img, coords.T, order=1, mode="constant", cval=cval)


@dataclass(frozen=True)
class AxisTip:
    """Tip found by :func:`tip_along_axis`; truthy when found.

    Attributes
    ----------
    position : float
        Tip position along the axis (units of ``positions``), with the threshold crossing
        interpolated linearly between the last needle sample and the next; NaN if not found.
    index : int
        Index of the last sample on the needle; -1 if not found.
    reaches_end : bool
        True when the needle does not drop before the last sample: the true tip may lie
        beyond the sampled range.
    reason : str or None
        Why no tip was found; None when found.
    """

    position: float
    index: int
    reaches_end: bool
    reason: str | None = None

    def __bool__(self) -> bool:
        return self.reason is None


def tip_along_axis(values_along_axis, positions_along_axis, threshold: float, max_gap: float):
    """Locate the needle tip as the point where the profile drops below ``threshold`` for good.

    Zhao 2013, Appendix B ("a significant drop below the threshold value is considered as the
    tip position") and Chatelain 2013, II-D ("we discard small intensity gaps"). Walking from
    the entry end (the first sample, smallest position) the needle starts at the first sample
    at or above ``threshold``; a run of samples below the threshold is a *gap*, of length the
    distance from its first sample to the next sample above the threshold. Gaps shorter than
    ``max_gap`` are bridged; the tip is the last needle sample before the first gap of length
    ``>= max_gap`` (or before the end of the profile).

    Parameters
    ----------
    values_along_axis : array, shape (K,)
        Intensity or likelihood profile; NaN (outside the volume) counts as below threshold.
    positions_along_axis : array, shape (K,)
        Strictly increasing positions along the axis, from the entry end.
    threshold : float
    max_gap : float
        Longest gap (in the units of ``positions``) that does not end the needle; >= 0.

    Returns
    -------
    AxisTip
    """
    v = np.asarray(values_along_axis, dtype=float)
    p = np.asarray(positions_along_axis, dtype=float)
    if v.ndim != 1 or v.size == 0:
        raise ValueError(f"values_along_axis must be a non-empty 1D array, got shape {v.shape}")
    if p.shape != v.shape:
        raise ValueError(
            f"positions_along_axis must have the shape of values_along_axis {v.shape}, "
            f"got {p.shape}"
        )
    if not np.all(np.isfinite(p)) or np.any(np.diff(p) <= 0):
        raise ValueError("positions_along_axis must be finite and strictly increasing")
    if not np.isfinite(threshold):
        raise ValueError(f"threshold must be finite, got {threshold}")
    max_gap = _check_positive(max_gap, "max_gap", allow_zero=True)

    above = np.greater_equal(v, threshold, where=np.isfinite(v), out=np.zeros(v.shape, bool))
    on = np.flatnonzero(above)
    if on.size == 0:
        return AxisTip(math.nan, -1, False, "no sample reaches the threshold")
    # Gap between consecutive needle samples on[i] < on[i+1]: from the first sample below the
    # threshold, on[i] + 1, to the next sample above it, on[i+1]; none when they are adjacent.
    has_gap = np.diff(on) > 1
    gap_length = p[on[1:]] - p[on[:-1] + 1]
    ends = np.flatnonzero(has_gap & (gap_length >= max_gap))
    last = int(on[ends[0]] if ends.size else on[-1])
    if last == v.size - 1:
        return AxisTip(float(p[last]), last, True)
    v_last, v_next = v[last], v[last + 1]
    position = p[last]
    if np.isfinite(v_next) and v_last > v_next:  # interpolate the threshold crossing
        position += (v_last - threshold) / (v_last - v_next) * (p[last + 1] - p[last])
    return AxisTip(float(position), last, False)
