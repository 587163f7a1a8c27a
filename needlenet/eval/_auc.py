"""ROC AUC by ranks (Mann-Whitney U), for likelihood maps."""

from __future__ import annotations

import numpy as np
from scipy.stats import rankdata

__all__ = ["roc_auc"]


def roc_auc(positives: np.ndarray, negatives: np.ndarray) -> float:
    """Probability that a positive scores above a negative (ties count half); NaN if either
    set is empty."""
    P = np.asarray(positives, float).ravel()
    N = np.asarray(negatives, float).ravel()
    if P.size == 0 or N.size == 0:
        return float("nan")
    ranks = rankdata(np.concatenate([P, N]))  # average ranks for ties
    return float((ranks[: P.size].sum() - P.size * (P.size + 1) / 2) / (P.size * N.size))
