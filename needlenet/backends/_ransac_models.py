"""The models RANSAC fits to needle points (:mod:`._ransac`), for N-dimensional points.

* :class:`LineModel`: a point and a unit direction (Zhao 2013 Appendix B, eqs. (B2)-(B4));
* :class:`PolyCurveModel`: the polynomial curve of Chatelain 2013 eq. (16), scored with the
  approximate point-to-curve distance of eq. (18).

Both implement :class:`RansacModel`, the protocol the loop of :func:`~._ransac.ransac` relies
on: the size of a minimal sample, a batched estimate from minimal samples, residuals, a
validity mask, a least-squares refinement on inliers and an orientation along a reference
direction. Model classes hold a *batch* of models: every parameter array has leading batch
axes (``origin`` has shape ``(..., D)``), so ``residuals(points)`` returns ``(..., N)``:
``(B, N)`` for the ``B`` hypotheses of a batch and ``(N,)`` for the single model that
:func:`~._ransac.ransac` returns. ``model[i]`` selects hypotheses; the batch plumbing
(indexing, length, shapes, finiteness, the coordinate along the principal direction) lives
once in :class:`_BatchedModel`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from ._fit_checks import _as_points, _as_weights, _check_int

__all__ = ["LineModel", "PolyCurveModel", "RansacModel"]

# A minimal sample whose curvilinear coordinates are closer than this fraction of their spread
# gives a singular Vandermonde system (Chatelain eq. (16)) and is treated as degenerate.
_DEGENERATE_RELATIVE_GAP = 1e-9
# Number of parameter values at which the curvature of a hypothesis is evaluated.
_CURVATURE_EVALUATIONS = 9


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


class RansacModel(Protocol):
    """What :func:`~._ransac.ransac` needs of a model class; instances are batches of models.

    ``sample_size(order)`` is the size m of a minimal sample; ``from_samples`` fits a batch of
    B models to (B, m, D) minimal samples at once; ``residuals`` gives the (B, N) distances of
    N points; ``is_valid`` masks degenerate fits; ``refine`` refits one model to its inliers
    by weighted least squares; ``oriented`` flips the principal direction towards a reference;
    ``model[i]`` selects hypotheses.
    """

    @classmethod
    def sample_size(cls, order: int) -> int: ...

    @classmethod
    def from_samples(cls, samples) -> RansacModel: ...

    @property
    def ndim(self) -> int: ...

    @property
    def principal_direction(self) -> np.ndarray: ...

    def __getitem__(self, index) -> RansacModel: ...

    def is_valid(self) -> np.ndarray: ...

    def residuals(self, points) -> np.ndarray: ...

    def refine(self, points, weights) -> RansacModel: ...

    def oriented(self, reference) -> RansacModel: ...


class _BatchedModel:
    """Batch plumbing shared by the models: every dataclass field has leading batch axes.

    Subclasses are frozen dataclasses with an ``origin`` field of shape (..., D), define
    :attr:`principal_direction`, and list in ``_finite_fields`` the fields (with the number
    of their trailing, non-batch axes) that must be finite for a model to be valid.
    """

    _finite_fields: ClassVar[tuple[tuple[str, int], ...]] = ()

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.origin.shape[:-1]

    @property
    def ndim(self) -> int:
        """Dimension D of the space."""
        return self.origin.shape[-1]

    def __getitem__(self, index):
        if not self.batch_shape:
            raise IndexError(f"cannot index a single (unbatched) {type(self).__name__}")
        return type(self)(*(getattr(self, f.name)[index] for f in dataclasses.fields(self)))

    def __len__(self) -> int:
        if not self.batch_shape:
            raise TypeError(f"a single (unbatched) {type(self).__name__} has no len()")
        return self.batch_shape[0]

    def is_valid(self) -> np.ndarray:
        """True where the parameters are finite (False for degenerate samples), shape (...)."""
        ok = np.ones(self.batch_shape, dtype=bool)
        for name, core in self._finite_fields:
            ok = ok & np.isfinite(getattr(self, name)).all(axis=tuple(range(-core, 0)))
        return ok

    def parameter(self, points) -> np.ndarray:
        """Coordinate of the orthogonal projection of (N, D) points on the principal
        direction, measured from :attr:`origin`: shape (..., N)."""
        d = np.asarray(points, dtype=float) - self.origin[..., None, :]
        return np.einsum("...nd,...d->...n", d, self.principal_direction)


@dataclass(frozen=True, eq=False)
class LineModel(_BatchedModel):
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

    _finite_fields: ClassVar[tuple[tuple[str, int], ...]] = (("origin", 1), ("direction", 1))

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
    def sample_size(cls, order: int = 2) -> int:
        """Two points define a line; ``order`` is ignored."""
        return 2

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

    def refine(self, points, weights=None) -> LineModel:
        """The least-squares line through (N, D) inliers (:meth:`from_inliers`)."""
        return type(self).from_inliers(points, weights)

    # -- geometry --------------------------------------------------------------------------

    @property
    def principal_direction(self) -> np.ndarray:
        """The unit direction k0 (Chatelain 2013, eq. (22)), shape (..., D)."""
        return self.direction

    def points_at(self, t) -> np.ndarray:
        """Points ``origin + t * direction`` for t of shape (K,) or (..., K): shape (..., K, D)."""
        t = np.asarray(t, dtype=float)
        return self.origin[..., None, :] + t[..., None] * self.direction[..., None, :]

    def residuals(self, points) -> np.ndarray:
        """Distance of (N, D) points to each line, shape (..., N) (Chatelain eq. (17)).

        Pythagoras on matrix products, |p - o|^2 - ((p - o) . u)^2, instead of the (..., N, D)
        difference vectors: for 64 hypotheses and 3,000 points 15 times faster, equal to
        4e-12 mm at 60 mm coordinates."""
        p = np.asarray(points, dtype=float)
        o, u = self.origin, self.direction
        po = o @ p.T  # (..., N)
        pu = u @ p.T
        oo = np.einsum("...d,...d->...", o, o)[..., None]
        ou = np.einsum("...d,...d->...", o, u)[..., None]
        d2 = np.einsum("nd,nd->n", p, p) - 2.0 * po + oo - (pu - ou) ** 2
        return np.sqrt(np.maximum(d2, 0.0))

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
class PolyCurveModel(_BatchedModel):
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

    _finite_fields: ClassVar[tuple[tuple[str, int], ...]] = (
        ("coefficients", 2), ("origin", 1), ("axis", 1))

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
    def sample_size(cls, order: int = 3) -> int:
        """A curve of ``order`` control points (Chatelain eq. (16)) needs ``order`` points."""
        return _check_int(order, "order", 2)

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

    def refine(self, points, weights=None) -> PolyCurveModel:
        """The least-squares curve of the same order through (N, D) inliers
        (:meth:`from_inliers`)."""
        return type(self).from_inliers(points, weights, order=self.order)

    # -- geometry --------------------------------------------------------------------------

    @property
    def order(self) -> int:
        """Number n of control points (columns of H)."""
        return self.coefficients.shape[-1]

    @property
    def principal_direction(self) -> np.ndarray:
        """The unit principal direction k0 (Chatelain 2013, eqs. (18) and (22)), shape (..., D)."""
        return self.axis

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
