"""The tip filters of Mathiassen 2017's in-plane methods on one frame (sections II-C and II-D):
Table II's Kalman filter with Bayesian candidate selection (Algorithm 4) or section III-B's
particle filter on h_pdf (Algorithm 5), started with a two-point initialisation, and OM's
maximum of h(x). A mixin of :class:`~._inplane.InplaneTracker`, whose state it uses
(``params``, ``filter_kind``, ``use_velocity``, ``dt_s``, ``rng``, the tip filter and the
last tip)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..backends import (
    MathiassenPFParams,
    MathiassenTipFilter,
    MathiassenTipParams,
    MathiassenTipParticleFilter,
    tip_candidates,
)
from ..features import PAPER_PX_MM, Frame

__all__ = ["TipStep", "TipFiltering", "mm_to_px"]


class TipStep(NamedTuple):
    """The tip filter's result on one frame (the last five: see :class:`InplaneDetails`)."""

    along_mm: float  # the tip along the axis
    var_px2: float | None  # its variance, paper px^2; None for OM (R_MIN is reported)
    velocity: str | None = None
    candidates: int | None = None
    accepted: bool | None = None
    velocity_mm_s: float | None = None
    measurement_mm: float | None = None


def mm_to_px(mm):
    """Millimetres in the paper's 0.10 mm pixels (section III-B)."""
    return np.asarray(mm, dtype=float) / PAPER_PX_MM


class TipFiltering:
    """The tip along the axis on one frame, for :class:`~._inplane.InplaneTracker`."""

    def _velocity_px_s(self, frame: Frame) -> float | None:
        """The robot's insertion speed along the axis in px/s (KF_v, PF_v), else None."""
        if not self.use_velocity or frame.insertion_speed_mm_s is None:
            return None
        return float(mm_to_px(frame.insertion_speed_mm_s))

    def _make_tip_filter(self, x0_px: float, v_px_s: float | None):
        """Table II's KF (read in frame units: see :mod:`._inplane`) or section III-B's PF."""
        dt = self.dt_s
        v0 = 0.0 if v_px_s is None else v_px_s
        if self.filter_kind == "kf":
            fps = 1.0 / dt
            params = MathiassenTipParams(
                dt_s=dt,
                p0_velocity_px2_s2=(5.0 * fps) ** 2,  # 5 px/frame
                q_std_px=0.1 * fps,  # Q = diag(1/2 0.1^2 px^2, (0.1 px/frame)^2)
                r_velocity_px2_s2=(1.0 * fps) ** 2,  # R_v = (1 px/frame)^2
                evidence=self.params.evidence)
            return MathiassenTipFilter(x0_px, v0, params)
        maker = MathiassenPFParams.pf_v if self.use_velocity else MathiassenPFParams.pf
        params = maker(dt_s=dt, n_particles=self.params.pf_particles)
        return MathiassenTipParticleFilter(x0_px, v0, params, rng=self.rng)

    def _tip_step(self, x_mm: np.ndarray, h: np.ndarray, seen: bool, frame: Frame) -> TipStep:
        """The tip along the axis (mm) and its variance for this frame, from h(x) at tip
        positions ``x_mm``."""
        x_px = mm_to_px(x_mm)
        velocity = self._velocity_px_s(frame)
        note = "the frame carries no insertion speed; image only" if \
            self.use_velocity and velocity is None else None
        if self.filter_kind is None or self._tip_filter is None:  # OM: the maximum of h(x)
            x_tip = float(x_mm[int(np.argmax(h))]) if seen else self._tip_along_mm
            if self.filter_kind is not None and seen:
                self._two_point_start(x_tip, float(frame.t))
            return TipStep(x_tip, None, note)
        if self.filter_kind == "kf":
            if seen:
                M = max(1, int(round(self.params.axis.candidate_radius_mm /
                                     float(x_mm[1] - x_mm[0]))))
                idx = tip_candidates(h, M)  # eq. (12)
                scores = h[idx] - h.min()  # P(j_i) of eq. (16) needs h >= 0
                if not scores.sum() > 0:
                    idx, scores = idx[:0], scores[:0]
            else:
                idx, scores = np.zeros(0, int), np.zeros(0)
            est = self._tip_filter.step(x_px[idx], scores, velocity)  # Algorithm 4
            measured = float(est.measurement_px * PAPER_PX_MM) if est.accepted else None
            return TipStep(est.position_px * PAPER_PX_MM, float(est.P[0, 0]), note,
                            int(idx.size), bool(est.accepted),
                            est.velocity_px_s * PAPER_PX_MM, measured)
        h_used = h if seen else np.zeros_like(h)  # a frame without the needle: flat h_pdf
        est = self._tip_filter.step(h_used, x_px, velocity, rng=self.rng)  # Algorithm 5
        return TipStep(est.position_px * PAPER_PX_MM, float(est.covariance[0, 0]), note,
                        accepted=bool(est.updated),
                        velocity_mm_s=est.velocity_px_s * PAPER_PX_MM)

    def _two_point_start(self, x_tip_mm: float, t: float) -> None:
        """Start the tip filter at this measurement with the velocity of the last two."""
        v = 0.0
        if self._first_fix is not None:
            x0, t0 = self._first_fix
            v = (x_tip_mm - x0) / (t - t0 if t > t0 else self.dt_s)
            if abs(v) > self.params.max_start_speed_mm_s:  # an outlier, not a needle speed
                v = 0.0
        self._tip_filter = self._make_tip_filter(float(mm_to_px(x_tip_mm)),
                                                 float(mm_to_px(v)))
        self._first_fix = None
