"""Extended Kalman filter, and Ye 2025's needle-tip models.

:class:`ExtendedKalmanFilter` takes its model as callables, f(x, u) with its Jacobian F(x, u)
and h(x) with its Jacobian H(x), and shares the linear filter's measurement update
(Joseph-form covariance, innovation, Mahalanobis distance; ``_kalman._correct``). It adds the
two safeguards of Ye 2025's discussion (section 5): measurements whose innovation exceeds a
preset multiple of its standard deviation are discarded (gating), and the measurement noise
covariance is adjusted online from the innovation sequence (:class:`AdaptiveNoise`).

Ye 2025, section 2.4: :func:`ye_pv_model` (position-velocity state, eqs. (6)-(10)) and
:func:`ye_prv_model` (position-relative-velocity state, eqs. (11)-(12)); Q and R of section 4,
eqs. (20)-(23), in :class:`YeEKFParams`. The input u is the feed speed v_in (mm/s) of the
insertion device.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ._kalman import _correct, _innovation_stats, _matrix, _positive, _vector

__all__ = [
    "AdaptiveNoise",
    "EKFModel",
    "EKFUpdate",
    "ExtendedKalmanFilter",
    "YeEKFParams",
    "YeModel",
    "ye_prv_model",
    "ye_pv_model",
]


class EKFUpdate(NamedTuple):
    """One EKF measurement update: the fields of ``_kalman.UpdateResult`` plus ``accepted``.

    When the gate rejects the measurement, ``x`` and ``P`` are the prior, ``K`` is zero, and
    ``y``, ``S``, ``mahalanobis``, ``log_likelihood`` describe the rejected measurement.
    """

    x: np.ndarray
    P: np.ndarray
    y: np.ndarray
    S: np.ndarray
    K: np.ndarray
    mahalanobis: float
    log_likelihood: float
    accepted: bool


@dataclass(frozen=True, eq=False)
class EKFModel:
    """x_k = f(x_{k-1}, u) + w, w ~ N(0, Q); z_k = h(x_k) + v, v ~ N(0, R).

    ``F(x, u)`` and ``H(x)`` are the Jacobians of ``f`` and ``h`` with respect to x.
    """

    f: Callable[[np.ndarray, object], np.ndarray]
    F: Callable[[np.ndarray, object], np.ndarray]
    h: Callable[[np.ndarray], np.ndarray]
    H: Callable[[np.ndarray], np.ndarray]
    Q: np.ndarray
    R: np.ndarray


@dataclass(frozen=True)
class AdaptiveNoise:
    """Innovation-based adaptive estimation of R (Mehra 1970; Mohamed & Schwarz 1999).

    Ye 2025 (section 5) says only that "the noise covariance ... is adjusted online by
    monitoring the innovation sequence", without saying which covariance or how; we adapt the
    measurement noise R, whose level is what changes with speckle and probe contact.

    Over the last ``window`` accepted updates, E[y y^T] = H P^- H^T + R, so

        R_hat = C_y - mean(H P^- H^T),   C_y = mean(y y^T)

    (a windowed estimate: it follows a change of noise within ``window`` frames and forgets
    older frames, where Sage-Husa's fading estimate never quite does). R_hat is symmetrised and
    its eigenvalues are clipped at ``floor_fraction`` times the smallest eigenvalue of the
    initial R, so it stays positive definite. The filter uses R_hat from the next update on,
    once the window is full. Gated-out innovations are not used, so a jump in noise far beyond
    the gate is not learned; gate generously when adapting.
    """

    window: int = 50
    floor_fraction: float = 1e-3

    def __post_init__(self):
        if int(self.window) < 2:
            raise ValueError(f"window must be >= 2, got {self.window}")
        _positive("floor_fraction", self.floor_fraction)


def _square(name: str, a) -> np.ndarray:
    m = np.array(a, dtype=float)
    if m.ndim != 2 or m.shape[0] != m.shape[1] or m.shape[0] == 0:
        raise ValueError(f"{name} must be a square matrix, got shape {m.shape}")
    return m


class ExtendedKalmanFilter:
    """Extended Kalman filter with optional innovation gating and adaptive R.

    ``gate_sigmas``: discard a measurement whose Mahalanobis distance sqrt(y^T S^-1 y) exceeds
    it (Ye 2025, section 5: "innovations ... are discarded if they exceed a preset innovation
    covariance multiple"); ``_kalman.chi2_gate`` gives it for a probability. None: no gate.
    ``adaptive``: an :class:`AdaptiveNoise` to adapt R online, or None to keep R fixed.
    """

    def __init__(self, f, F, h, H, Q, R, x0, P0, *, gate_sigmas: float | None = None,
                 adaptive: AdaptiveNoise | None = None):
        self.f, self.F, self.h, self.H = f, F, h, H
        self.Q = _square("Q", Q)
        n = self.Q.shape[0]
        self.R = _square("R", R)
        m = self.R.shape[0]
        self.x = _vector("x0", x0, n).copy()
        self.P = _matrix("P0", P0, n, n).copy()
        if gate_sigmas is not None:
            gate_sigmas = _positive("gate_sigmas", gate_sigmas)
        self.gate_sigmas = gate_sigmas
        self.adaptive = adaptive
        if adaptive is not None:
            w = int(adaptive.window)
            self._yy = np.zeros((w, m, m))
            self._hph = np.zeros((w, m, m))
            self._r_floor = adaptive.floor_fraction * float(np.linalg.eigvalsh(self.R).min())
        self._n_accepted = 0
        self.n_rejected = 0
        self.y = np.zeros(m)
        self.S = np.zeros((m, m))
        self.K = np.zeros((n, m))
        self.mahalanobis = float("nan")
        self.log_likelihood = float("nan")
        self.accepted = False

    @classmethod
    def from_model(cls, model: EKFModel, x0, P0, **kwargs) -> ExtendedKalmanFilter:
        """Build from an :class:`EKFModel` (for example :func:`ye_pv_model`)."""
        return cls(model.f, model.F, model.h, model.H, model.Q, model.R, x0, P0, **kwargs)

    @property
    def dim_x(self) -> int:
        return self.x.shape[0]

    @property
    def dim_z(self) -> int:
        return self.R.shape[0]

    def predict(self, u=None) -> tuple[np.ndarray, np.ndarray]:
        """x^- = f(x, u), P^- = F P F^T + Q, F at the posterior x; returns the prior."""
        n = self.dim_x
        F = _matrix("F", self.F(self.x, u), n, n)  # Jacobian at the current estimate
        x_prior = _vector("f", self.f(self.x, u), n)
        self.x = x_prior
        self.P = F @ self.P @ F.T + self.Q
        return self.x, self.P

    def update(self, z) -> EKFUpdate:
        """Correct with measurement ``z`` unless the gate rejects it."""
        m, n = self.dim_z, self.dim_x
        z = _vector("z", np.atleast_1d(np.asarray(z, dtype=float)), m)
        H = _matrix("H", self.H(self.x), m, n)  # Jacobian at the prior
        y = z - _vector("h", self.h(self.x), m)  # innovation
        HPH = H @ self.P @ H.T
        S = HPH + self.R
        d, ll = _innovation_stats(y, S)
        if self.gate_sigmas is not None and d > self.gate_sigmas:  # Ye 2025, section 5
            self.y, self.S, self.K = y, S, np.zeros((n, m))
            self.mahalanobis, self.log_likelihood, self.accepted = d, ll, False
            self.n_rejected += 1
            return EKFUpdate(self.x, self.P, y, S, self.K, d, ll, False)
        res = _correct(self.x, self.P, y, self.R, H)
        self.x, self.P = res.x, res.P
        self.y, self.S, self.K = res.y, res.S, res.K
        self.mahalanobis, self.log_likelihood, self.accepted = (
            res.mahalanobis, res.log_likelihood, True)
        if self.adaptive is not None:
            self._adapt(y, HPH)
        return EKFUpdate(*res, True)

    def _adapt(self, y: np.ndarray, HPH: np.ndarray) -> None:
        w = self._yy.shape[0]
        i = self._n_accepted % w
        self._yy[i] = np.outer(y, y)
        self._hph[i] = HPH
        self._n_accepted += 1
        if self._n_accepted < w:
            return
        R_hat = self._yy.mean(axis=0) - self._hph.mean(axis=0)  # C_y - H P^- H^T
        R_hat = 0.5 * (R_hat + R_hat.T)
        lam, V = np.linalg.eigh(R_hat)
        self.R = (V * np.maximum(lam, self._r_floor)) @ V.T  # keep R positive definite


# --------------------------------------------------------------------------- Ye 2025


@dataclass(frozen=True)
class YeEKFParams:
    """Ye 2025, section 4: sampling and the noise covariances of eqs. (20)-(23) (diagonals).

    Units: mm and mm/s for PV; for PRV the velocity entries are the dimensionless relative
    velocities v' = v / v_in. Q is per sample (period ``dt_s``, f_u = 25 Hz, section 4.1).
    The printed values are used as they stand. Note that R_yz = 100 mm^2 is far above the
    variance 4/3 mm^2 of the simulated noise (uniform on [-2, 2] mm, section 4.2): with
    Q ~ 1e-6 it sets a heavily smoothing Q/R ratio rather than the noise level, so a gate on
    these S is loose; use :class:`AdaptiveNoise` or your own R for a calibrated S.

    ``min_axial_fraction`` (ours) floors v_x at this fraction of v_in (v'_x at this value) so
    the square roots of eq. (3) stay real and the Jacobians (8), (12) bounded when the
    estimated lateral velocity exceeds v_in, as it can early on, when v_in is near 0. Where
    the floor is active v_x no longer depends on v_y, v_z and those Jacobian entries are 0.
    """

    dt_s: float = 1.0 / 25.0
    q_pv: tuple[float, ...] = (1e-6, 1e-6, 1e-6, 5e-6, 5e-6)  # eq. (20)
    r_pv: tuple[float, ...] = (0.5, 100.0, 100.0)  # eq. (21)
    q_prv: tuple[float, ...] = (5e-6, 1e-6, 1e-6, 5e-6, 5e-6)  # eq. (22)
    r_prv: tuple[float, ...] = (0.5, 100.0, 100.0)  # eq. (23)
    min_axial_fraction: float = 0.1

    def __post_init__(self):
        _positive("dt_s", self.dt_s)
        for name, size in (("q_pv", 5), ("r_pv", 3), ("q_prv", 5), ("r_prv", 3)):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape != (size,) or not np.all(np.isfinite(v)) or np.any(v <= 0.0):
                raise ValueError(f"{name} must be {size} positive variances, got {v}")
        if not 0.0 < self.min_axial_fraction < 1.0:
            raise ValueError(
                f"min_axial_fraction must be in (0, 1), got {self.min_axial_fraction}")


@dataclass(frozen=True, eq=False)
class YeModel(EKFModel):
    """An :class:`EKFModel` plus ``velocity(x, v_in) -> [v_x, v_y, v_z]`` in mm/s."""

    velocity: Callable[[np.ndarray, float], np.ndarray]


_H_YE = np.hstack([np.eye(3), np.zeros((3, 2))])  # H = [I_3 0], eq. (10)


def _feed_speed(u) -> float:
    v_in = np.asarray(np.nan if u is None else u, dtype=float).reshape(-1)
    if v_in.size != 1 or not np.isfinite(v_in[0]) or v_in[0] < 0.0:
        raise ValueError(f"u must be the feed speed v_in (a finite scalar >= 0), got {u}")
    return float(v_in[0])


def _state(x) -> np.ndarray:
    return _vector("x", x, 5)


def ye_pv_model(params: YeEKFParams | None = None) -> YeModel:
    """Ye 2025, position-velocity (PV) state x = [p_x, p_y, p_z, v_y, v_z] (eq. (6)).

    Constant velocity, eq. (7), with the sample period written out: the printed
    "p(k+1) = p(+) + v(k)" omits T and has a typo for p(k); the authors meant

        p(k+1) = p(k) + T v(k),  v_yz(k+1) = v_yz(k),  v_x = sqrt(v_in^2 - v_y^2 - v_z^2)

    (eq. (3)), which is what f does. Its Jacobian is eq. (8) with T on the velocity columns:
    dp_x/dv_y = -T v_y / v_x, dp_x/dv_z = -T v_z / v_x, dp_y/dv_y = dp_z/dv_z = T.
    z = H x + v with H = [I_3 0] (eqs. (9)-(10)); Q, R of eqs. (20)-(21).
    """
    p = YeEKFParams() if params is None else params
    T, c = p.dt_s, p.min_axial_fraction

    def velocity(x, v_in) -> np.ndarray:
        x, v_in = _state(x), _feed_speed(v_in)
        vy, vz = x[3], x[4]
        vx = np.sqrt(max(v_in**2 - vy**2 - vz**2, (c * v_in) ** 2))  # eq. (3), floored
        return np.array([vx, vy, vz])

    def f(x, u) -> np.ndarray:
        x = _state(x)
        out = x.copy()
        out[:3] += T * velocity(x, u)  # eq. (7), p(k+1) = p(k) + T v(k)
        return out  # v_yz(k+1) = v_yz(k), eq. (7)

    def F(x, u) -> np.ndarray:
        x, v_in = _state(x), _feed_speed(u)
        vy, vz = x[3], x[4]
        A = np.eye(5)  # eq. (8)
        A[1, 3] = A[2, 4] = T
        radicand = v_in**2 - vy**2 - vz**2
        if radicand > (c * v_in) ** 2:  # v_x depends on v_y, v_z only off the floor
            vx = np.sqrt(radicand)
            A[0, 3] = -T * vy / vx  # eq. (8), -v_y / v_x
            A[0, 4] = -T * vz / vx  # eq. (8), -v_z / v_x
        return A

    return YeModel(f=f, F=F, h=_h_ye, H=_H_jac_ye, Q=np.diag(p.q_pv), R=np.diag(p.r_pv),
                   velocity=velocity)


def ye_prv_model(params: YeEKFParams | None = None) -> YeModel:
    """Ye 2025, position-relative-velocity (PRV) state x = [p_x, p_y, p_z, v'_y, v'_z]
    (eq. (11)), v' = v / v_in.

    Same constant-velocity model (eq. (7)) with v = v_in v':

        p(k+1) = p(k) + T v_in(k) v'(k),  v'_yz(k+1) = v'_yz(k),  v'_x = sqrt(1 - v'_y^2 - v'_z^2).

    The Jacobian differs from the printed eq. (12) in three places, all typos: the (1,5)
    entry prints -v_z / v'_x where the chain rule gives -T v_in v'_z / v'_x; the (1,4) entry
    -v'_y / v'_x lacks the factor T v_in; and the (2,4), (3,5) entries print 1 / v_in where
    dp_y / dv'_y = T v_in. We implement the derivative (checked against finite differences in
    the tests). H = [I_3 0]; Q, R of eqs. (22)-(23).
    """
    p = YeEKFParams() if params is None else params
    T, c = p.dt_s, p.min_axial_fraction

    def relative(x) -> np.ndarray:
        x = _state(x)
        vy, vz = x[3], x[4]
        vx = np.sqrt(max(1.0 - vy**2 - vz**2, c**2))  # v'_x, from eq. (3), floored
        return np.array([vx, vy, vz])

    def velocity(x, v_in) -> np.ndarray:
        return _feed_speed(v_in) * relative(x)  # v = v_in v', eq. (11)

    def f(x, u) -> np.ndarray:
        x = _state(x)
        out = x.copy()
        out[:3] += T * velocity(x, u)  # eq. (7) with v = v_in v'
        return out

    def F(x, u) -> np.ndarray:
        x, v_in = _state(x), _feed_speed(u)
        vy, vz = x[3], x[4]
        A = np.eye(5)  # eq. (12), corrected
        A[1, 3] = A[2, 4] = T * v_in  # printed 1 / v_in
        radicand = 1.0 - vy**2 - vz**2
        if radicand > c**2:
            vx = np.sqrt(radicand)
            A[0, 3] = -T * v_in * vy / vx  # printed -v'_y / v'_x
            A[0, 4] = -T * v_in * vz / vx  # printed -v_z / v'_x
        return A

    return YeModel(f=f, F=F, h=_h_ye, H=_H_jac_ye, Q=np.diag(p.q_prv), R=np.diag(p.r_prv),
                   velocity=velocity)


def _h_ye(x) -> np.ndarray:
    return _H_YE @ _state(x)  # eq. (9)-(10)


def _H_jac_ye(x) -> np.ndarray:
    _state(x)
    return _H_YE.copy()  # eq. (10), constant
