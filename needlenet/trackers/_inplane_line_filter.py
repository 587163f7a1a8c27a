"""The `line` tracker's Kalman filter on the tip: constant velocity in (x, z) with white
acceleration noise, a chi-square gate on each tip measurement, and a restart after
``reinit_after_rejects`` refused measurements in a row. A mixin of
:class:`~._inplane_line.LineTracker`, whose state it keeps (``_x``, ``_P``, the gate's
counters).

The covariance it reports is the actual error covariance of this filter when the tip
measurements are noisier than the ``measurement_std_mm`` it was built with: the gain stays the
nominal filter's (the gate and the estimate are unchanged), and the measurement noise is
estimated from the innovations of the last ``noise_window_frames`` accepted measurements by
covariance matching (Mehra 1972: the innovations' sample covariance less the predicted part,
floored at the nominal noise), propagated through that gain (Joseph form). On a frame whose
measurement the gate refuses, it also covers the refused tip: the image put the tip there, and
the frame cannot tell which of the two is wrong.
"""

from __future__ import annotations

import numpy as np

from ..backends import chi2_gate, predict, update

__all__ = ["TipKalman"]

_H = np.hstack([np.eye(2), np.zeros((2, 2))])


class TipKalman:
    """The tip's filter (see the module's doc)."""

    def _motion(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Constant velocity in (x, z) with white acceleration noise (F, Q)."""
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        q = self.params.accel_std_mm_s2 ** 2
        blk = q * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
        Q = np.zeros((4, 4))
        Q[np.ix_([0, 2], [0, 2])] = blk
        Q[np.ix_([1, 3], [1, 3])] = blk
        return F, Q

    def _predict_tip(self, dt: float) -> None:
        F, Q = self._motion(dt)
        self._x, self._P = predict(self._x, self._P, F, Q)
        self._P_actual = F @ self._P_actual @ F.T + Q

    def _nominal_R(self) -> np.ndarray:
        return np.eye(2) * self.params.measurement_std_mm ** 2

    def _gate_distance(self, z: np.ndarray, extra: np.ndarray | None = None) -> float:
        """Mahalanobis distance of tip measurement ``z`` (its noise the nominal one plus
        ``extra``) from the filter's prediction."""
        y = z - self._x[:2]
        S = self._P[:2, :2] + self._measurement_R(extra)
        return float(np.sqrt(y @ np.linalg.solve(S, y)))

    def _measurement_R(self, extra: np.ndarray | None = None) -> np.ndarray:
        return self._nominal_R() if extra is None else self._nominal_R() + extra

    def _filter(self, z: np.ndarray, extra: np.ndarray | None = None
                ) -> tuple[bool | None, bool]:
        """Update the filter with tip measurement ``z``, whose noise is the nominal one plus
        ``extra`` (a measurement known to be coarser): whether the gate accepted it (None
        when the filter starts at it) and whether the filter restarted at it."""
        p = self.params
        if self._x is None:
            self._start(z)
            return None, False
        if self._gate_distance(z, extra) > chi2_gate(2, p.gate_probability):
            self._accepted_run = 0
            self._rejects += 1
            if self._rejects >= p.reinit_after_rejects:
                self._start(z)
                return False, True
            return False, False
        self._rejects = 0
        self._accepted_run += 1
        self._held_confirmed = self._held_confirmed or self._confirmed
        res = update(self._x, self._P, z, self._measurement_R(extra), _H)
        self._innovations.append((np.outer(res.y, res.y), self._P_actual[:2, :2].copy()))
        del self._innovations[:-p.noise_window_frames]
        J = np.eye(4) - res.K @ _H  # the nominal gain, applied to the actual errors
        self._P_actual = J @ self._P_actual @ J.T + res.K @ self._measurement_noise() @ res.K.T
        self._x, self._P = res.x, res.P
        return True, False

    def _measurement_noise(self) -> np.ndarray:
        """The tip measurements' noise covariance by covariance matching over the window,
        floored at the nominal noise in every direction."""
        R = self._nominal_R()
        if len(self._innovations) < 2:
            return R
        C = np.mean([c for c, _ in self._innovations], axis=0) - \
            np.mean([pp for _, pp in self._innovations], axis=0)
        ev, V = np.linalg.eigh(0.5 * (C + C.T))
        return (V * np.maximum(ev, R[0, 0])) @ V.T

    def _start(self, z: np.ndarray) -> None:
        p = self.params
        self._x = np.array([z[0], z[1], 0.0, 0.0])
        self._P = np.diag([p.measurement_std_mm ** 2] * 2 + [p.initial_speed_std_mm_s ** 2] * 2)
        self._P_actual = self._P.copy()
        self._innovations: list[tuple[np.ndarray, np.ndarray]] = []
        self._rejects = 0
        self._accepted_run = 0

    def _reported_covariance(self, measured_mm: np.ndarray, accepted: bool | None,
                             restarted: bool) -> np.ndarray:
        """The tip's covariance for this frame (see the module's doc)."""
        off = np.zeros(2) if accepted is not False or restarted else measured_mm - self._x[:2]
        return self._P_actual[:2, :2] + np.outer(off, off)
