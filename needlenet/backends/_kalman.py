"""Linear Kalman filter and the linear models of three papers.

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
- Mathiassen 2017, section II-A3 and III-B: the scalar Kalman filter on the insertion angle
  (:class:`MathiassenAngleFilter`); section II-C, eqs. (11)-(19), Algorithm 4 and Table II: the
  1-D constant-velocity tip filter with Bayesian selection among the peaks of h(x)
  (:func:`tip_candidates`, :func:`candidate_posterior`, :class:`MathiassenTipFilter`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, NamedTuple

import numpy as np

__all__ = [
    "LinearModel",
    "KalmanFilter",
    "MathiassenAngleFilter",
    "MathiassenAngleParams",
    "MathiassenTipFilter",
    "MathiassenTipParams",
    "TipEstimate",
    "UpdateResult",
    "angles_to_direction",
    "candidate_posterior",
    "chatelain_control_points_model",
    "chi2_gate",
    "direction_to_angles",
    "mahalanobis",
    "predict",
    "tip_candidates",
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


# --------------------------------------------------------------------------- Mathiassen 2017


@dataclass(frozen=True)
class MathiassenAngleParams:
    """Mathiassen 2017, section III-B: the Kalman filter on the insertion angle theta.

    Random walk theta_k = theta_{k-1} + w; variances in degrees^2.
    """

    q_theta_deg2: float = 1.0  # Q_theta = 1
    r_theta_deg2: float = 4.0**2  # R_theta = 4^2
    p0_theta_deg2: float = 10.0**2  # P(0) = 10^2

    def __post_init__(self) -> None:
        for name in ("q_theta_deg2", "r_theta_deg2", "p0_theta_deg2"):
            _positive(name, getattr(self, name))


class MathiassenAngleFilter:
    """Scalar random-walk Kalman filter smoothing the estimated insertion angle (section II-A3,
    Algorithm 4 line 16). ``theta0_deg=None`` starts the filter at the first measurement."""

    def __init__(self, params: MathiassenAngleParams | None = None,
                 theta0_deg: float | None = None):
        self.params = params = MathiassenAngleParams() if params is None else params
        _positive("q_theta_deg2", params.q_theta_deg2)
        _positive("r_theta_deg2", params.r_theta_deg2)
        _positive("p0_theta_deg2", params.p0_theta_deg2)
        self._kf: KalmanFilter | None = None
        if theta0_deg is not None:
            self._start(float(theta0_deg))

    def _start(self, theta_deg: float) -> None:
        p = self.params
        self._kf = KalmanFilter([theta_deg], [[p.p0_theta_deg2]], [[1.0]], [[1.0]],
                                [[p.q_theta_deg2]], [[p.r_theta_deg2]])

    @property
    def theta_deg(self) -> float:
        return float("nan") if self._kf is None else float(self._kf.x[0])

    @property
    def variance_deg2(self) -> float:
        return float("nan") if self._kf is None else float(self._kf.P[0, 0])

    @property
    def gain(self) -> float:
        """Kalman gain of the last update."""
        return float("nan") if self._kf is None else float(self._kf.K[0, 0])

    def step(self, theta_measured_deg: float) -> float:
        """Predict and correct with one measured angle; returns the filtered angle (degrees)."""
        z = float(theta_measured_deg)
        if not np.isfinite(z):
            raise ValueError(f"theta_measured_deg must be finite, got {z}")
        if self._kf is None:
            self._start(z)
        self._kf.predict()
        self._kf.update([z])
        return self.theta_deg


@dataclass(frozen=True)
class MathiassenTipParams:
    """Mathiassen 2017, Table II (KF and KF_v columns) and section II-C; units as the paper: px
    along the needle axis, px/s, seconds.

    The process noise is Table II's Q = diag(dt^2/2 * 0.1^2, 0.1^2) (diagonal, as printed).
    ``dt_s`` defaults to the frame grabber's 20 frames/s (section III). ``candidate_radius_px``
    is M of eq. (12) (footnote 3). ``window_sigmas`` is ours, not the paper's: candidates farther
    than ``window_sigmas * sigma`` from the prediction are not eligible; when none is, the
    filter only predicts and sigma grows by ``sigma_step_px`` (up to ``sigma_max_px``), where
    the paper only describes the decrease from sigma_MAX to sigma_MIN.
    ``evidence`` selects P(x_bar) in eq. (13): ``"paper"`` is eq. (15) as printed,
    N(x_bar; 0, sigma), which depends on where the axis coordinate starts and lets
    P(j|x_bar) exceed 1 (R_k below R_MIN); ``"marginal"`` is the exact Bayes normaliser
    sum_i P(x_bar|j_i) P(j_i), so P(j|x_bar) <= 1 and R_k >= R_MIN as the text says.
    """

    dt_s: float = 1.0 / 20.0
    sigma_max_px: float = 300.0  # sigma_MAX
    sigma_min_px: float = 200.0  # sigma_MIN
    sigma_step_px: float = 5.0  # Delta sigma
    p0_position_px2: float = 20.0**2  # P_0 = diag(20^2, 5^2)
    p0_velocity_px2_s2: float = 5.0**2
    q_std_px: float = 0.1  # Q = diag(dt^2/2 * 0.1^2, 0.1^2)
    r_min_px2: float = 30.0**2  # R_MIN
    r_velocity_px2_s2: float = 1.0**2  # R_v, KF_v column and eq. (19)
    candidate_radius_px: int = 10  # M in eq. (12)
    window_sigmas: float = 3.0  # ours: eligibility window |j - x_bar| <= window_sigmas * sigma
    evidence: Literal["paper", "marginal"] = "paper"


@dataclass(frozen=True)
class TipEstimate:
    """One step of :class:`MathiassenTipFilter`.

    ``position_px``, ``velocity_px_s``, ``P``: posterior. ``accepted``: a candidate was used.
    ``measurement_px`` z_k (eq. (17)), ``posterior`` P(j|x_bar) of that candidate (eq. (13)),
    ``measurement_variance_px2`` R_k (eq. (18)) and ``candidate_index`` are None when not
    accepted, and ``reason`` says why ("no candidates" or "no candidate in the window"; None
    when accepted). ``predicted_px`` is x_bar; ``sigma_px`` the sigma used at this step.
    """

    position_px: float
    velocity_px_s: float
    P: np.ndarray
    predicted_px: float
    sigma_px: float
    accepted: bool
    measurement_px: float | None
    measurement_variance_px2: float | None
    posterior: float | None
    candidate_index: int | None
    reason: str | None = None


def tip_candidates(h, radius_px: int = 10) -> np.ndarray:
    """Mathiassen 2017, eq. (12): indices x with h(x) >= h(x + i) for all i in [-M, M] inside h.

    ``h`` is sampled along the needle axis; plateaus give every sample of the plateau, as the
    inequality does.
    """
    h = _vector("h", h)
    M = int(radius_px)
    if M < 0:
        raise ValueError(f"radius_px must be >= 0, got {radius_px}")
    padded = np.pad(h, M, constant_values=-np.inf)
    local_max = np.lib.stride_tricks.sliding_window_view(padded, 2 * M + 1).max(axis=1)
    return np.flatnonzero(h >= local_max)  # eq. (12)


def _log_candidate_posterior(candidates: np.ndarray, scores: np.ndarray, predicted: float,
                             sigma: float, evidence: str) -> np.ndarray:
    """log P(j_i | x_bar), eqs. (13)-(16), in log space so that the paper's eq. (15) cannot
    overflow. The 1/(sigma sqrt(2 pi)) factors of eqs. (14) and (15) cancel."""
    with np.errstate(divide="ignore"):
        log_prior = np.log(scores / scores.sum())  # P(j_i), eq. (16)
    log_lik = -0.5 * ((candidates - predicted) / sigma) ** 2  # P(x_bar | j_i), eq. (14)
    joint = log_lik + log_prior
    if evidence == "paper":
        log_evidence = -0.5 * (predicted / sigma) ** 2  # P(x_bar), eq. (15) as printed
    elif evidence == "marginal":
        top = np.max(joint)
        log_evidence = top + np.log(np.sum(np.exp(joint - top)))  # sum_i P(x_bar|j_i) P(j_i)
    else:
        raise ValueError(f"evidence must be 'paper' or 'marginal', got {evidence!r}")
    return joint - log_evidence  # Bayes' rule, eq. (13)


def _check_candidates(candidates_px, candidate_scores) -> tuple[np.ndarray, np.ndarray]:
    c = _vector("candidates_px", np.atleast_1d(np.asarray(candidates_px, dtype=float)))
    s = _vector("candidate_scores", np.atleast_1d(np.asarray(candidate_scores, dtype=float)),
                c.shape[0])
    if c.size:
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(s))):
            raise ValueError("candidates_px and candidate_scores must be finite")
        if np.any(s < 0.0) or s.sum() <= 0.0:
            raise ValueError("candidate_scores must be >= 0 with a positive sum: they are the "
                             "prior P(j_i) of eq. (16); shift h (e.g. h - min h) first")
    return c, s


def candidate_posterior(candidates_px, candidate_scores, predicted_px: float, sigma_px: float,
                        evidence: Literal["paper", "marginal"] = "paper") -> np.ndarray:
    """P(j_i | x_bar) of Mathiassen 2017, eqs. (13)-(16), for every candidate.

    P(j_i | x_bar) = P(x_bar | j_i) P(j_i) / P(x_bar), with P(x_bar | j_i) = N(j_i; x_bar,
    sigma) (eq. (14)), the prior P(j_i) = h(j_i) / sum_J h (eq. (16)), so the scores must be
    non-negative, and P(x_bar) = N(x_bar; 0, sigma) (eq. (15), ``evidence="paper"``) or the
    marginal sum_i P(x_bar | j_i) P(j_i) (``evidence="marginal"``).
    """
    c, s = _check_candidates(candidates_px, candidate_scores)
    sigma = _positive("sigma_px", sigma_px)
    if c.size == 0:
        return np.zeros(0)
    return np.exp(_log_candidate_posterior(c, s, float(predicted_px), sigma, evidence))


class MathiassenTipFilter:
    """Mathiassen 2017, section II-C and Algorithm 4: 1-D tip filter along the needle axis.

    State x = [position (px), velocity (px/s)] with F = [[1, T_s], [0, 1]] (eq. (11)). Each
    :meth:`step` predicts (Algorithm 4 line 5), scores the candidate peaks of h(x) (from
    :func:`tip_candidates`, eq. (12)) by P(j_i | x_bar) (eqs. (13)-(16), see
    :func:`candidate_posterior`), takes the most probable one as z_k (eq. (17)) with variance
    R_k = R_MIN / P(j_i | x_bar) of that candidate (eq. (18)), and corrects with z_k alone or,
    when the robot's velocity is given, with y_k = [z_k, velocity] and R = diag(R_k, R_v)
    (eq. (19)). sigma of eq. (14) starts at sigma_MAX and drops by Delta sigma at each step
    with a measurement down to sigma_MIN; see :class:`MathiassenTipParams` for the window
    (ours) that rejects far candidates and widens sigma again.

    How P in R_k = R_MIN / P comes from the scores h(j_i), the 1/(sigma sqrt(2 pi)) factors of
    eqs. (14)-(15) cancelling:

    - ``evidence="paper"`` (default, eq. (15) as printed):
      P = h(j) / sum_J h * exp(-((j - x_bar)^2 - x_bar^2) / (2 sigma^2)).
      x_bar is measured from the origin of the caller's axis coordinate (h's first sample),
      so the factor exp(x_bar^2 / (2 sigma^2)) grows along the axis: P can exceed 1 and R_k
      fall below R_MIN (by 14x at x_bar = 460 px, sigma = 200 px).
    - ``evidence="marginal"``: P = h(j) exp(-(j - x_bar)^2 / (2 sigma^2)) /
      sum_J h(j_i) exp(-(j_i - x_bar)^2 / (2 sigma^2)), a proper posterior in (0, 1].

    ``x0_px`` is where the tip is expected to appear (the paper's initialisation).
    """

    def __init__(self, x0_px: float, v0_px_s: float = 0.0,
                 params: MathiassenTipParams | None = None):
        p = MathiassenTipParams() if params is None else params
        dt = _positive("dt_s", p.dt_s)
        for name in ("sigma_max_px", "sigma_min_px", "p0_position_px2", "p0_velocity_px2_s2",
                     "q_std_px", "r_min_px2", "r_velocity_px2_s2", "window_sigmas"):
            _positive(name, getattr(p, name))
        if p.sigma_min_px > p.sigma_max_px:
            raise ValueError("sigma_min_px must be <= sigma_max_px")
        if p.sigma_step_px < 0.0:
            raise ValueError(f"sigma_step_px must be >= 0, got {p.sigma_step_px}")
        if p.evidence not in ("paper", "marginal"):
            raise ValueError(f"evidence must be 'paper' or 'marginal', got {p.evidence!r}")
        self.params = p
        F = np.array([[1.0, dt], [0.0, 1.0]])  # eq. (11)
        Q = np.diag([dt**2 / 2.0 * p.q_std_px**2, p.q_std_px**2])  # Table II
        P0 = np.diag([p.p0_position_px2, p.p0_velocity_px2_s2])  # Table II
        self.kf = KalmanFilter([float(x0_px), float(v0_px_s)], P0, F, [[1.0, 0.0]], Q,
                               [[p.r_min_px2]])
        self.sigma_px = float(p.sigma_max_px)  # "It begins with sigma_MAX"

    @property
    def x(self) -> np.ndarray:
        return self.kf.x

    @property
    def P(self) -> np.ndarray:
        return self.kf.P

    def step(self, candidates_px, candidate_scores, velocity_measurement: float | None = None
             ) -> TipEstimate:
        """One frame. ``candidates_px``: positions j_i along the axis (px); ``candidate_scores``:
        their h(j_i) (>= 0); ``velocity_measurement``: the robot's insertion velocity along the
        axis in px/s, or None. An empty candidate list is allowed (no image measurement); when
        no candidate is accepted but a velocity is given, the filter corrects with the velocity
        row of eq. (19) alone."""
        p = self.params
        c, s = _check_candidates(candidates_px, candidate_scores)
        if velocity_measurement is not None and not np.isfinite(velocity_measurement):
            raise ValueError("velocity_measurement must be finite or None")
        self.kf.predict()  # Algorithm 4 line 5
        x_bar = float(self.kf.x[0])
        sigma = self.sigma_px
        best = None
        if c.size:
            log_post = _log_candidate_posterior(c, s, x_bar, sigma, p.evidence)
            eligible = (np.abs(c - x_bar) <= p.window_sigmas * sigma) & np.isfinite(log_post)
            if np.any(eligible):
                best = int(np.argmax(np.where(eligible, log_post, -np.inf)))  # eq. (17)
        if best is not None:
            z = float(c[best])
            posterior = float(np.exp(log_post[best]))
            R_k = p.r_min_px2 * float(np.exp(-log_post[best]))  # R_k = R_MIN / P(j|x_bar), (18)
            if velocity_measurement is None:
                self.kf.update([z], R=[[R_k]], H=[[1.0, 0.0]])  # Algorithm 4 line 13
            else:
                self.kf.update([z, float(velocity_measurement)],  # eq. (19)
                               R=np.diag([R_k, p.r_velocity_px2_s2]), H=np.eye(2))
            self.sigma_px = max(sigma - p.sigma_step_px, p.sigma_min_px)
            reason = None
        else:
            if velocity_measurement is not None:  # the velocity row of eq. (19) alone
                self.kf.update([float(velocity_measurement)], R=[[p.r_velocity_px2_s2]],
                               H=[[0.0, 1.0]])
            self.sigma_px = min(sigma + p.sigma_step_px, p.sigma_max_px)
            z = posterior = R_k = None
            reason = "no candidates" if c.size == 0 else "no candidate in the window"
        return TipEstimate(
            position_px=float(self.kf.x[0]),
            velocity_px_s=float(self.kf.x[1]),
            P=self.kf.P.copy(),
            predicted_px=x_bar,
            sigma_px=sigma,
            accepted=best is not None,
            measurement_px=z,
            measurement_variance_px2=R_k,
            posterior=posterior,
            candidate_index=best,
            reason=reason,
        )
