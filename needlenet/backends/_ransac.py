"""Batched, constrained RANSAC for needle axes in 2D images and 3D volumes.

Implements the needle localisation of Chatelain 2013 (section II-D, eqs. (15)-(22)) and the
model-fitting RANSAC of Zhao 2013 (Appendix B, eqs. (B1)-(B8)):

* the models (:mod:`._ransac_models`): :class:`LineModel` (a point and a unit direction, Zhao
  eqs. (B2)-(B4)) and :class:`PolyCurveModel`, the polynomial curve of Chatelain eq. (16) scored
  with the approximate point-to-curve distance of eq. (18), both implementing the
  :class:`RansacModel` protocol;
* the papers' constraints as validity checks (:mod:`._ransac_checks`): Zhao's minimum distance
  between sample points, Uhercik's curvature bound (quoted by Chatelain) and the angle to a
  predicted direction (Chatelain eq. (22));
* one generic loop, :func:`ransac`, in named steps: draw ``batch_size`` minimal samples at once
  (:func:`_draw_samples`, uniformly or weighted by a likelihood), reject degenerate samples
  (:func:`_reject_degenerate`), estimate every hypothesis of the batch at once, validate them
  (:func:`_validate`), score the survivors as one ``(B, N)`` residual matrix (:func:`_score`,
  eq. (19) / eq. (B5), ties broken by the cost (B6)), stop with the adaptive trial count of
  eq. (21) / eq. (B8), and refine the winner by least squares on its inliers
  (:func:`_refine`);
* the tip search along the fitted axis (Zhao Appendix B, Chatelain II-D) lives in
  :mod:`._axis_profile`.

The layout follows scikit-image's ``skimage/measure/fit.py`` (model classes with ``residuals``
and class-method estimators, ``is_model_valid``, ``_dynamic_max_trials``, a falsy result on
failure) and the batching and the steps follow Kornia's ``geometry/ransac.py``: the only Python
loops run over batches of hypotheses, over the checks and over refinement iterations, never
over hypotheses or points.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ._fit_checks import _as_points, _as_vector, _as_weights, _check_int, _check_positive
from ._ransac_checks import min_pairwise_distance
from ._ransac_models import LineModel, PolyCurveModel, RansacModel

__all__ = ["RansacResult", "adaptive_trial_count", "ransac"]


@dataclass(frozen=True, eq=False)
class RansacResult:
    """Outcome of :func:`ransac`; truthy on success, falsy on failure.

    Attributes
    ----------
    model : RansacModel or None
        The refined model (unbatched), a :class:`LineModel` or :class:`PolyCurveModel` for
        the built-in models; None on failure.
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

    model: RansacModel | None
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


Checks = Callable[..., np.ndarray] | Sequence[Callable[..., np.ndarray]] | None

_MODELS = {"line": LineModel, "curve": PolyCurveModel}


def _as_checks(checks: Checks, name: str) -> tuple[Callable[..., np.ndarray], ...]:
    """``checks`` as a tuple of callables: none, one, or a sequence of them."""
    if checks is None:
        return ()
    if callable(checks):
        return (checks,)
    checks = tuple(checks)
    if not all(callable(c) for c in checks):
        raise ValueError(f"{name} must be a callable or a sequence of callables")
    return checks


def _reject_degenerate(samples: np.ndarray, checks) -> np.ndarray:
    """Samples worth fitting, shape (B,): no two points coincide and every check passes."""
    keep = min_pairwise_distance(samples) > 0  # coincident points define no axis
    for check in checks:
        keep &= check(samples)  # e.g. Zhao: reject kappa(N) < d_min
    return keep


def _validate(hypotheses: RansacModel, checks) -> np.ndarray:
    """Hypotheses to score, shape (B,): finite parameters and every check passes."""
    ok = hypotheses.is_valid()
    for check in checks:
        ok &= check(hypotheses)  # e.g. Uhercik's curvature, Chatelain eq. (22)
    return ok


def _score(hypotheses: RansacModel, points: np.ndarray, weights: np.ndarray, threshold: float):
    """Inlier masks (B, N), scores (B,) and costs (B,) of a batch of hypotheses.

    The (B, N) residual matrix (Chatelain eqs. (17)-(18)); inliers have residual below the
    threshold (Chatelain eq. (19), Zhao eq. (B5)); the score is their count, or their weight;
    the cost is the sum of inlier distances (Zhao eq. (B6)).
    """
    res = hypotheses.residuals(points)  # (B, N) residual matrix, Chatelain eq. (17)-(18)
    inl = res < threshold  # Chatelain eq. (19), Zhao eq. (B5)
    score = inl @ weights  # |X_in|, or the inlier weight
    cost = np.where(inl, res, 0.0).sum(axis=1)  # Zhao eq. (B6)
    return inl, score, cost


def _refine(fitted: RansacModel, inliers: np.ndarray, score: float, points: np.ndarray,
            weights: np.ndarray, threshold: float, iterations: int):
    """Refit the winner to its inliers by weighted least squares, ``iterations`` times.

    Local optimisation, Chatelain II-D: a refit is kept only if it does not lose inlier weight;
    a degenerate inlier set keeps the current model. Returns (model, inliers, score).
    """
    for _ in range(iterations):
        try:
            refit = fitted.refine(points[inliers], weights[inliers])
        except ValueError:  # degenerate inlier set: keep the current model
            break
        refit_inliers = refit.residuals(points) < threshold  # eq. (19)
        refit_score = weights[refit_inliers].sum()
        if refit_score < score:
            break
        fitted, inliers, score = refit, refit_inliers, refit_score
    return fitted, inliers, score


def ransac(
    points,
    model: str | type[RansacModel] = "line",
    *,
    residual_threshold: float,
    weights=None,
    is_sample_valid: Checks = None,
    is_model_valid: Checks = None,
    predicted_direction=None,
    success_probability: float = 0.99,
    max_trials: int = 1000,
    batch_size: int = 64,
    order: int = 3,
    refine_iterations: int = 2,
    rng: np.random.Generator | int | None = None,
) -> RansacResult:
    """Fit a needle axis (line or polynomial curve) to candidate points with batched RANSAC.

    Chatelain 2013, II-D, and Zhao 2013, Appendix B. Each batch:

    1. samples: draws ``batch_size`` minimal samples (uniformly, or with probability
       proportional to ``weights`` without replacement: likelihood-weighted sampling);
    2. rejects degenerate samples: coincident points, or a failed ``is_sample_valid`` check
       (e.g. :func:`min_sample_distance`, Zhao's ``kappa(N) < d_min``);
    3. estimates all hypotheses at once (``model.from_samples``);
    4. validates them: finite parameters and every ``is_model_valid`` check (e.g.
       :func:`max_curvature`, Uhercik's constraint; :func:`within_angle`, Chatelain eq. (22));
    5. scores the survivors as one (B, N) residual matrix: inliers have residual
       ``< residual_threshold`` (Chatelain eq. (19), Zhao eq. (B5)); the best hypothesis has
       the most inliers (the largest inlier weight when weights are given), ties broken by the
       smaller sum of inlier distances (Zhao eq. (B6));
    6. updates the number of trials needed, eq. (21) / eq. (B8), and stops once that many
       samples (or ``max_trials``) have been drawn.

    The winner is then refined ``refine_iterations`` times by weighted least squares on its
    inliers (closed-form line, Chatelain II-D; least-squares curve for n > 2), keeping a
    refinement only if it does not lose inlier weight. The refined model is not checked
    again.

    Every sample drawn counts as a trial, rejected ones included: a rejected sample is not an
    all-inlier sample of an admissible axis, so eq. (21) keeps its meaning.

    Parameters
    ----------
    points : array, shape (N, D)
        Candidate points (voxel positions, in mm or in array indices), D >= 2.
    model : {"line", "curve"} or a class implementing :class:`RansacModel`
        :class:`LineModel` (minimal sample of 2) or :class:`PolyCurveModel` with ``order``
        control points (minimal sample of ``order``).
    residual_threshold : float
        f0 of eq. (19), r of eq. (B5): the expected needle radius, in the units of ``points``.
    weights : array, shape (N,), optional
        Non-negative likelihoods. They drive the sampling, the inlier count (sum of inlier
        weights), the inlier ratio of eq. (21) and the least-squares refinement.
    is_sample_valid : callable or sequence of callables, optional
        ``check(samples) -> (B,) bool`` on (B, m, D) minimal samples; all must hold.
    is_model_valid : callable or sequence of callables, optional
        ``check(hypotheses) -> (B,) bool`` on a batch of models; all must hold.
    predicted_direction : array, shape (D,), optional
        k0^- predicted by the Kalman filter: orients the returned model's direction.
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
        ``reason`` when there are too few points or no hypothesis passed the checks.
    """
    pts = _as_points(points)
    n_points, dim = pts.shape
    if isinstance(model, str):
        if model not in _MODELS:
            raise ValueError(f"model must be one of {sorted(_MODELS)}, got {model!r}")
        model = _MODELS[model]
    threshold = _check_positive(residual_threshold, "residual_threshold")
    w = _as_weights(weights, n_points)
    sample_checks = _as_checks(is_sample_valid, "is_sample_valid")
    model_checks = _as_checks(is_model_valid, "is_model_valid")
    k_pred = (
        None
        if predicted_direction is None
        else _as_vector(predicted_direction, dim, "predicted_direction")
    )
    if not 0.0 <= float(success_probability) < 1.0:
        raise ValueError(f"success_probability must be in [0, 1), got {success_probability}")
    max_trials = _check_int(max_trials, "max_trials", 1)
    batch_size = _check_int(batch_size, "batch_size", 1)
    refine_iterations = _check_int(refine_iterations, "refine_iterations", 0)
    m = model.sample_size(order)
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
        idx = _draw_samples(w, n_draws, m, rng)  # 1. sample, the whole batch at once
        trials += n_draws
        samples = pts[idx]  # (B, m, D)
        keep = _reject_degenerate(samples, sample_checks)  # 2.
        if not keep.any():
            continue
        idx = idx[keep]
        hyp = model.from_samples(samples[keep])  # 3. estimate, vectorised over hypotheses
        ok = _validate(hyp, model_checks)  # 4.
        if not ok.any():
            continue
        hyp, idx = hyp[ok], idx[ok]
        inl, score, cost = _score(hyp, pts, w, threshold)  # 5.
        j = np.lexsort((cost, -score))[0]  # most inliers, then least cost
        if score[j] > best_score or (score[j] == best_score and cost[j] < best_cost):
            best = (hyp[j], inl[j], idx[j])
            best_score, best_cost = score[j], cost[j]
            # 6. Chatelain eq. (21), Zhao eq. (B8): bound p_in by the best inlier ratio so far
            required = adaptive_trial_count(best_score / total_weight, m, success_probability)

    if best is None:
        names = ", ".join(["distinct sample points", "finite model",
                           *(getattr(c, "name", getattr(c, "__name__", repr(c)))
                             for c in (*sample_checks, *model_checks))])
        return RansacResult.failure(
            f"no hypothesis passed the constraints ({names})", n_points, trials
        )

    fitted, inliers, sample = best
    fitted, inliers, score = _refine(
        fitted, inliers, best_score, pts, w, threshold, refine_iterations
    )
    if k_pred is not None:
        fitted = fitted.oriented(k_pred)
    return RansacResult(fitted, inliers, trials, float(score / total_weight), np.sort(sample))
