"""``"roi-rk"``: Zhao 2013's ROI-based RANSAC and Kalman method.

Initialise on the tubularness of the whole first volume (Frangi's line filter, Appendix A;
with learned features on the map), then in each volume run RANSAC inside a cylindrical ROI
around the axis predicted by the Kalman filter (eq. (1)), measure the tip velocity by 3-D
speckle tracking (eq. (5)) and correct the state of eqs. (2)-(4). When the ROI loses the
needle the tracker reports ``lost`` and initialises again on the next volume.

The initialisation accepts only a needle that starts near the sector's boundary (Zhao: "the
needle is inserted from the outside"), trying the next RANSAC hypothesis otherwise. At CR 2.5
the 99th-percentile threshold sits at the needle's own level (Zhao's Table 3) and the line
filter's strongest tubes are tissue, so the classical initialisation fails or locks on a
tissue structure. A bright tissue line can pass that test as well as a needle; the needle is
what advances. So every ``rival_check_volumes`` volumes the initialisation runs again without
the tracked line's ROI, and a needle found there that has advanced along its axis by
``rival_advance_mm`` since it was first seen, while the tracked tip stood still, takes the
track over (the tracked line was tissue).
"""

from __future__ import annotations

import math

import numpy as np

from ...backends import (
    angles_to_direction,
    min_sample_distance,
    ransac,
    tip_velocity,
    zhao_model,
)
from ...features import Frame, FrangiFeatures
from .._base import NeedleEstimate, Status
from ._base import StateFilter, VolumeTracker, angles, wrap
from ._geometry import Volume, cylinder
from ._measure import (
    Measurement,
    candidates,
    fail,
    implausible_start,
    measure,
    median_profile,
    runs_out,
    threshold,
)

__all__ = ["ANGLES", "ANGLE_RATES", "STATE_SIZE", "TIP", "TIP_VELOCITY", "RoiRkTracker"]

# Zhao's state S = [beta, alpha, v_beta, v_alpha, p_t, v_t] (eqs. (2)-(4), zhao_model)
ANGLES = slice(0, 2)  # beta, alpha of eq. (4) (rad)
ANGLE_RATES = slice(2, 4)  # their rates (rad/s)
TIP = slice(4, 7)  # p_t (mm, point order)
TIP_VELOCITY = slice(7, 10)  # v_t (mm/s)
STATE_SIZE = 10
# The measurement Z = [beta, alpha, p_t, v_t]; without a speckle velocity, its first rows
_Z_WITHOUT_VELOCITY = slice(0, 5)
_MAX_RIVALS = 8  # needles noted beside the tracked line: a bound on memory, not a setting
# Learned initialisation (init_select = "likelihood"): the structures that compete with a
# needle already found are looked for among this many of the most likely voxels left, with a
# quarter of init_max_trials (a needle needs a few hundred of the map's most likely voxels).
_SELECT_CANDIDATES = 5000


class RoiRkTracker(VolumeTracker, method="roi-rk"):
    """Zhao 2013's ROI-RK; its Kalman filter's state is laid out as ``ANGLES``,
    ``ANGLE_RATES``, ``TIP``, ``TIP_VELOCITY``."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._frangi = FrangiFeatures(self.params.roi_rk.frangi)

    def reset(self) -> None:
        super().reset()
        self._kf: StateFilter | None = None
        self._prev_image: np.ndarray | None = None  # for speckle tracking
        # the rival search's own random stream, so that it leaves the tracking's draws alone
        self._rival_rng = self.rng.spawn(1)[0]
        # needles seen beside the tracked line: (direction, tip, the tracked tip then)
        self._rivals: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._since_check = 0
        self._check_tip: np.ndarray | None = None  # the tracked tip at the last check
        # a new track on probation: (when it started, its first measured tip)
        self._probation: tuple[float, np.ndarray] | None = None
        # lines dropped for standing still: (direction, tip then)
        self._still: list[tuple[np.ndarray, np.ndarray]] = []

    def _zhao_model(self, dt: float):
        r = self.params.roi_rk
        return zhao_model(dt, q_angle=r.q_angle, q_tip=r.q_tip, r_angle=r.r_angle,
                          r_position=r.r_position, r_velocity=r.r_velocity)

    def _track(self, frame: Frame, vol: Volume, dt: float) -> NeedleEstimate:
        p = self.params
        r = p.roi_rk
        level = threshold(vol, p.measurement)  # eq. (B1)
        if self._kf is None:  # Step 1: initialise the ROI
            m = self._initialise(frame, vol, level)
            if not m.ok:
                self._prev_image = None
                return self._report(frame, self._not_found(), m)
            return self._start(frame, vol, m, dt)
        # Step 2: predict (eqs. (2)-(3)), ROI (eq. (1)), RANSAC, speckle tracking, correct.
        kf = self._kf
        model = self._zhao_model(dt)
        prev_tip = kf.x[TIP].copy()
        kf.predict(F=model.F, Q=model.Q)
        u_pred = angles_to_direction(*kf.x[ANGLES])
        tip_pred = kf.x[TIP]
        rival = self._advancing_rival(frame, vol, level, tip_pred, u_pred)
        if rival is not None:  # the tracked line stood still while a needle advanced
            return self._start(frame, vol, rival, dt, proven=True)
        region = cylinder(vol, tip_pred, u_pred, r.roi_radius_mm)  # eq. (1)
        self._region_maps(vol, tip_pred, u_pred, r.roi_radius_mm)  # learned: the ROI's maps
        m = measure(vol, region, level, p, self.rng, max_trials=p.measurement.max_trials,
                    predicted_direction=u_pred, predicted_tip=tip_pred)
        reason = None
        if m.ok:
            turn, shift = _axis_change(m.direction, m.entry, u_pred, tip_pred)
            if turn > r.max_axis_jump_deg:
                reason = f"axis jump: {turn:.1f} deg > {r.max_axis_jump_deg} deg"
            elif shift > r.max_axis_shift_mm:
                reason = f"axis shift: {shift:.2f} mm > {r.max_axis_shift_mm} mm"
        else:
            reason = m.reason
        if reason is None:
            reason = self._stood_still(frame, m)
        if reason is not None:  # the ROI has lost the needle: initialise again next volume
            self._kf = None
            self._prev_image = None
            return self._report(frame, Status.LOST, m, reason=reason)
        beta, alpha = angles(m.direction)
        alpha_prior = float(kf.x[ANGLES][1])
        alpha = alpha_prior + wrap(alpha - alpha_prior)  # no 2 pi jump in the innovation
        velocity = self._speckle_velocity(vol, prev_tip, dt)  # eq. (5)
        if velocity is not None:
            kf.update(np.r_[beta, alpha, m.tip, velocity])  # eqs. (C5)-(C7)
        else:  # no velocity: update on the angles and the tip only
            z = _Z_WITHOUT_VELOCITY
            kf.update(np.r_[beta, alpha, m.tip], R=kf.R[z, z], H=kf.H[z])
        self._prev_image = vol.image
        return self._report(frame, Status.TRACKING, m, kf.x[TIP],
                            angles_to_direction(*kf.x[ANGLES]), kf.P[TIP, TIP])

    def _start(self, frame: Frame, vol: Volume, m: Measurement, dt: float,
               proven: bool = False) -> NeedleEstimate:
        """Start the Kalman filter on needle ``m`` (the rates and the velocity at zero), on
        probation (:meth:`_stood_still`) unless ``proven`` (seen advancing already)."""
        r = self.params.roi_rk
        self._probation = None if proven else (frame.t, m.tip.copy())
        x = np.zeros(STATE_SIZE)
        x[ANGLES] = angles(m.direction)
        x[TIP] = m.tip
        p0 = np.empty(STATE_SIZE)
        p0[ANGLES], p0[ANGLE_RATES] = r.r_angle, r.p0_angle_rate
        p0[TIP], p0[TIP_VELOCITY] = r.r_position, r.p0_velocity
        model = self._zhao_model(dt)
        self._kf = StateFilter(x, np.diag(p0), model.H, model.R)
        self._prev_image = vol.image
        self._rivals, self._since_check, self._check_tip = [], 0, m.tip.copy()
        return self._report(frame, Status.TRACKING, m, m.tip, m.direction,
                            self._kf.P[TIP, TIP])

    def _stood_still(self, frame: Frame, m: Measurement) -> str | None:
        """Why a new track is dropped, or None: within ``prove_within_s`` of its start its
        measured tip must advance along its axis by half ``rival_advance_mm`` (the advance by
        which the rival search takes a tracked needle for the one inserted); a bright line of
        the tissue crossing the volume's face looks like a needle inserted from outside in one
        volume, but stands still. The line is remembered, and a start on it is refused until
        its tip lies that far beyond where it stood (:meth:`_on_still_line`)."""
        r = self.params.roi_rk
        if self._probation is None or r.prove_within_s == 0:
            return None
        t0, tip0 = self._probation
        step = 0.5 * r.rival_advance_mm
        if float((m.tip - tip0) @ m.direction) >= step:
            self._probation = None  # proven: a needle being inserted
            return None
        if frame.t - t0 < r.prove_within_s:
            return None
        self._probation = None
        if len(self._still) >= _MAX_RIVALS:
            del self._still[0]
        self._still.append((m.direction.copy(), m.tip.copy()))
        return (f"no needle: the line has not advanced {step:g} mm in {frame.t - t0:.1f} s "
                "since it was taken: a still structure of the tissue, not a needle inserted")

    def _on_still_line(self, m: Measurement) -> str | None:
        """Why a start on ``m`` is refused, or None: it lies on a line dropped for standing
        still (within ``max_axis_jump_deg`` and ``max_axis_shift_mm``) and its tip is not half
        ``rival_advance_mm`` beyond where that line's stood."""
        r = self.params.roi_rk
        for u, tip in self._still:
            turn, shift = _axis_change(u, tip, m.direction, m.tip)
            if turn <= r.max_axis_jump_deg and shift <= r.max_axis_shift_mm and \
                    float((m.tip - tip) @ u) < 0.5 * r.rival_advance_mm:
                return "a line that stood still before, its tip where it stood: no needle"
        return None

    def _advancing_rival(self, frame: Frame, vol: Volume, level: float, tip: np.ndarray,
                         direction: np.ndarray) -> Measurement | None:
        """Every ``rival_check_volumes`` volumes, unless the tracked tip has advanced along its
        axis by half ``rival_advance_mm`` since the last such volume or the start (then the
        tracked needle is the one being inserted), Step 1 on the whole volume less the
        tracked line's ROI: each needle found there is noted with the tracked tip; when one
        is found again on a noted line (within ``max_axis_jump_deg`` and
        ``max_axis_shift_mm``) with its tip ``rival_advance_mm`` further along its axis than
        when first seen, while the tracked tip advanced along the tracked axis by less than
        half as much, it is returned: the needle to track."""
        r = self.params.roi_rk
        self._since_check += 1
        if r.rival_check_volumes == 0 or self._since_check < r.rival_check_volumes:
            return None
        self._since_check = 0
        last, self._check_tip = self._check_tip, np.array(tip, float)
        if last is not None and float((tip - last) @ direction) >= 0.5 * r.rival_advance_mm:
            return None  # the tracked needle advances: it is the one inserted
        m = self._initialise(frame, vol, level, exclude=(tip, direction, r.roi_radius_mm),
                             rng=self._rival_rng)
        if not m.ok:
            return None
        for r_dir, r_tip, tracked_then in self._rivals:
            turn, shift = _axis_change(m.direction, m.tip, r_dir, r_tip)
            if turn <= r.max_axis_jump_deg and shift <= r.max_axis_shift_mm:
                advanced = float((m.tip - r_tip) @ m.direction)
                tracked = float((tip - tracked_then) @ direction)
                if advanced >= r.rival_advance_mm and tracked < 0.5 * advanced:
                    return m
                return None  # a noted line: its first sighting stays the reference
        if len(self._rivals) >= _MAX_RIVALS:
            del self._rivals[0]
        self._rivals.append((m.direction.copy(), m.tip.copy(), np.array(tip, float)))
        return None

    def _initialise(self, frame: Frame, vol: Volume, level: float,
                    exclude: tuple[np.ndarray, np.ndarray, float] | None = None,
                    rng: np.random.Generator | None = None) -> Measurement:
        """Step 1 of Zhao: RANSAC on the tubularness of the whole volume places the first ROI,
        in which the needle is measured on the intensity.

        The hypothesis must look like a needle inserted from outside (Zhao App. B: "the
        needle is inserted from the outside"): bright along its axis, at least
        ``min_length_mm`` long, starting within ``entry_margin_mm`` of the sector's boundary
        and ending with a tip inside the volume (``init_tip_margin_mm``). A hypothesis that
        is not (a tubular structure of the tissue) is set aside with its inliers and RANSAC
        runs again, up to ``init_attempts`` times (sequential RANSAC). ``exclude``: (point,
        direction, radius): candidates within the radius of that line are set aside first;
        ``rng``: the random stream (the tracker's by default).
        """
        rng = self.rng if rng is None else rng
        p = self.params
        mp, r = p.measurement, p.roi_rk
        if self._learned:  # a learned map already says where the needle is
            cand, weights = candidates(vol, None, level, mp)
            pts, r_in = vol.points(cand), mp.inlier_radius_mm
        else:
            tub = self._frangi.tubularness(frame)  # Appendix A, whole volume
            sector = _block_sector(vol.sector, tub.factor) & (tub.values > 0)
            values = tub.values[sector]
            if values.size < mp.min_inliers:
                return fail("no tubular structure in the volume")
            t_tub = float(np.percentile(values, mp.threshold_percentile))  # eq. (B1)
            idx = np.flatnonzero(sector.reshape(-1) & (tub.values.reshape(-1) >= t_tub))
            pts = tub.grid.index_to_points(np.stack(np.unravel_index(idx, tub.values.shape), -1))
            weights = tub.values.reshape(-1)[idx].astype(float)
            # Inliers on the block-averaged grid lie up to a working voxel from the axis.
            r_in = max(mp.inlier_radius_mm, float(np.max(tub.grid.spacing_mm)))
        keep = np.ones(len(pts), bool)
        if exclude is not None:
            c, u, radius = exclude
            w = pts - np.asarray(c, float)
            keep &= np.linalg.norm(w - np.outer(w @ u, u), axis=1) > radius
        trials = 0
        m = fail("no candidates")
        # learned maps: every hypothesis that passes competes on its likelihood
        choose = self._learned and r.init_select == "likelihood"
        found: list[tuple[float, Measurement]] = []
        for _ in range(r.init_attempts):
            active = np.flatnonzero(keep)
            if active.size < mp.min_inliers:
                break
            max_trials = mp.init_max_trials
            if found:  # competitors of a found needle: the most likely voxels, fewer trials
                max_trials = max(1, mp.init_max_trials // 4)
                if active.size > _SELECT_CANDIDATES:
                    top = np.argpartition(weights[active], active.size - _SELECT_CANDIDATES)
                    active = active[top[active.size - _SELECT_CANDIDATES:]]
            w = None if weights is None else weights[active]
            res = ransac(pts[active], "line", residual_threshold=r_in, weights=w,
                         is_sample_valid=min_sample_distance(mp.min_sample_distance_mm),
                         success_probability=mp.success_probability,
                         max_trials=max_trials, batch_size=mp.batch_size,
                         refine_iterations=mp.refine_iterations, rng=rng)
            trials += res.n_trials
            if not res:
                m = fail(f"RANSAC: {res.reason}", trials)
                break
            region = cylinder(vol, res.model.origin, res.model.direction, r.roi_radius_mm)
            m = measure(vol, region, level, p, rng, max_trials=mp.max_trials)
            m.trials += trials
            if m.ok and m.entry_gap_mm > mp.entry_margin_mm:
                m = fail(f"not a needle inserted from outside: it starts {m.entry_gap_mm:.1f} "
                         f"mm inside the sector", m.trials, m.roi_voxels, m.inliers)
            why = None if not m.ok else (
                runs_out(vol, m, r.init_tip_margin_mm)
                or implausible_start(vol, m, p, r.init_min_likelihood, r.init_min_contrast,
                                     r.init_max_sheet)
                or self._on_still_line(m))
            if why is not None:
                m = fail(why, m.trials, m.roi_voxels, m.inliers)
            if m.ok and not choose:
                return m
            if m.ok:
                found.append((median_profile(vol, m.model, m.a_entry, m.a_tip, mp), m))
            keep[active[res.inliers]] = False  # set the structure aside
        if found:
            score, best = found[0]  # RANSAC's own choice: the most support
            for s, other in found[1:]:
                if s > r.init_select_ratio * score:
                    score, best = s, other
            best.trials = trials
            return best
        return m

    def _speckle_velocity(self, vol: Volume, tip_mm: np.ndarray, dt: float):
        """Tip velocity (mm/s, point order) by 3-D speckle tracking (Zhao eq. (5)), or None.

        The kernel is taken around the previous tip in the previous volume and searched for in
        the current one; only the search box is handed over, so no whole volume is copied.
        """
        if self._prev_image is None or self._prev_image.shape != vol.image.shape:
            return None
        r = self.params.roi_rk
        k_half = np.maximum(np.rint(r.speckle_kernel_mm / vol.spacing), 1).astype(int)
        s_half = k_half + np.ceil(r.speckle_search_mm / vol.spacing).astype(int)
        centre = np.rint(vol.to_index(tip_mm)).astype(int)
        if np.any(centre < 0) or np.any(centre >= vol.shape):
            return None
        lo = np.maximum(centre - s_half, 0)
        hi = np.minimum(centre + s_half + 1, vol.shape)
        box = tuple(slice(a, b) for a, b in zip(lo, hi, strict=True))
        try:
            res = tip_velocity(self._prev_image[box], vol.image[box], centre - lo, k_half,
                               s_half, vol.spacing, dt)
        except ValueError:  # constant kernel (outside the sector) or clipped away
            return None
        return res.velocity_mm_s[::-1]  # array order -> point order

    def _move_state(self, R: np.ndarray, t: np.ndarray) -> None:
        """The tip moves as a point, its velocity rotates, the axis angles (beta, alpha of
        eq. (4)) are recomputed from the rotated direction, their rates and covariance carried
        by the Jacobian of that map; P becomes B P B^T with B the whole linear map. The
        previous volume (speckle tracking) and the needles noted beside the tracked line are
        dropped; the next check compares the tracked tip with where it is now."""
        kf = self._kf
        if kf is not None:
            x = kf.x
            alpha0 = float(x[ANGLES][1])

            def new_angles(a):
                b, al = angles(R @ angles_to_direction(a[0], a[1]))
                return np.array([b, alpha0 + wrap(al - alpha0)])

            ang = np.asarray(x[ANGLES], float)
            J = np.empty((2, 2))
            h = 1e-6
            for j in range(2):
                e = np.zeros(2)
                e[j] = h
                J[:, j] = (new_angles(ang + e) - new_angles(ang - e)) / (2 * h)
            B = np.zeros((STATE_SIZE, STATE_SIZE))
            B[ANGLES, ANGLES] = J
            B[ANGLE_RATES, ANGLE_RATES] = J
            B[TIP, TIP] = R
            B[TIP_VELOCITY, TIP_VELOCITY] = R
            moved = np.empty(STATE_SIZE)
            moved[ANGLES] = new_angles(ang)
            moved[ANGLE_RATES] = J @ x[ANGLE_RATES]
            moved[TIP] = R @ x[TIP] + t
            moved[TIP_VELOCITY] = R @ x[TIP_VELOCITY]
            kf.x = moved
            kf.P = B @ kf.P @ B.T
            self._check_tip = kf.x[TIP].copy()
        self._prev_image = None
        self._rivals = []
        self._still = []  # where the tissue stood in the volume before


def _axis_change(direction: np.ndarray, point: np.ndarray, other_direction: np.ndarray,
                 other_point: np.ndarray) -> tuple[float, float]:
    """(degrees between two axes, mm from the first axis, through ``point`` along unit
    ``direction``, to ``other_point``)."""
    turn = math.degrees(math.acos(min(1.0, abs(float(direction @ other_direction)))))
    w = other_point - point
    return turn, float(np.linalg.norm(w - (w @ direction) * direction))


def _block_sector(sector: np.ndarray, f: int) -> np.ndarray:
    """Sector mask on the block-averaged working grid of the line filter (all of a block)."""
    if f == 1:
        return sector
    pad = [(0, (-n) % f) for n in sector.shape]
    s = np.pad(sector, pad, mode="constant")
    shape = []
    for n in s.shape:
        shape += [n // f, f]
    return s.reshape(shape).all(axis=tuple(range(1, 2 * sector.ndim, 2)))
