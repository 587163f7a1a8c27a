"""Linear Kalman filter and the linear models of two papers (Mathiassen 2017's filters, built on
it, are in ``_mathiassen_kf``).

The filter is written as FilterPy writes it (``filterpy/kalman/kalman_filter.py``): pure
functions ``predict(x, P, F, Q)`` and ``update(x, P, z, R, H)`` with the textbook letters, plus
a thin stateful :class:`KalmanFilter` that keeps the last innovation ``y``, its covariance ``S``
and the Mahalanobis distance for gating. Vectors are 1-D arrays ``(n,)`` (FilterPy uses
columns ``(n, 1)``); matrices are 2-D.

Models:

- Chatelain 2013, section II-C, eqs. (3)-(14): constant velocity on the n control points of the
  needle curve (:func:`chatelain_control_points_model`).
- Zhao 2013, "Mathematical model for Kalman filter", eqs. (2)-(4), and Appendix C,
  eqs. (C1)-(C7): angles beta, alpha, the tip and their rates (:func:`zhao_model`,
  :func:`direction_to_angles`, :func:`angles_to_direction`).
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

__all__ = [
    "LinearModel",
    "KalmanFilter",
    "UpdateResult",
    "angles_to_direction",
    "chatelain_control_points_model",
    "chi2_gate",
    "direction_to_angles",
    "mahalanobis",
    "predict",
    "update",
    "zhao_model",
]

_LOG_2PI = float(np.log(2.0 * np.pi))


# --------------------------------------------------------------------------- validation


def _vector(name: str, a, n: int | None = None) -> np.ndarray:
    v = np.asarray(a, dtype=float)
    if v.ndim != 1 or (n is not None and v.shape[0] != n):
        want = f"({n},)" if n is not None else "1-D"
        raise ValueError(f"{name} must have shape {want}, got {v.shape}")
    return v


def _matrix(name: str, a, rows: int, cols: int) -> np.ndarray:
    m = np.asarray(a, dtype=float)
    if m.shape != (rows, cols):
        raise ValueError(f"{name} must have shape ({rows}, {cols}), got {m.shape}")
    return m


def _noise(name: str, a, n: int) -> np.ndarray:
    """A covariance given as an (n, n) matrix, or as a scalar meaning ``a * I``."""
    m = np.asarray(a, dtype=float)
    if m.ndim == 0:
        return float(m) * np.eye(n)
    return _matrix(name, m, n, n)


def _observation(name: str, a, n: int) -> np.ndarray:
    """An (m, n) observation matrix, m free."""
    m = np.asarray(a, dtype=float)
    if m.ndim != 2 or m.shape[1] != n:
        raise ValueError(f"{name} must have shape (dim_z, {n}), got {m.shape}")
    return m


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0.0:
        raise ValueError(f"{name} must be positive and finite, got {value}")
    return value


# --------------------------------------------------------------------------- the filter


class UpdateResult(NamedTuple):
    """What one measurement update returns (FilterPy keeps the same quantities on its class).

    ``x``, ``P``: posterior state and covariance; ``y = z - H x^-``: innovation; ``S``: its
    covariance; ``K``: gain; ``mahalanobis``: sqrt(y^T S^-1 y), in standard deviations;
    ``log_likelihood``: log N(y; 0, S).
    """

    x: np.ndarray
    P: np.ndarray
    y: np.ndarray
    S: np.ndarray
    K: np.ndarray
    mahalanobis: float
    log_likelihood: float


def _innovation_stats(y: np.ndarray, S: np.ndarray) -> tuple[float, float]:
    """Mahalanobis distance and log N(y; 0, S), from one Cholesky factor S = L L^T."""
    L = np.linalg.cholesky(S)  # raises LinAlgError when S is not positive definite
    w = np.linalg.solve(L, y)  # L^-1 y, so y^T S^-1 y = |w|^2
    d2 = float(w @ w)
    log_det_S = 2.0 * float(np.sum(np.log(np.diag(L))))
    return float(np.sqrt(d2)), -0.5 * (d2 + log_det_S + y.shape[0] * _LOG_2PI)


def mahalanobis(y, S) -> float:
    """Mahalanobis distance sqrt(y^T S^-1 y) of an innovation ``y`` with covariance ``S``."""
    y = _vector("y", y)
    S = _matrix("S", S, y.shape[0], y.shape[0])
    return _innovation_stats(y, S)[0]


@lru_cache(maxsize=64)  # a tracker asks for the same gate every frame; chi2.ppf takes 0.1 ms
def chi2_gate(dim_z: int, probability: float = 0.997) -> float:
    """Mahalanobis-distance threshold of the chi-square gate.

    A measurement passes when d^2 = y^T S^-1 y <= chi2.ppf(probability, dim_z), that is when
    the distance d is at most the returned value (3.0 for ``dim_z=1`` near p = 0.9973).
    """
    from scipy.stats import chi2  # scipy.stats is slow to import; load it on first use

    if int(dim_z) < 1:
        raise ValueError(f"dim_z must be >= 1, got {dim_z}")
    if not 0.0 < probability < 1.0:
        raise ValueError(f"probability must be in (0, 1), got {probability}")
    return float(np.sqrt(chi2.ppf(probability, int(dim_z))))


def predict(x, P, F, Q, B=None, u=None) -> tuple[np.ndarray, np.ndarray]:
    """Time update. Returns the prior ``(x, P)``.

    x^- = F x + B u  (Zhao 2013, eq. (C3); Chatelain 2013, eq. (10) with B = 0)
    P^- = F P F^T + Q  (Zhao 2013, eq. (C4); Chatelain 2013, eq. (11))

    ``Q`` may be an (n, n) matrix or a scalar meaning ``Q * I``; ``B`` and ``u`` go together.
    """
    x = _vector("x", x)
    n = x.shape[0]
    P = _matrix("P", P, n, n)
    F = _matrix("F", F, n, n)
    Q = _noise("Q", Q, n)
    x_prior = F @ x  # eq. (C3)
    if B is not None or u is not None:
        if B is None or u is None:
            raise ValueError("B and u must be given together")
        u = np.atleast_1d(np.asarray(u, dtype=float))
        u = _vector("u", u)
        B = _matrix("B", B, n, u.shape[0])
        x_prior = x_prior + B @ u  # eq. (C3), control term
    P_prior = F @ P @ F.T + Q  # eq. (C4)
    return x_prior, P_prior


def _correct(x: np.ndarray, P: np.ndarray, y: np.ndarray, R: np.ndarray,
             H: np.ndarray) -> UpdateResult:
    """Measurement update from an innovation ``y``; shared with the EKF."""
    PHT = P @ H.T
    S = H @ PHT + R  # innovation covariance
    d, log_likelihood = _innovation_stats(y, S)
    # K = P H^T S^-1, eq. (C5) / Chatelain eq. (12); solved, not inverted: S K^T = H P^T.
    K = np.linalg.solve(S, PHT.T).T
    x_post = x + K @ y  # eq. (C6) / Chatelain eq. (13)
    # Joseph form P = (I - K H) P^- (I - K H)^T + K R K^T instead of the papers' (I - K H) P^-
    # (eq. (C7), Chatelain eq. (14)). The two are equal for the optimal gain, but the Joseph
    # form is a sum of two congruences, so P stays symmetric positive semi-definite for any
    # gain and under rounding; the short form loses symmetry and can go indefinite when R is
    # small next to P.
    I_KH = np.eye(x.shape[0]) - K @ H
    P_post = I_KH @ P @ I_KH.T + K @ R @ K.T
    return UpdateResult(x_post, P_post, y, S, K, d, log_likelihood)


def update(x, P, z, R, H) -> UpdateResult:
    """Measurement update with the Joseph-form covariance (see :class:`UpdateResult`).

    ``R`` may be an (m, m) matrix or a scalar meaning ``R * I``.
    """
    x = _vector("x", x)
    n = x.shape[0]
    P = _matrix("P", P, n, n)
    H = _observation("H", H, n)
    m = H.shape[0]
    z = _vector("z", np.atleast_1d(np.asarray(z, dtype=float)), m)
    R = _noise("R", R, m)
    return _correct(x, P, z - H @ x, R, H)  # innovation y = z - H x^-, eq. (C6)


class KalmanFilter:
    """Thin stateful wrapper around :func:`predict` and :func:`update`.

    After each update, ``y``, ``S``, ``K``, ``mahalanobis`` and ``log_likelihood`` hold the last
    values (NaN for the scalars before the first update), for gating and diagnostics.
    """

    def __init__(self, x, P, F, H, Q, R, B=None):
        self.x = _vector("x", x).copy()
        n = self.x.shape[0]
        self.P = _matrix("P", P, n, n).copy()
        self.F = _matrix("F", F, n, n).copy()
        self.H = _observation("H", H, n).copy()
        m = self.H.shape[0]
        self.Q = _noise("Q", Q, n).copy()
        self.R = _noise("R", R, m).copy()
        self.B = None if B is None else np.asarray(B, dtype=float).copy()
        self.y = np.zeros(m)
        self.S = np.zeros((m, m))
        self.K = np.zeros((n, m))
        self.mahalanobis = float("nan")
        self.log_likelihood = float("nan")

    @property
    def dim_x(self) -> int:
        return self.x.shape[0]

    @property
    def dim_z(self) -> int:
        return self.H.shape[0]

    def predict(self, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Advance to the prior; returns ``(x, P)``."""
        B = self.B if u is not None else None
        if u is not None and B is None:
            raise ValueError("u given but the filter has no control matrix B")
        self.x, self.P = predict(self.x, self.P, self.F, self.Q, B, u)
        return self.x, self.P

    def update(self, z, R=None, H=None) -> UpdateResult:
        """Correct with measurement ``z``; ``R`` and ``H`` override the filter's for this call."""
        res = update(self.x, self.P, z, self.R if R is None else R, self.H if H is None else H)
        self.x, self.P = res.x, res.P
        self.y, self.S, self.K = res.y, res.S, res.K
        self.mahalanobis, self.log_likelihood = res.mahalanobis, res.log_likelihood
        return res

    def innovation(self, z, R=None, H=None) -> tuple[np.ndarray, np.ndarray, float]:
        """``(y, S, d)`` that ``z`` would give against the current prior; the state is unchanged."""
        H = self.H if H is None else _observation("H", H, self.dim_x)
        z = _vector("z", np.atleast_1d(np.asarray(z, dtype=float)), H.shape[0])
        R = _noise("R", self.R if R is None else R, H.shape[0])
        y = z - H @ self.x
        S = H @ self.P @ H.T + R
        return y, S, mahalanobis(y, S)

    def gate(self, z, threshold: float, R=None, H=None) -> bool:
        """Chi-square gate: True when the Mahalanobis distance of ``z`` is <= ``threshold``.

        ``threshold`` is a distance in standard deviations; :func:`chi2_gate` gives the one
        for a probability (d^2 follows chi-square with dim_z degrees of freedom).
        """
        return self.innovation(z, R, H)[2] <= float(threshold)


# --------------------------------------------------------------------------- linear models


class LinearModel(NamedTuple):
    """x_k = F x_{k-1} + w, w ~ N(0, Q); z_k = H x_k + v, v ~ N(0, R)."""

    F: np.ndarray
    H: np.ndarray
    Q: np.ndarray
    R: np.ndarray


def _white_acceleration_block(dt: float) -> np.ndarray:
    """Discretised continuous white-noise acceleration for one (position, velocity) pair, per
    unit spectral density (Bar-Shalom, Li & Kirubarajan 2001, section 6.2.2)."""
    return np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])


def chatelain_control_points_model(n_points: int, dim: int = 3, *, dt: float, q: float,
                                   r: float) -> LinearModel:
    """Constant-velocity model on the n control points of the needle curve.

    State (Chatelain 2013, eq. (3)): X = (p_1, ..., p_n, p'_1, ..., p'_n), each point ``dim``
    coordinates, so dim_x = 2 n dim and the measurement (the fitted control points) has
    dim_z = n dim.

    The paper does not give Q or R. Q is the continuous white-noise-acceleration model ("small
    accelerations being modeled by the state noise"), ``q`` its spectral density in
    length^2 / time^3 on every coordinate; R = r I, ``r`` a variance in length^2.
    """
    n_points, dim = int(n_points), int(dim)
    if n_points < 1:
        raise ValueError(f"n_points must be >= 1, got {n_points}")
    if dim < 1:
        raise ValueError(f"dim must be >= 1, got {dim}")
    dt, q, r = _positive("dt", dt), _positive("q", q), _positive("r", r)
    m = n_points * dim
    I = np.eye(m)
    F = np.block([[I, dt * I], [np.zeros((m, m)), I]])  # A, eq. (8)
    H = np.hstack([I, np.zeros((m, m))])  # C = [I_3n 0], eq. (9)
    Q = np.kron(_white_acceleration_block(dt), q * I)  # u_t ~ N(0, Q), eq. (6)
    R = r * I  # v_t ~ N(0, R), eq. (7)
    return LinearModel(F, H, Q, R)


def zhao_model(dt: float, *, q_angle: float = 1e-3, q_tip: float = 1.0,
               r_angle: float = np.deg2rad(1.0) ** 2, r_position: float = 0.25,
               r_velocity: float = 1.0) -> LinearModel:
    """Zhao 2013's model: S = [beta, alpha, v_beta, v_alpha, p_t (3), v_t (3)], 10 states.

    F follows eq. (2)-(3). The printed F is not 10 x 10: its third block row reads
    [0_3x4, I_3, dt I_3] (10 columns) and its last [0_2x4, 0_2x2, I_2] (8 columns, 2 rows),
    so the rows add up to 9. The authors meant constant velocity on both groups:

        F = [[I_2, dt I_2, 0_2x6],
             [0_2, I_2,    0_2x6],
             [0_3x4,  I_3, dt I_3],
             [0_3x4,  0_3, I_3  ]]

    which is what is built. H = [[I_2, 0_2x8], [0_6x4, I_6]] maps S to the measurement
    Z = [beta, alpha, p, v] (RANSAC gives the angles and tip, speckle tracking the velocity).

    The paper gives neither Q nor R ("estimated by a large number of repeat trials"); the
    defaults here are ours: continuous white-noise acceleration with spectral densities
    ``q_angle`` (rad^2/s^3) on the angles and ``q_tip`` (mm^2/s^3) on the tip, and measurement
    variances ``r_angle`` (rad^2), ``r_position`` (mm^2), ``r_velocity`` (mm^2/s^2).
    """
    dt = _positive("dt", dt)
    q_angle, q_tip = _positive("q_angle", q_angle), _positive("q_tip", q_tip)
    r_angle, r_position = _positive("r_angle", r_angle), _positive("r_position", r_position)
    r_velocity = _positive("r_velocity", r_velocity)
    I2, I3 = np.eye(2), np.eye(3)
    F_angles = np.block([[I2, dt * I2], [np.zeros((2, 2)), I2]])  # eq. (2)-(3), angle block
    F_tip = np.block([[I3, dt * I3], [np.zeros((3, 3)), I3]])  # eq. (2)-(3), tip block
    F = np.zeros((10, 10))
    F[:4, :4] = F_angles
    F[4:, 4:] = F_tip
    H = np.zeros((8, 10))  # H = [[I_2, 0_2x8], [0_6x4, I_6]]
    H[:2, :2] = I2
    H[2:, 4:] = np.eye(6)
    Q = np.zeros((10, 10))
    Q[:4, :4] = np.kron(_white_acceleration_block(dt), q_angle * I2)
    Q[4:, 4:] = np.kron(_white_acceleration_block(dt), q_tip * I3)
    R = np.diag([r_angle] * 2 + [r_position] * 3 + [r_velocity] * 3)
    return LinearModel(F, H, Q, R)


def direction_to_angles(u) -> tuple[np.ndarray, np.ndarray]:
    """Zhao 2013, eq. (4): ``(beta, alpha)`` in radians of direction(s) ``u`` of shape (..., 3).

    beta = arccos(u_z / |u|) (angle to +z); alpha = arctan(u_y / u_x). We use arctan2, which
    equals eq. (4) for u_x > 0 and keeps the quadrant otherwise, so that
    :func:`angles_to_direction` inverts it exactly. (The text calls alpha "the angle between
    the needle and the plane xoz"; eq. (4) is the azimuth in the xoy plane, which we follow.)
    """
    u = np.asarray(u, dtype=float)
    if u.ndim < 1 or u.shape[-1] != 3:
        raise ValueError(f"u must have shape (..., 3), got {u.shape}")
    norm = np.linalg.norm(u, axis=-1)
    if np.any(norm == 0.0):
        raise ValueError("u must be non-zero")
    beta = np.arccos(np.clip(u[..., 2] / norm, -1.0, 1.0))  # eq. (4)
    alpha = np.arctan2(u[..., 1], u[..., 0])  # eq. (4), quadrant-aware
    return beta, alpha


def angles_to_direction(beta, alpha) -> np.ndarray:
    """Inverse of eq. (4): unit vector(s) (..., 3) from ``beta`` (to +z) and ``alpha`` (azimuth)."""
    beta, alpha = np.broadcast_arrays(np.asarray(beta, float), np.asarray(alpha, float))
    s = np.sin(beta)
    return np.stack([s * np.cos(alpha), s * np.sin(alpha), np.cos(beta)], axis=-1)
