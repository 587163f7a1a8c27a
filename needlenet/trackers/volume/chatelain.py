"""``"chatelain"``: Chatelain 2013, II-B to II-D.

Detect an insertion from volume differences (fixed-size candidate set, variance test,
geometric median, entry on the boundary), then track the n control points of the needle curve
with a constant-velocity Kalman filter (eqs. (3)-(14)), select a fixed number of the brightest
voxels inside a VOI around the predicted curve (eq. (15)), fit the curve by RANSAC with the
angle constraint to the predicted direction (eq. (22)), refine it by least squares and find the
tip by the intensity drop, bridging small gaps. A withdrawal moves the measured tip back; a
needle that vanishes is reported ``lost`` and the tracker waits for a new insertion.

Two choices are not in the paper: the delta test measures the distance of the change to the
sector's boundary, not to the faces of the array (a sector volume does not fill them); and
after a detection the needle's tip is its end nearer to the change (the needle changes the
volume where it moves).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...backends import InsertionDetector, InsertionParams, chatelain_control_points_model
from ...features import Frame
from .._base import NeedleEstimate, Status
from ._base import StateFilter, VolumeTracker
from ._geometry import Volume, ball, boundary_distance, cylinder, voxel_count
from ._measure import Measurement, fail, implausible_start, measure, runs_out, threshold

__all__ = ["ChatelainTracker", "ControlPoints"]

# The insertion detector's own distance test is switched off with this (see _search).
_NO_LIMIT_MM = 1e9
# Fewest candidates of the insertion detection: a geometric median needs a few points.
_MIN_INSERTION_CANDIDATES = 10


@dataclass(frozen=True)
class ControlPoints:
    """Chatelain's state layout (eq. (3)): X = (p_1, ..., p_n, p'_1, ..., p'_n), each point
    three coordinates (mm, point order; velocities mm/s), from the entry to the tip p_n."""

    n: int

    @property
    def positions(self) -> slice:
        return slice(0, 3 * self.n)

    @property
    def velocities(self) -> slice:
        return slice(3 * self.n, 6 * self.n)

    @property
    def tip(self) -> slice:
        """p_n, the tip, in the state (and in its covariance)."""
        return slice(3 * (self.n - 1), 3 * self.n)

    @property
    def size(self) -> int:
        return 6 * self.n


class ChatelainTracker(VolumeTracker, method="chatelain"):
    """Chatelain 2013's insertion detection and VOI tracking; its Kalman filter's state is laid
    out as :class:`ControlPoints`."""

    def reset(self) -> None:
        super().reset()
        self._kf: StateFilter | None = None
        # the previous volume's whole map for the insertion detection's difference, or the
        # volume itself when tracking computed only its VOI's learned maps
        self._prev_map: np.ndarray | None = None
        self._prev_frame: Frame | None = None
        self._detector: InsertionDetector | None = None  # made for the first volume's grid
        self._pending: tuple[np.ndarray, int] | None = None  # detection, volumes left
        self._misses = 0

    @property
    def _layout(self) -> ControlPoints:
        return ControlPoints(self.params.chatelain.n_control_points)

    def _model(self, dt: float):
        c = self.params.chatelain
        return chatelain_control_points_model(c.n_control_points, 3, dt=dt, q=c.q_control,
                                              r=c.r_control)

    def _control_points(self, m: Measurement) -> np.ndarray:
        """Z_t: the n control points of eq. (3), entry to tip along the fitted curve."""
        a = np.linspace(m.a_entry, m.a_tip, self.params.chatelain.n_control_points)
        return m.model.points_at(a).reshape(-1)

    def _voi_count(self, vol: Volume) -> int:
        """Size of the fixed candidate set of eq. (15) on this grid."""
        p = self.params
        return voxel_count(p.chatelain.voi_candidates_mm3, vol, 2 * p.measurement.min_inliers)

    def _track(self, frame: Frame, vol: Volume, dt: float) -> NeedleEstimate:
        est = self._search(frame, vol, dt) if self._kf is None else self._follow(frame, vol, dt)
        self._prev_map = vol.values if vol.whole else None
        # without its whole map, the volume itself (a copy: a source may reuse its buffer)
        self._prev_frame = (None if self._prev_map is not None else
                            replace(frame, image=np.array(frame.image)))
        return est

    def _previous_map(self, vol: Volume) -> np.ndarray | None:
        """The previous volume's whole map: kept, or computed again from its frame when
        tracking computed only its VOI's (the step after a loss)."""
        if self._prev_map is None and self._prev_frame is not None:
            self._prev_map = Volume(self._prev_frame, None, vol.learned, self.features).values
        return self._prev_map

    def _follow(self, frame: Frame, vol: Volume, dt: float) -> NeedleEstimate:
        """Chatelain II-C and II-D: predict the control points, measure the needle in the VOI
        around the predicted curve, correct."""
        p = self.params
        c = p.chatelain
        n, layout, kf = c.n_control_points, self._layout, self._kf
        model = self._model(dt)
        kf.predict(F=model.F, Q=model.Q)  # eqs. (10)-(11)
        ctrl = kf.x[layout.positions].reshape(n, 3)
        chord = ctrl[-1] - ctrl[0]
        length = float(np.linalg.norm(chord))
        if length > 0:
            k0 = chord / length  # predicted principal direction k0^- (eq. (22))
            bow = 0.0 if n == 2 else float(np.linalg.norm(ctrl[1] - 0.5 * (ctrl[0] + ctrl[-1])))
            # VOI around the predicted curve (its chord, widened by the bow of a curve).
            extent = (-c.voi_margin_mm, length + c.voi_margin_mm)
            region = cylinder(vol, ctrl[0], k0, c.voi_radius_mm + bow, extent)
            self._region_maps(vol, ctrl[0], k0, c.voi_radius_mm + bow, extent)  # learned
            m = measure(vol, region, threshold(vol, p.measurement), p, self.rng,
                        max_trials=p.measurement.init_max_trials, predicted_direction=k0,
                        max_angle_deg=c.max_angle_deg, fixed_size=self._voi_count(vol),
                        model="line" if n == 2 else "curve", order=n,
                        predicted_tip=ctrl[-1])  # eqs. (15)-(22)
            if m.ok and np.linalg.norm(m.tip - ctrl[-1]) > c.voi_margin_mm:
                # a tip beyond the VOI's end: the profile ran along another structure
                m = fail(f"tip jump: {np.linalg.norm(m.tip - ctrl[-1]):.1f} mm from the "
                         f"predicted tip > voi_margin_mm", m.trials, m.roi_voxels, m.inliers)
        else:
            m = fail("the predicted needle has no length")
        if not m.ok:  # the needle has vanished (or was missed): coast, then wait for a new one
            self._misses += 1
            if self._misses > c.max_coast_volumes:
                self._kf = None
            return self._report(frame, Status.LOST, m)
        self._misses = 0
        kf.update(self._control_points(m))  # eqs. (12)-(14)
        ctrl = kf.x[layout.positions].reshape(n, 3)
        chord = ctrl[-1] - ctrl[0]
        norm = float(np.linalg.norm(chord))
        direction = m.direction if norm == 0 else chord / norm
        return self._report(frame, Status.TRACKING, m, ctrl[-1], direction,
                            kf.P[layout.tip, layout.tip], axis_point=ctrl[0])

    def _insertion_params(self, vol: Volume) -> InsertionParams:
        """The detector's parameters for this grid: the candidate set covers
        ``insertion_candidates_mm3`` whatever the voxel size, and the delta test is left to
        :meth:`_search`, which measures it to the sector's boundary."""
        c = self.params.chatelain
        n = c.insertion.n_candidates
        if c.insertion_candidates_mm3 is not None:
            n = voxel_count(c.insertion_candidates_mm3, vol, _MIN_INSERTION_CANDIDATES)
        n = min(n, int(np.prod(vol.shape)))
        return replace(c.insertion, n_candidates=int(n), distance_threshold_mm=_NO_LIMIT_MM)

    def _boundary_distance(self, vol: Volume, point: np.ndarray) -> float:
        """Distance from a point to the sector's boundary along the nearest of a fan of rays
        (the scan-converted sector is the volume whose boundary Chatelain's entry lies on)."""
        return boundary_distance(vol, point, self.params.chatelain.insertion.distance_threshold_mm)

    def _search(self, frame: Frame, vol: Volume, dt: float) -> NeedleEstimate:
        """Chatelain II-B: wait for a localised change, then fit the needle around it.

        The change map is ``|I_t - I_(t-1)|`` (or the change of a learned likelihood). The
        detector keeps a fixed number of the largest changes (eq. (1)), tests their variance
        and takes their geometric median (eq. (2)); the median must lie within delta of the
        boundary of the imaged sector. After a detection, the needle is fitted in a ball
        around the median for ``detection_window`` volumes, and tracking starts once it is
        visible over ``start_length_mm`` and passes the start tests.
        """
        p = self.params
        c = p.chatelain
        delta = c.insertion.distance_threshold_mm
        status = self._not_found()
        reason = "first volume: nothing to compare with"
        values = vol.values  # the whole map: this volume's change, and the next volume's
        previous = self._previous_map(vol)
        if previous is not None and previous.shape == values.shape:
            if self._detector is None:
                self._detector = InsertionDetector(self._insertion_params(vol))
            detection = self._detector.update_difference(np.abs(values - previous),
                                                         vol.spacing)  # eqs. (1)-(2)
            reason = detection.reason
            if detection.median_mm is not None:
                median = (vol.origin + detection.median_mm)[::-1]  # array -> point order
                gap = self._boundary_distance(vol, median)
                if gap < delta:  # ||E_t - Med|| < delta
                    self._pending = (median, c.detection_window)
                else:
                    reason = (f"median too far from the sector's boundary: {gap:.1f} mm >= "
                              f"delta = {delta} mm")
        if self._pending is None:
            return self._report(frame, status, None, reason=reason)
        median, left = self._pending
        m = self._fit_new_needle(vol, median)
        if not m.ok:
            self._pending = (median, left - 1) if left > 1 else None
            return self._report(frame, status, m)
        self._pending = None
        layout = self._layout
        model = self._model(dt)
        x = np.zeros(layout.size)  # velocities start at zero
        x[layout.positions] = self._control_points(m)
        p0 = np.empty(layout.size)
        p0[layout.positions], p0[layout.velocities] = c.r_control, c.p0_control_velocity
        self._kf = StateFilter(x, np.diag(p0), model.H, model.R)
        self._misses = 0
        return self._report(frame, Status.TRACKING, m, m.tip, m.direction,
                            self._kf.P[layout.tip, layout.tip])

    def _fit_new_needle(self, vol: Volume, median: np.ndarray) -> Measurement:
        """The needle in a ball around a detected change, if it is one to start tracking on:
        in with a sufficient length (II-A), on the change's axis, inserted from outside, its
        tip inside the sector, and brighter than its tissue (or likely on the map)."""
        p = self.params
        mp, c = p.measurement, p.chatelain
        region = ball(vol, median, c.init_voi_radius_mm)
        level = threshold(vol, mp)
        # tracking starts once the needle is in with a sufficient length (Chatelain II-A)
        mp = replace(mp, min_length_mm=max(mp.min_length_mm, c.start_length_mm))
        p = replace(p, measurement=mp)
        # The change is where the needle moved, at its tip: it orients the needle.
        m = measure(vol, region, level, p, self.rng, max_trials=mp.init_max_trials,
                    fixed_size=self._voi_count(vol), tip_hint=median)
        if not m.ok:
            return m
        w = median - m.entry
        off_axis = float(np.linalg.norm(w - (w @ m.direction) * m.direction))
        if off_axis > c.voi_radius_mm + mp.inlier_radius_mm:
            return fail(f"the fitted axis passes {off_axis:.1f} mm from the detected change",
                        m.trials, m.roi_voxels, m.inliers)
        if m.entry_gap_mm > mp.entry_margin_mm:
            return fail(f"not a needle inserted from outside: it starts {m.entry_gap_mm:.1f} "
                        f"mm inside the sector", m.trials, m.roi_voxels, m.inliers)
        why = runs_out(vol, m, c.start_tip_margin_mm) or \
            implausible_start(vol, m, p, c.start_min_likelihood, c.start_min_contrast,
                              c.start_max_sheet)
        if why is not None:
            return fail(why, m.trials, m.roi_voxels, m.inliers)
        if c.n_control_points == 3:
            m = measure(vol, region, level, p, self.rng,
                        max_trials=mp.init_max_trials, predicted_direction=m.direction,
                        max_angle_deg=c.max_angle_deg, fixed_size=self._voi_count(vol),
                        model="curve", order=3)
        return m

    def _move_state(self, R: np.ndarray, t: np.ndarray) -> None:
        """The control points move as points, their velocities rotate, P becomes B P B^T with
        B that linear map; a pending detection moves with them. The previous map (the
        insertion detection's difference) is dropped."""
        kf = self._kf
        if kf is not None:
            layout = ControlPoints(len(kf.x) // 6)
            n = layout.n
            moved = np.empty(layout.size)
            moved[layout.positions] = (kf.x[layout.positions].reshape(n, 3) @ R.T + t).reshape(-1)
            moved[layout.velocities] = (kf.x[layout.velocities].reshape(n, 3) @ R.T).reshape(-1)
            kf.x = moved
            B = np.kron(np.eye(2 * n), R)
            kf.P = B @ kf.P @ B.T
        if self._pending is not None:
            self._pending = (R @ self._pending[0] + t, self._pending[1])
        self._prev_frame = self._prev_map = None
