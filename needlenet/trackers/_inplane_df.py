"""Mathiassen 2017's method 1, DF (Ding and Fenster's Hough detector, section III-C), as a step
of :class:`InplaneTracker`: every frame is searched within +-5 degrees of the tracked angle
and the tip put at the first gap along the axis. The reported axis is the segmented echo's
moved to the needle's centre line by the offset the other methods use for the same feature
source; with learned features the tip map places the tip near the first gap
(:meth:`DingFensterStep._tip_on_map`).

A per-frame detector holds no track, so two rules of ours give it one, both from what an
insertion can do between frames:

- the needle pivots at its entry; its axis cannot jump sideways between frames. While a needle
  is tracked, a Hough axis that passes more than ``axis_gate_mm`` from the tracked axis's
  entry is another line (a tissue line at the needle's angle, found when the needle has left
  the plane) and counts as a frame without the needle;
- once a reported needle has been lost, a line that does not lie on its axis (the same gate)
  is taken for a needle only when it is seen growing where it was first seen
  (:class:`GrowingMark`, ``growing.growth_mm``): an insertion grows, a tissue line does not.
  A needle that comes back on its own axis is taken at once.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..backends import MathiassenTipParams, NeedleLine
from ..features import AxisEstimate, axis_vectors, ding_fenster, roi_anchor_mm
from ..features._hough import DFResult
from ._base import NeedleEstimate, Status
from ._details import InplaneDetails
from ._inplane_geometry import off_line_mm
from ._inplane_growing import GrowingMark

__all__ = ["DingFensterStep"]


class DingFensterStep:
    """DF's frame step and its two rules (see the module's doc); mixed into
    :class:`InplaneTracker`, whose track state it shares."""

    def _forget_departed(self) -> None:
        self._df_departed: tuple[np.ndarray, np.ndarray] | None = None
        self._df_mark = GrowingMark(self.params.growing)

    def _df(self, frame, image, previous, tip_map, detecting: bool) -> NeedleEstimate:
        p = self.params
        grid = frame.grid
        centre = self.expected_angle_deg if self.expected_angle_deg is not None else \
            self._theta_ref
        res = ding_fenster(image, grid, centre, p.df)
        contrast, seen, cover, reason = 0.0, False, None, res.reason
        if res:
            anchor = roi_anchor_mm(grid, p.axis)
            vn, vp = axis_vectors(res.theta_deg)
            axis = AxisEstimate(res.theta_deg, float((res.tip_mm - anchor) @ vp), 0.0,
                                anchor, np.array([p.axis.ray_half_width_mm]), np.zeros(1),
                                np.zeros(1))
            x_tip = float((res.tip_mm - anchor) @ vn)
            feats, h = self._measure(image, previous, tip_map, grid, axis)
            if tip_map is not None:
                res = self._tip_on_map(res, feats.x_mm, h, x_tip, vn)
                x_tip = float((res.tip_mm - anchor) @ vn)
            first = float((res.entry_mm - anchor) @ vn)
            contrast = feats.shaft_contrast(max(first, axis.rays_mm[0]), x_tip)
            # the echo is judged from the ROI's corner, where the needle enters, to the tip
            seen, cover = self._needle_seen(feats, float(axis.rays_mm[0]), x_tip)
        need = p.detect_contrast if detecting else p.keep_contrast
        found = bool(res) and contrast >= need and seen
        if found and not detecting and self._df_line is not None:
            off = off_line_mm(self._df_line[0], res.entry_mm, res.direction)
            if off > p.axis_gate_mm:
                found = False
                reason = f"DF's axis passes {off:.1f} mm from the tracked needle's entry"
        if detecting and not found:
            self._df_mark.missed()
        if found and detecting and not self._df_taken(res):
            return NeedleEstimate(t=frame.t, status=self.status,
                                  reason="a line off the axis of the needle that left: taken "
                                         "once it grows",
                                  details=InplaneDetails(contrast, echo_coverage=cover))
        self._misses = 0 if found else self._misses + 1
        if not found and self._confirming:
            return self._not_confirmed(frame, contrast, cover)
        if not found:
            reason = reason or (f"shaft contrast {contrast:.2f} below {need}" if
                                contrast < need else "no needle echo along the axis")
            status = self.status if detecting else Status.LOST
            if not detecting and self._misses >= p.lost_after_frames:
                if self._df_line is not None and self._df_reported:
                    self._df_departed = self._df_line
                self._clear_track()
            return NeedleEstimate(t=frame.t, status=status, reason=reason,
                                  details=InplaneDetails(contrast, echo_coverage=cover))
        if detecting:
            self._clear_track()
            self._theta_ref = res.theta_deg
            self._confirming = True
        self._tip_along_mm = x_tip
        self._df_line = (np.asarray(res.entry_mm, float), np.asarray(res.direction, float))
        if detecting:
            return self._unconfirmed(frame, contrast, res.theta_deg, cover)
        confirmed_now, self._confirming = self._confirming, False
        self._df_reported = True
        self._df_departed = None  # a needle tracked again is the reference now
        self._df_mark.clear()
        # the segmented echo lies on the wall facing the probe: the centre line is the same
        # offset along v_p away as for the other methods on this feature source
        to_centre = self._offset_mm(tip_map) * vp  # vp of this frame's axis (res is found)
        return NeedleEstimate(
            t=frame.t, status=Status.TRACKING, tip_mm=np.asarray(res.tip_mm, float) + to_centre,
            direction=np.asarray(res.direction, float),
            covariance=self._covariance(res.theta_deg, float(MathiassenTipParams().r_min_px2),
                                        1.0 / 12.0 * (grid.spacing_mm[0] ** 2),
                                        p.angle.r_theta_deg2, x_tip - first),
            axis_point_mm=np.asarray(res.entry_mm, float) + to_centre,
            details=InplaneDetails(contrast, theta_deg=res.theta_deg, hough_votes=res.votes,
                                   echo_coverage=cover, detected=confirmed_now))

    def _tip_on_map(self, res: DFResult, x_mm: np.ndarray, h: np.ndarray, x_tip: float,
                    vn) -> DFResult:
        """With learned features the segmented image is the shaft map, which runs on past the
        needle by the network's blur; the tip map marks where the shaft ends. The tip is put
        at the tip map's maximum along the axis within one closing length (``df.close_mm``,
        the gap DF itself bridges) of the first gap."""
        near = np.abs(x_mm - x_tip) <= self.params.df.close_mm
        if not near.any() or not np.isfinite(h[near]).any():
            return res
        i = np.flatnonzero(near)[int(np.nanargmax(h[near]))]
        tip = np.asarray(res.tip_mm, float) + (float(x_mm[i]) - x_tip) * np.asarray(vn, float)
        return dataclasses.replace(res, tip_mm=tip)

    def _df_taken(self, res) -> bool:
        """Whether a detection ``res`` may start a track: always, unless a reported needle
        has left and ``res`` is off its axis and has not grown by ``growing.growth_mm``."""
        if self._df_departed is None:
            return True
        entry, direction = self._df_departed
        if off_line_mm(entry, res.entry_mm, res.direction) <= self.params.axis_gate_mm:
            return True
        seg = NeedleLine(True, "", np.asarray(res.entry_mm, float),
                         np.asarray(res.tip_mm, float), np.asarray(res.direction, float))
        return self._df_mark.growth_mm(seg) >= self.params.growing.growth_mm
