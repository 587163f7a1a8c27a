"""Mathiassen 2017's Kalman filters, on the generic filter of ``_kalman``.

- Section II-A3 and III-B: the scalar Kalman filter on the insertion angle
  (:class:`MathiassenAngleFilter`).
- Section II-C, eqs. (11)-(19), Algorithm 4 and Table II: the 1-D constant-velocity tip filter
  with Bayesian selection among the peaks of h(x) (:func:`tip_candidates`,
  :func:`candidate_posterior`, :class:`MathiassenTipFilter`).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ._kalman import KalmanFilter, _positive, _vector

__all__ = [
    "MathiassenAngleFilter",
    "MathiassenAngleParams",
    "MathiassenTipFilter",
    "MathiassenTipParams",
    "TipEstimate",
    "candidate_posterior",
    "tip_candidates",
]


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

    def copy(self) -> MathiassenAngleFilter:
        """An independent copy: the filter's steps replace its state arrays, never change them
        in place, so the arrays may be shared (deepcopy took 0.1 ms a frame)."""
        out = copy.copy(self)
        out._kf = copy.copy(self._kf)
        return out

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
