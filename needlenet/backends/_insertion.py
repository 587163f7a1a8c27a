"""Needle insertion detection from frame or volume differences.

Implements Chatelain 2013, section II-B ("Insertion detection"):

1. the difference ``Delta I_t = |I_t - I_(t-1)|`` between consecutive frames or volumes (or any
   precomputed change map, e.g. a change in likelihood maps);
2. a candidate set of fixed size, obtained by thresholding the difference at the level T_t
   that keeps exactly ``n_candidates`` voxels (eq. (1)): :func:`candidate_set`;
3. a variance test: a needle moving in creates *localised* changes, so the spread of the
   candidate positions must be below a threshold tau; a global motion of the tissues (or a
   gain change) spreads candidates over the whole volume;
4. the geometric median of the candidates (eq. (2)) by Weiszfeld's algorithm, initialised at
   the mean: :func:`geometric_median`;
5. the entry point E_t, projection of the median on the nearest face of the volume, accepted
   only if ``||E_t - Med|| < delta``.

:func:`detect_insertion` is the pure function; :class:`InsertionDetector` keeps the previous
frame and calls it. All of it works on 2D images and 3D volumes alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Detection",
    "InsertionDetector",
    "InsertionParams",
    "candidate_set",
    "detect_insertion",
    "geometric_median",
]


def geometric_median(points, weights=None, tol: float = 1e-6, max_iter: int = 200) -> np.ndarray:
    """Weighted geometric median ``argmin_y sum_i w_i ||x_i - y||`` (Chatelain 2013, eq. (2)).

    Weiszfeld's algorithm, an iteratively re-weighted least squares: starting from the
    (weighted) mean, as Chatelain does,

        y <- sum_i (w_i / d_i) x_i / sum_i (w_i / d_i),   d_i = ||x_i - y||.

    When an iterate lands on data points (``d_i = 0``, where the plain step divides by zero)
    the modification of Vardi & Zhang (2000) is used: with ``eta`` the weight at ``y`` and
    ``R = sum_{d_i > 0} w_i (x_i - y) / d_i``, ``y`` is the median if ``||R|| <= eta``;
    otherwise ``y <- (1 - eta/||R||) T(y) + (eta/||R||) y`` with T the Weiszfeld step over the
    other points. This converges to the median even when it is a data point.

    Parameters
    ----------
    points : array, shape (N, D)
    weights : array, shape (N,), optional
        Non-negative weights, not all zero.
    tol : float
        Stop when an iterate moves less than this (units of ``points``).
    max_iter : int
        Maximum number of iterations; the last iterate is returned when reached.

    Returns
    -------
    array, shape (D,)
    """
    x = np.asarray(points, dtype=float)
    if x.ndim != 2 or x.shape[0] == 0:
        raise ValueError(f"points must have shape (N, D) with N >= 1, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("points contains NaN or infinite values")
    if weights is None:
        w = np.ones(len(x))
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape != (len(x),):
            raise ValueError(f"weights must have shape ({len(x)},), got {w.shape}")
        if not np.all(np.isfinite(w)) or np.any(w < 0) or not w.sum() > 0:
            raise ValueError("weights must be finite, non-negative and not all zero")
    if not (np.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be finite and > 0, got {tol}")
    if isinstance(max_iter, bool) or int(max_iter) != max_iter or max_iter < 1:
        raise ValueError(f"max_iter must be an integer >= 1, got {max_iter!r}")

    # Distances below this count as "on a data point"; relative to the extent of the data.
    extent = float(np.ptp(x, axis=0).max())
    coincide = 1e-12 * max(extent, 1.0)

    y = w @ x / w.sum()  # initialisation at the (weighted) mean, Chatelain II-B
    for _ in range(int(max_iter)):
        diff = x - y
        d = np.linalg.norm(diff, axis=1)
        at_y = d <= coincide
        inv = np.where(at_y, 0.0, w / np.where(at_y, 1.0, d))  # w_i / d_i
        if not inv.sum() > 0:  # every point with positive weight sits at y
            return y
        step = inv @ x / inv.sum()  # Weiszfeld step, eq. (2)
        eta = w[at_y].sum()
        if eta > 0:  # Vardi & Zhang (2000): the iterate is on data points
            r = np.linalg.norm(inv @ diff)
            if r <= eta:  # zero is in the subgradient: y is the median
                return y
            beta = eta / r
            step = (1.0 - beta) * step + beta * y
        moved = np.linalg.norm(step - y)
        y = step
        if moved < tol:
            break
    # Weiszfeld converges only linearly towards a median that is a data point: return that
    # point exactly when it satisfies the optimality condition ||R|| <= eta.
    nearest = np.argmin(np.linalg.norm(x - y, axis=1))
    diff = x - x[nearest]
    d = np.linalg.norm(diff, axis=1)
    at_point = d <= coincide
    inv = np.where(at_point, 0.0, w / np.where(at_point, 1.0, d))
    if np.linalg.norm(inv @ diff) <= w[at_point].sum():
        return x[nearest].copy()
    return y


def candidate_set(difference, n_candidates: int) -> tuple[np.ndarray, float]:
    """The ``n_candidates`` voxels with the largest difference (Chatelain 2013, eq. (1)).

    ``X_t = {v : Delta I_t(v) >= T_t}`` with T_t chosen so that ``|X_t|`` is fixed. The set
    is found with :func:`numpy.argpartition` in linear time and always has exactly
    ``n_candidates`` elements: voxels tied with the n-th largest value beyond that count are
    left out.

    Parameters
    ----------
    difference : array, any shape (2D image or 3D volume)
    n_candidates : int
        Size of the set, 1 <= n_candidates <= difference.size.

    Returns
    -------
    indices : int array, shape (n_candidates, difference.ndim)
        Array indices of the candidates (as :func:`numpy.argwhere`), in no particular order.
    threshold : float
        T_t, the smallest difference in the set.
    """
    diff = np.asarray(difference, dtype=float)
    if diff.ndim == 0 or diff.size == 0:
        raise ValueError(f"difference must be a non-empty array, got shape {diff.shape}")
    if not np.all(np.isfinite(diff)):
        raise ValueError("difference contains NaN or infinite values")
    if isinstance(n_candidates, bool) or int(n_candidates) != n_candidates:
        raise ValueError(f"n_candidates must be an integer, got {n_candidates!r}")
    n = int(n_candidates)
    if not 1 <= n <= diff.size:
        raise ValueError(f"n_candidates must be in [1, {diff.size}] (difference.size), got {n}")
    flat = diff.ravel()
    top = np.argpartition(flat, flat.size - n)[flat.size - n :]  # eq. (1): the n largest
    threshold = float(flat[top].min())  # T_t
    indices = np.stack(np.unravel_index(top, diff.shape), axis=1)
    return indices, threshold


@dataclass(frozen=True)
class InsertionParams:
    """Parameters of the insertion detection (Chatelain 2013, II-B).

    The paper tunes them empirically and reports no values; these defaults are ours, for
    volumes in mm of a few centimetres.

    Attributes
    ----------
    n_candidates : int
        Fixed size ``|X_t|`` of the candidate set (eq. (1)).
    variance_threshold_mm2 : float
        tau: the candidate spread (see :func:`detect_insertion`) must be below it. 100 mm^2 is
        an RMS distance of 10 mm to the centroid.
    distance_threshold_mm : float
        delta: the median must lie closer than this to a face of the volume.
    """

    n_candidates: int = 200
    variance_threshold_mm2: float = 100.0
    distance_threshold_mm: float = 10.0

    def __post_init__(self):
        n = self.n_candidates
        if isinstance(n, bool) or int(n) != n or n < 1:
            raise ValueError(f"n_candidates must be an integer >= 1, got {n!r}")
        for name in ("variance_threshold_mm2", "distance_threshold_mm"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")


@dataclass(frozen=True, eq=False)
class Detection:
    """Outcome of one insertion test; truthy when an entry point was detected.

    Positions are in mm (array indices times ``spacing``), in array axis order.

    Attributes
    ----------
    detected : bool
    entry_point_mm : array (D,) or None
        E_t, the median projected on the nearest face; None if the variance test failed.
    median_mm : array (D,) or None
        Geometric median of the candidates (eq. (2)); None if the variance test failed.
    variance_mm2 : float
        Spread of the candidates; NaN when not computed.
    threshold : float
        T_t of eq. (1); NaN when not computed.
    face : tuple (axis, side) or None
        Face of E_t: ``side`` 0 is index 0 along ``axis``, 1 the last index.
    reason : str or None
        Why nothing was detected; None when detected.
    """

    detected: bool
    entry_point_mm: np.ndarray | None = None
    median_mm: np.ndarray | None = None
    variance_mm2: float = np.nan
    threshold: float = np.nan
    face: tuple[int, int] | None = None
    reason: str | None = None

    def __bool__(self) -> bool:
        return self.detected


def _as_spacing(spacing, ndim: int) -> np.ndarray:
    sp = np.asarray(spacing, dtype=float)
    if sp.ndim > 1 or (sp.ndim == 1 and sp.shape != (ndim,)):
        raise ValueError(f"spacing must be a scalar or have shape ({ndim},), got {sp.shape}")
    sp = np.broadcast_to(sp, (ndim,))
    if not np.all(np.isfinite(sp) & (sp > 0)):
        raise ValueError(f"spacing must be finite and > 0, got {spacing!r}")
    return sp


def _as_frame(array, name: str) -> np.ndarray:
    arr = np.asarray(array, dtype=float)
    if arr.ndim not in (2, 3):
        raise ValueError(f"{name} must be a 2D image or a 3D volume, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def detect_insertion(difference, spacing, params: InsertionParams | None = None) -> Detection:
    """Detect a needle entering the field of view from a difference map (Chatelain 2013, II-B).

    Parameters
    ----------
    difference : array, 2D or 3D
        Change map, larger where more changed: ``|I_t - I_(t-1)|``, or e.g. the increase of
        a needle likelihood map. Candidates are its ``n_candidates`` largest values.
    spacing : float or array (difference.ndim,)
        Voxel size in mm per axis; voxel ``i`` lies at ``i * spacing``.
    params : InsertionParams, optional

    Returns
    -------
    Detection
        The variance is the trace of the covariance of the candidate positions,
        ``mean_i ||x_i - mean(x)||^2`` in mm^2 (sum of the per-axis variances, normalised by
        N; invariant to rotations). The volume faces are the planes through the first and
        last voxel centres of each axis.
    """
    params = InsertionParams() if params is None else params
    diff = _as_frame(difference, "difference")
    sp = _as_spacing(spacing, diff.ndim)
    if params.n_candidates > diff.size:
        raise ValueError(
            f"params.n_candidates ({params.n_candidates}) exceeds the number of voxels "
            f"({diff.size})"
        )

    indices, threshold = candidate_set(diff, params.n_candidates)  # eq. (1)
    if not threshold > 0:
        return Detection(False, threshold=threshold, reason="no change: threshold T_t is not > 0")
    positions = indices * sp  # mm
    centred = positions - positions.mean(axis=0)
    variance = float(np.einsum("nd,nd->", centred, centred) / len(positions))  # trace of cov
    if variance >= params.variance_threshold_mm2:
        return Detection(
            False,
            variance_mm2=variance,
            threshold=threshold,
            reason=(
                f"change not localised: candidate variance {variance:.3g} mm^2 >= "
                f"tau = {params.variance_threshold_mm2:.3g} mm^2"
            ),
        )

    median = geometric_median(positions)  # eq. (2), Weiszfeld
    upper = (np.array(diff.shape) - 1) * sp
    to_faces = np.stack([median, upper - median])  # (2, D): distance to the low / high faces
    side, axis = np.unravel_index(np.argmin(to_faces), to_faces.shape)
    entry = median.copy()
    entry[axis] = 0.0 if side == 0 else upper[axis]  # E_t on the nearest face
    distance = float(np.linalg.norm(entry - median))
    detected = distance < params.distance_threshold_mm
    reason = None
    if not detected:
        reason = (
            f"median too far from the volume boundary: ||E_t - Med|| = {distance:.3g} mm >= "
            f"delta = {params.distance_threshold_mm:.3g} mm"
        )
    return Detection(
        bool(detected), entry, median, variance, threshold, (int(axis), int(side)), reason
    )


class InsertionDetector:
    """Stateful insertion detector: keeps the previous frame (Chatelain 2013, II-B).

    Call :meth:`update` with each new image or volume, or :meth:`update_difference` with a
    precomputed change map (e.g. a difference of likelihood maps).
    """

    def __init__(self, params: InsertionParams | None = None):
        self.params = InsertionParams() if params is None else params
        self._previous: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the previous frame."""
        self._previous = None

    def update(self, frame, spacing) -> Detection:
        """Test the difference between ``frame`` and the previous one, then store ``frame``.

        The first frame after construction or :meth:`reset` only gets stored.
        """
        current = _as_frame(frame, "frame")
        previous = self._previous
        if previous is not None and previous.shape != current.shape:
            raise ValueError(
                f"frame has shape {current.shape}, the previous frame {previous.shape}; "
                "call reset() when the geometry changes"
            )
        self._previous = current.copy()
        if previous is None:
            return Detection(False, reason="first frame: no previous frame to compare with")
        return self.update_difference(np.abs(current - previous), spacing)  # Delta I_t

    def update_difference(self, difference, spacing) -> Detection:
        """Test a precomputed change map; the stored frame is left untouched."""
        return detect_insertion(difference, spacing, self.params)
