"""The public volume tracker: :class:`VolumeTracker` picks the method's class
(``ransac``, ``roi-rk``, ``chatelain``, each in its own module) and holds what they share:
parameters and random generator, one :class:`Volume` per frame, the report, and the checks of
a probe motion. Also the Kalman filter that the two tracking methods each own.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from ...backends import direction_to_angles, predict, update
from ...features import FeatureSource, Frame
from .._base import NeedleEstimate, Status, Tracker
from .._details import VolumeDetails
from ._geometry import Volume, cylinder
from ._measure import Measurement
from .params import VolumeTrackerParams  # also where tracker_params looks for it

__all__ = ["MAP_PAD_MM", "StateFilter", "VolumeTracker", "VolumeTrackerParams", "angles", "wrap"]

# Learned maps of a tracking method's ROI/VOI are computed on a cylinder this much wider and
# longer: the profile along the fitted axis reads the map up to profile_radius_mm (0.25 mm)
# off it, through a linear interpolation of the voxels around each sample.
MAP_PAD_MM = 1.0


def angles(u) -> tuple[float, float]:
    """Zhao 2013 eq. (4): ``(beta, alpha)`` of a direction, in radians."""
    beta, alpha = direction_to_angles(np.asarray(u, float))
    return float(beta), float(alpha)


def wrap(angle: float) -> float:
    """Angle in (-pi, pi]."""
    return float(math.pi - (math.pi - angle) % (2.0 * math.pi))


class StateFilter:
    """A linear Kalman filter (Zhao 2013 App. C, Chatelain 2013 eqs. (10)-(14)): the state
    ``x``, its covariance ``P`` and the measurement model ``H``, ``R``. The motion model
    depends on the time step, so ``F`` and ``Q`` are given to each :meth:`predict`, as
    FilterPy's ``KalmanFilter.predict(F=..., Q=...)``."""

    def __init__(self, x, P, H, R):
        self.x = np.asarray(x, float).copy()
        self.P = np.asarray(P, float).copy()
        self.H = np.asarray(H, float).copy()
        self.R = np.asarray(R, float).copy()

    def predict(self, *, F, Q) -> None:
        """x^- = F x, P^- = F P F^T + Q (Zhao eqs. (C3)-(C4), Chatelain eqs. (10)-(11))."""
        self.x, self.P = predict(self.x, self.P, F, Q)

    def update(self, z, R=None, H=None) -> None:
        """Correct with measurement ``z`` (Zhao eqs. (C5)-(C7), Chatelain eqs. (12)-(14));
        ``R`` and ``H`` override the filter's for this call (a partial measurement)."""
        res = update(self.x, self.P, z, self.R if R is None else R, self.H if H is None else H)
        self.x, self.P = res.x, res.P


class VolumeTracker(Tracker):
    """Needle tracking in 3D ultrasound volumes: ``"ransac"``, ``"roi-rk"`` or ``"chatelain"``.

    ``VolumeTracker(method, ...)`` makes the method's tracker (:class:`RansacTracker`,
    :class:`RoiRkTracker`, :class:`ChatelainTracker`), each a ``VolumeTracker``.

    Parameters
    ----------
    method : {"ransac", "roi-rk", "chatelain"}
        See the package documentation.
    features : FeatureSource, optional
        Default :class:`IntensityFeatures`. A learned source (``kind == "learned"``) turns the
        threshold into likelihood-weighted candidates, replaces the line filter of the roi-rk
        initialisation and the volume differences of the insertion detection.
    params : VolumeTrackerParams, optional
    rng, seed : numpy.random.Generator or int or None
        RANSAC's random generator (``seed`` is an alias of ``rng``, as for every tracker).

    Each :meth:`update` returns a :class:`NeedleEstimate` with the tip (mm, x, y, z), the unit
    direction from the entry to the tip, the tip covariance (mm^2; the Kalman filter's for
    roi-rk and chatelain, ``r_position * I`` for ransac, plus what the volume leaves unknown,
    :mod:`._ambiguity`), ``axis_point_mm`` (where the
    visible needle starts on the axis), ``reason`` when nothing was measured, and
    :class:`VolumeDetails` (angles of eq. (4), RANSAC's inliers and trials, the ROI's size,
    the tip before the Kalman filter).

    With a learned source the maps are computed for the whole volume where a method detects
    or initialises (every volume for ransac), and once roi-rk or chatelain tracks, only on
    the cylinder it reads (its ROI/VOI, ``MAP_PAD_MM`` wider): the source is asked for
    ``likelihood(frame, roi=flat_indices)``. A learned source must return a new array from
    each ``likelihood`` call: chatelain keeps the previous map for the difference of the next
    volume.
    """

    modality = "volume"
    methods = ("ransac", "roi-rk", "chatelain")
    # method -> its class, filled as the method modules define them
    _by_method: ClassVar[dict[str, type[VolumeTracker]]] = {}

    def __init_subclass__(cls, method: str | None = None, **kwargs):
        super().__init_subclass__(**kwargs)
        if method is not None:
            cls.methods = (method,)
            VolumeTracker._by_method[method] = cls

    def __new__(cls, method: str | None = None, *args, **kwargs):
        if cls is VolumeTracker:
            if method not in cls._by_method:
                raise ValueError(f"{cls.__name__}: unknown method {method!r}; "
                                 f"choose one of {', '.join(cls.methods)}")
            cls = cls._by_method[method]
        return super().__new__(cls)

    def __init__(self, method: str, features: FeatureSource | None = None,
                 params: VolumeTrackerParams | None = None,
                 rng: np.random.Generator | int | None = None, seed: int | None = None):
        self.params = VolumeTrackerParams() if params is None else params
        super().__init__(method, features, rng=rng, seed=seed)

    def reset(self) -> None:
        super().reset()
        self._t_prev: float | None = None

    # -- what the methods share ------------------------------------------------------------

    @property
    def _learned(self) -> bool:
        return getattr(self.features, "kind", "classical") == "learned"

    def _not_found(self) -> Status:
        """``searching`` until the needle is first found, ``lost`` after that."""
        return Status.SEARCHING if self.status == Status.SEARCHING else Status.LOST

    def _dt(self, t: float) -> float:
        dt = self.params.default_dt_s if self._t_prev is None else t - self._t_prev
        return dt if dt > 0 else self.params.default_dt_s

    def _step(self, frame: Frame) -> NeedleEstimate:
        if frame.grid.ndim != 3:
            raise ValueError(f"VolumeTracker needs 3D volumes, got a {frame.grid.ndim}D frame")
        # the maps are computed when the method first reads them, or for its region
        vol = Volume(frame, None, self._learned, self.features)
        est = self._track(frame, vol, self._dt(frame.t))
        self._t_prev = frame.t
        return est

    def _track(self, frame: Frame, vol: Volume, dt: float) -> NeedleEstimate:
        """The method's step on one volume, ``dt`` seconds after the previous one."""
        raise NotImplementedError

    def _region_maps(self, vol: Volume, point, direction, radius_mm: float,
                     t_range: tuple[float, float] = (-math.inf, math.inf)) -> None:
        """With learned features, the maps of ``vol`` computed only on the cylinder a tracking
        method reads (its ROI/VOI, :func:`cylinder`'s arguments), ``MAP_PAD_MM`` wider and
        longer; classical maps stay the whole volume's."""
        if vol.learned:
            lo, hi = t_range
            vol.load_maps(cylinder(vol, point, direction, radius_mm + MAP_PAD_MM,
                                   (lo - MAP_PAD_MM, hi + MAP_PAD_MM)))

    def _report(self, frame: Frame, status: Status, m: Measurement | None, tip=None,
                direction=None, covariance=None, reason: str | None = None,
                axis_point=None) -> NeedleEstimate:
        counts = (0, 0, 0) if m is None else (m.inliers, m.trials, m.roi_voxels)
        if tip is None:
            if reason is None and m is not None:
                reason = m.reason
            return NeedleEstimate(t=frame.t, status=status, reason=reason,
                                  details=VolumeDetails(*counts))
        beta, alpha = angles(direction)
        if axis_point is None:  # the visible entry, on the reported axis
            length = float(m.a_tip - m.a_entry) if (m is not None and m.ok) else 0.0
            axis_point = np.asarray(tip, float) - length * np.asarray(direction, float)
        measured = np.asarray(m.tip, float) if m is not None and m.ok else None
        covariance = np.asarray(covariance, float)
        if measured is not None and m.ambiguity is not None:
            covariance = covariance + m.ambiguity  # what this volume leaves unknown
        return NeedleEstimate(t=frame.t, status=status, tip_mm=np.asarray(tip, float),
                              direction=np.asarray(direction, float),
                              covariance=covariance, reason=reason,
                              axis_point_mm=np.asarray(axis_point, float),
                              details=VolumeDetails(*counts, alpha_deg=math.degrees(alpha),
                                                    beta_deg=math.degrees(beta),
                                                    measured_tip_mm=measured))

    # -- the probe moved -------------------------------------------------------------------

    def move_frame(self, D) -> None:
        """Re-express the tracker's state in the probe frame after the probe moved.

        ``D`` (4, 4) is the rigid motion of the probe: new pose = old pose @ D, so a point p
        of the old probe frame is ``inv(D) @ p`` in the new one. Each method moves its own
        state (:meth:`_move_state`); what compares two volumes voxel by voxel needs both from
        the same pose, so a non-trivial motion drops the previous volume. A bad ``D`` raises
        ``ValueError``.
        """
        D = np.asarray(D, float)
        if D.shape != (4, 4) or not np.all(np.isfinite(D)):
            raise ValueError(f"move_frame needs a finite 4x4 rigid transform, got shape "
                             f"{D.shape}")
        R0 = D[:3, :3]
        if (not np.allclose(R0.T @ R0, np.eye(3), atol=1e-6) or np.linalg.det(R0) <= 0
                or not np.allclose(D[3], [0.0, 0.0, 0.0, 1.0])):
            raise ValueError("move_frame needs a rigid transform (a rotation and a "
                             "translation, last row 0 0 0 1)")
        if np.allclose(D, np.eye(4), atol=1e-12):
            return
        R = R0.T  # inv(D): p_new = R p_old + t
        self._move_state(R, -R @ D[:3, 3])

    def _move_state(self, R: np.ndarray, t: np.ndarray) -> None:
        """Move the state to the new probe frame, p_new = R p_old + t (no state: nothing)."""
