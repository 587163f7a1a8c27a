"""Whether a tracker's reported tip covariance is honest: the share of tracked frames whose
labelled tip lies inside the reported region (95% of them when the covariance is the error's)."""

from __future__ import annotations

import numpy as np

__all__ = ["COVERAGE_PROBABILITY", "region_coverage", "reported_tips", "tip_coverage"]

# the probability of the reported region that is tested
COVERAGE_PROBABILITY = 0.95


def region_coverage(errors: np.ndarray, covariances: np.ndarray,
                    probability: float = COVERAGE_PROBABILITY) -> tuple[int, int]:
    """(frames with a usable covariance, those whose error (N, D) lies inside the
    ``probability`` region of its covariance (N, D, D): Mahalanobis distance within the
    chi-square point of D degrees of freedom). A covariance that is not finite or not positive
    definite is no region."""
    from ..backends import chi2_gate

    y = np.asarray(errors, float)
    cov = np.asarray(covariances, float)
    if not len(y):
        return 0, 0
    usable = np.all(np.isfinite(cov), axis=(1, 2)) & np.all(np.isfinite(y), axis=1)
    usable[usable] &= np.all(np.linalg.eigvalsh(cov[usable]) > 0, axis=1)
    if not usable.any():
        return 0, 0
    y, cov = y[usable], cov[usable]
    d2 = np.einsum("ni,ni->n", y, np.linalg.solve(cov, y[..., None])[..., 0])
    return len(y), int(np.count_nonzero(np.sqrt(d2) <= chi2_gate(y.shape[1], probability)))


def reported_tips(estimates, nd: int) -> tuple[np.ndarray, np.ndarray]:
    """The estimates' tips (T, nd) and tip covariances (T, nd, nd), NaN where none (or of
    another dimension)."""
    tips = np.full((len(estimates), nd), np.nan)
    covs = np.full((len(estimates), nd, nd), np.nan)
    for k, e in enumerate(estimates):
        if e.tip_mm is not None and np.shape(e.tip_mm) == (nd,):
            tips[k] = e.tip_mm
        if e.covariance is not None and np.shape(e.covariance) == (nd, nd):
            covs[k] = e.covariance
    return tips, covs


def tip_coverage(estimates, seq) -> float | None:
    """The share of ``seq``'s frames reported ``tracking`` with a visible, labelled tip whose
    tip lies inside the reported ``COVERAGE_PROBABILITY`` region; None without such frames."""
    if seq.tip_mm is None:
        return None
    true = np.asarray(seq.tip_mm, float)
    tips, covs = reported_tips(estimates, true.shape[1])
    frames = np.array([e.status.value == "tracking" for e in estimates], bool) & \
        np.all(np.isfinite(true), axis=1)
    if seq.visible is not None:
        frames &= np.asarray(seq.visible, bool)
    usable, inside = region_coverage(tips[frames] - true[frames], covs[frames])
    return inside / usable if usable else None
