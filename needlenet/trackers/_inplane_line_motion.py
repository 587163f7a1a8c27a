"""The `line` tracker's reading of a tip from the echo gained between frames
(:mod:`._inplane_motion`), where the frame's search offers no needle line.

While a needle is tracked, the change is read along its line from where it entered to the
edge of the view. The tip read there is a measurement of the filter's tip when it passes the
filter's gate (the needle's map runs on along an interface beside it, or fades, while the
needle goes on advancing); when it does not, the filter restarts there once the tip has been
read advancing along the line on consecutive frames (the filter held a tip the map had
misplaced). While none is tracked, the change is read along the line the search refused
because it shows no tip (it crosses the view, or runs on to its edge: a needle merged on the
map with an interface), when that line enters through the edge of the view and descends (so
that its entry end is known); a tip read there starts a track once it has been read advancing
along the same line (:class:`~._inplane_motion.MotionMark`). The needle reported is the line
from its entry to the tip read.

A tip the map gives that the filter's gate refuses is replaced by the one read from the gain
on its line when that passes the gate. A new track's line is read too: where the echo gained
on it shows an advancing tip well short of the tip the map gives (more than the tip map's
window behind it and the search's bridged gap), the map's line runs on past the needle
(merged with an interface, or along the streak past a tip), and the tip is the one read from
the gain, once seen advancing; until then the frame is missed.
"""

from __future__ import annotations

import numpy as np

from ..backends import NeedleLine, WorkingMap, chi2_gate
from ..features import Frame
from ._base import NeedleEstimate
from ._inplane_geometry import distance_to_edge, entry_to_tip
from ._inplane_line_params import MAX_DISTANCE_MM
from ._inplane_line_tip import tip_spread_covariance
from ._inplane_motion import MotionPeak

__all__ = ["MovingTip"]


class MovingTip:
    """Mixin of :class:`~._inplane_line.LineTracker` (module doc)."""

    def _moving_tip(self, frame: Frame, seg: NeedleLine, wm: WorkingMap, inner: np.ndarray,
                    priority) -> NeedleEstimate | None:
        """The estimate from the tip read where the echo was gained since the frame before,
        or None (the frame is then missed as it would be without it)."""
        p = self.params
        tracked = self._x is not None and self._dir is not None and self._entry_mm is not None
        shown = seg if seg else seg.refused
        if tracked:
            entry, d = self._entry_mm, self._dir
        else:
            if shown is None or not shown.found or not priority(shown) or \
                    abs(shown.direction[1]) < np.sin(np.deg2rad(p.orientation_min_angle_deg)):
                self._motion_mark.clear()
                return None
            line = entry_to_tip(shown, frame, p.orientation_min_angle_deg, inner)
            entry, d = line.start_mm, line.direction
        peak = self._gain_on(frame, inner, entry, d)
        if peak is None:
            self._motion_mark.clear()  # a tip is seen advancing on consecutive frames
            return None
        tip = self._gain_tip(peak, d)
        speed = p.initial_speed_std_mm_s * chi2_gate(1, p.gate_probability)
        advanced = self._motion_mark.advanced(frame.t, entry, d, tip, p.track_window_deg,
                                              p.entry_margin_mm, p.growing.growth_mm, speed,
                                              1.5 * self.dt_s)
        spread = self._run_covariance(d, peak)
        restart = not tracked or \
            self._gate_distance(tip, spread) > chi2_gate(2, p.gate_probability)
        if restart and not advanced:
            return None
        along = float((tip - entry) @ d)
        piece = NeedleLine(True, "", entry.copy(), entry + along * d, d.copy(),
                           support=float(shown.support if shown else 0.0))
        if priority(piece):
            self._axis = (0.5 * (piece.start_mm + piece.end_mm), d.copy())
        self._misses = 0
        if restart:  # a tip seen advancing along the line: the needle's, wherever the
            self._start(tip.copy())  # filter held it
            accepted, restarted = None, tracked
        else:
            accepted, restarted = self._filter(tip.copy(), spread)
        ambiguity = tip_spread_covariance(d, peak.run_mm) + \
            self._band_covariance(wm, piece, self._level())
        return self._estimate(frame, piece, tip.copy(), False, accepted, restarted, False,
                              peak.run_mm, ambiguity, from_motion=True)

    def _runs_past_gain(self, frame: Frame, seg: NeedleLine, tip_mm: np.ndarray,
                        inner: np.ndarray) -> float:
        """How far (mm) the tip measured on ``seg`` (a new track's line, oriented entry to
        tip) lies past an advancing tip read from the echo gained on it, when that is more
        than the tip map's window behind the end plus the search's bridged gap; else 0."""
        p = self.params
        d = seg.direction
        peak = self._gain_on(frame, inner, seg.start_mm, d)
        if peak is None:
            return 0.0
        past = float((tip_mm - seg.start_mm) @ d) - peak.along_mm
        return past if past > p.tip_window_mm[0] + p.search.gap_mm else 0.0

    def _tip_before_line_end(self, frame: Frame, seg: NeedleLine, past: float,
                             wm: WorkingMap, inner: np.ndarray, priority) -> NeedleEstimate:
        """A new track's line that runs ``past`` mm on past the advancing tip read from the
        echo gained on it: the estimate at that tip once seen advancing, else the frame is
        missed."""
        return self._moving_tip(frame, NeedleLine(False, refused=seg), wm, inner, priority) or \
            self._missed(frame, seg, (
                f"no needle: the {seg.length_mm:.0f} mm line's tip lies {past:.0f} mm past "
                "where an advancing tip gained echo since the frame before"))

    def _measure(self, frame: Frame, seg: NeedleLine, tip_mm: np.ndarray, inner: np.ndarray
                 ) -> tuple[np.ndarray, bool | None, bool, bool]:
        """Update the filter with the tip measured on ``seg`` (oriented entry to tip); where
        the gate refuses it (the map's end misplaced, on the streak or the reverberation arcs
        past a tip), with the tip read from the echo gained on the line instead when that
        passes the gate. (The measurement, whether the gate accepted it, whether the filter
        restarted, whether the tip was read from the gain.)"""
        accepted, restarted = self._filter(tip_mm)
        if accepted is not False or restarted:
            return tip_mm.copy(), accepted, restarted, False
        d = seg.direction
        peak = self._gain_on(frame, inner, seg.start_mm, d)
        if peak is None:
            return tip_mm.copy(), accepted, restarted, False
        spread = self._run_covariance(d, peak)
        gained = self._gain_tip(peak, d)
        if self._gate_distance(gained, spread) > chi2_gate(2, self.params.gate_probability):
            return tip_mm.copy(), accepted, restarted, False
        accepted, restarted = self._filter(gained.copy(), spread)
        return gained, accepted, restarted, True

    @staticmethod
    def _run_covariance(direction: np.ndarray, peak: MotionPeak) -> np.ndarray:
        """The tip read from the gain lies anywhere along its changed run: a variance of
        the run's length squared over 12 along the line."""
        return np.outer(direction, direction) * peak.run_mm ** 2 / 12.0

    def _gain_tip(self, peak: MotionPeak, direction: np.ndarray) -> np.ndarray:
        """The tip on the centre line: the gain read is the echo of the wall facing the
        probe, moved by ``needle_radius_mm`` into the tissue (as the classical echo is)."""
        normal = np.array([-direction[1], direction[0]])
        if normal[1] < 0:
            normal = -normal
        return peak.point_mm + self.params.needle_radius_mm * normal

    def _gain_on(self, frame: Frame, inner: np.ndarray, entry: np.ndarray,
                 direction: np.ndarray) -> MotionPeak | None:
        """The advancing tip read on the line from ``entry`` along ``direction`` to the edge
        of the view (:meth:`~._inplane_motion.MotionTip.peak_on`; None: none)."""
        room = distance_to_edge(inner, frame, entry, direction, max_mm=2 * MAX_DISTANCE_MM)
        return self._change.peak_on(frame, inner, entry, direction, room)

