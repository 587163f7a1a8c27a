"""Ye 2025's probe plant and controllers (sections 2-4): a mass-damper axis f = m a + b v
(eq. (5)), the PI controller on the probe's X velocity (eqs. (14)-(16)), the PD controller on
its Y position (eqs. (17)-(19)) and the dynamic speed gain K_e of eq. (13).

The time base of the mass-damper (velocity in mm per control cycle) and the safety limits are
described in :mod:`._ye`, which closes these loops around the EKF and the measurement.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["MassDamperAxis", "PositionPD", "SpeedGain", "VelocityPI"]


# --------------------------------------------------------------------------- plant, control


class MassDamperAxis:
    """One probe axis, f = m a + b v (eq. (5)), one step per control cycle.

    Position in mm, velocity in mm per cycle (``dt_s`` seconds; ``velocity_mm_s`` converts).
    ``integrator="implicit"``: v(k) = (f + m v(k-1)) / (m + b), p(k) = p(k-1) + v(k), Ye's
    eqs. (16), (19); ``"exact"``: the exact solution under f held over the cycle.
    """

    def __init__(self, m: float = 150.0, b: float = 20.0, *, integrator: str = "implicit",
                 dt_s: float = 1.0 / 7500.0, p: float = 0.0, v: float = 0.0):
        if not (m > 0 and b > 0 and dt_s > 0):
            raise ValueError(f"m, b, dt_s must be positive, got {m}, {b}, {dt_s}")
        if integrator == "implicit":
            cv = m / (m + b)
            cf = 1.0 / (m + b)
            dv, df = cv, cf  # p advances by the new velocity
        elif integrator == "exact":
            a = math.exp(-b / m)
            beta = (m / b) * (1.0 - a)
            cv, cf = a, (1.0 - a) / b
            dv, df = beta, (1.0 - beta) / b
        else:
            raise ValueError(f"integrator must be 'implicit' or 'exact', got {integrator!r}")
        self.m, self.b, self.integrator, self.dt_s = float(m), float(b), integrator, dt_s
        self.coef = (cv, cf, dv, df)  # v' = cv v + cf f;  p' = p + dv v + df f
        self.p, self.v = float(p), float(v)

    @property
    def velocity_mm_s(self) -> float:
        return self.v / self.dt_s

    def steady_velocity(self, f: float) -> float:
        return f / self.b

    def step(self, f: float) -> None:
        cv, cf, dv, df = self.coef
        self.p, self.v = self.p + dv * self.v + df * f, cv * self.v + cf * f


def _powers(M: np.ndarray, n: int) -> np.ndarray:
    out = np.empty((n, *M.shape))
    A = np.eye(M.shape[0])
    for j in range(n):
        A = M @ A
        out[j] = A
    return out


class _Loop:
    """A linear control loop on a :class:`MassDamperAxis` with a reference held for n cycles.

    Closed form: the augmented state s = [p, v, (integral), r] evolves as s' = M s, so the n
    cycles are ``powers @ s`` at once. When a limit would be exceeded the cycles are stepped
    one by one with clipping instead.
    """

    n_state = 3

    def __init__(self, axis: MassDamperAxis, n_steps: int, v_limit: float | None,
                 a_limit: float | None):
        self.axis, self.n_steps = axis, int(n_steps)
        self.v_limit, self.a_limit = v_limit, a_limit  # mm/cycle, mm/cycle^2
        self.integral = 0.0
        self._pw = _powers(self._matrix(), self.n_steps)
        self.n_limited = 0

    def _force_row(self) -> np.ndarray:  # f = row @ s_after_integration
        raise NotImplementedError

    def _matrix(self) -> np.ndarray:
        raise NotImplementedError

    def _state(self, r: float) -> np.ndarray:
        raise NotImplementedError

    def _set(self, s: np.ndarray) -> None:
        raise NotImplementedError

    def run(self, r: float) -> np.ndarray:
        """Run n cycles with reference r; returns the (n,) velocities (mm/cycle)."""
        ax = self.axis
        traj = self._pw @ self._state(r)
        v = traj[:, 1]
        if self._within(v, ax.v):
            self._set(traj[-1])
            return v
        self.n_limited += 1
        return self._run_limited(r)

    def _within(self, v: np.ndarray, v0: float) -> bool:
        if self.v_limit is not None and np.max(np.abs(v)) > self.v_limit:
            return False
        return self.a_limit is None or np.max(np.abs(np.diff(v, prepend=v0))) <= self.a_limit

    def _run_limited(self, r: float) -> np.ndarray:
        """Step with clipping; every 16 cycles, finish in closed form if no limit binds."""
        ax = self.axis
        cv, cf, dv, df = ax.coef
        out = np.empty(self.n_steps)
        vl = np.inf if self.v_limit is None else self.v_limit
        al = np.inf if self.a_limit is None else self.a_limit
        for j in range(self.n_steps):
            if j and j % 16 == 0:
                traj = self._pw[: self.n_steps - j] @ self._state(r)
                if self._within(traj[:, 1], ax.v):
                    self._set(traj[-1])
                    out[j:] = traj[:, 1]
                    return out
            f, integral = self._force(r)
            v_new = cv * ax.v + cf * f
            v_cl = min(max(v_new, ax.v - al), ax.v + al)
            v_cl = min(max(v_cl, -vl), vl)
            if v_cl == v_new:
                ax.p += dv * ax.v + df * f
                self.integral = integral  # integrate only while unsaturated (anti-windup)
            else:
                ax.p += v_cl
            ax.v = v_cl
            out[j] = v_cl
        return out

    def _force(self, r: float) -> tuple[float, float]:
        raise NotImplementedError


class VelocityPI(_Loop):
    """Eqs. (14)-(16): e(k) = r - v(k-1), f = K_p1 e(k) + K_i sum_i e(i), on the X axis.

    The reference r and the velocities are in mm per control cycle; :meth:`run_mm_s` takes r in
    mm/s.
    """

    def __init__(self, axis: MassDamperAxis, kp: float = 100.0, ki: float = 20.0,
                 n_steps: int = 300, v_limit: float | None = None,
                 a_limit: float | None = None):
        self.kp, self.ki = float(kp), float(ki)
        super().__init__(axis, n_steps, v_limit, a_limit)

    def _matrix(self) -> np.ndarray:
        cv, cf, dv, df = self.axis.coef
        kp, ki = self.kp, self.ki
        # s = [p, v, S, r]; S' = S + r - v; f = (kp + ki)(r - v) + ki S
        frow = np.array([0.0, -(kp + ki), ki, kp + ki])
        M = np.zeros((4, 4))
        M[0] = np.array([1.0, dv, 0.0, 0.0]) + df * frow
        M[1] = np.array([0.0, cv, 0.0, 0.0]) + cf * frow
        M[2] = [0.0, -1.0, 1.0, 1.0]
        M[3, 3] = 1.0
        return M

    def _state(self, r):
        return np.array([self.axis.p, self.axis.v, self.integral, r])

    def _set(self, s):
        self.axis.p, self.axis.v, self.integral = float(s[0]), float(s[1]), float(s[2])

    def _force(self, r):
        e = r - self.axis.v
        integral = self.integral + e
        return self.kp * e + self.ki * integral, integral

    def run_mm_s(self, r_mm_s: float) -> np.ndarray:
        """Run n cycles at reference r (mm/s); returns the velocities in mm/s."""
        return self.run(r_mm_s * self.axis.dt_s) / self.axis.dt_s


class PositionPD(_Loop):
    """Eqs. (17)-(19): e(k) = r - p(k-1), f = K_p2 e(k) + K_D (e(k) - e(k-1)) on the Y axis,
    with e(k) - e(k-1) = -v(k-1) as in eq. (19) (reference held within a frame)."""

    def __init__(self, axis: MassDamperAxis, kp: float = 30.0, kd: float = 50.0,
                 n_steps: int = 300, v_limit: float | None = None,
                 a_limit: float | None = None):
        self.kp, self.kd = float(kp), float(kd)
        super().__init__(axis, n_steps, v_limit, a_limit)

    def _matrix(self) -> np.ndarray:
        cv, cf, dv, df = self.axis.coef
        frow = np.array([-self.kp, -self.kd, self.kp])  # s = [p, v, r]
        M = np.zeros((3, 3))
        M[0] = np.array([1.0, dv, 0.0]) + df * frow
        M[1] = np.array([0.0, cv, 0.0]) + cf * frow
        M[2, 2] = 1.0
        return M

    def _state(self, r):
        return np.array([self.axis.p, self.axis.v, r])

    def _set(self, s):
        self.axis.p, self.axis.v = float(s[0]), float(s[1])

    def _force(self, r):
        return self.kp * (r - self.axis.p) - self.kd * self.axis.v, 0.0


class SpeedGain:
    """K_e of the X reference velocity.

    ``"dynamic"`` (Ye eq. (13)): 0.8**t1 after t1 consecutive frames without the needle,
    1.01**t2 after t2 consecutive frames with it (t1, t2 >= 1 count the current frame).
    ``"constant"`` (Vrooijink 2013, the "ICRA" baseline): 0.5 without, 1.05 with.
    """

    def __init__(self, kind: str = "dynamic", max_gain: float = math.inf):
        if kind not in ("dynamic", "constant"):
            raise ValueError(f"gain must be 'dynamic' or 'constant', got {kind!r}")
        self.kind = kind
        self.max_gain = float(max_gain)  # the dynamic law's ceiling (ours; see YeServoConfig)
        self.t1 = 0  # consecutive frames not detected
        self.t2 = 0  # consecutive frames detected

    def update(self, detected: bool) -> float:
        if detected:
            self.t1, self.t2 = 0, self.t2 + 1
        else:
            self.t1, self.t2 = self.t1 + 1, 0
        if self.kind == "constant":
            return 1.05 if detected else 0.5
        return min(1.01**self.t2, self.max_gain) if detected else 0.8**self.t1
