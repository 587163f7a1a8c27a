"""``"ransac"``: the model-fitting RANSAC of Uhercik 2010 as Zhao 2013 describes it
(Appendix B), on every volume from scratch.

Threshold the imaged sector at the 99th percentile (eq. (B1)), fit a line with the adaptive
trial count (eq. (B8)) capped at Zhao's 50 trials, refine it by least squares on the inliers
(local optimisation, eq. (B6)) and find the tip where the intensity along the axis drops below
the threshold (:func:`._measure.measure`). No state is kept between volumes.

Whole-volume RANSAC capped at 50 trials misses most short needles, as Zhao reports (inlier
ratio ~0.05, eq. (B8) asks for ~1800 trials); with enough trials it still prefers a bright
line-like tissue structure when that is longer than the needle.
"""

from __future__ import annotations

import numpy as np

from ...features import Frame
from .._base import NeedleEstimate, Status
from ._base import VolumeTracker
from ._geometry import Volume
from ._measure import measure, threshold

__all__ = ["RansacTracker"]


class RansacTracker(VolumeTracker, method="ransac"):
    """Uhercik 2010 / Zhao 2013 App. B: one whole-volume RANSAC per volume. Its covariance is
    ``r_position * I`` (the tip's measurement variance of roi-rk's filter)."""

    def _track(self, frame: Frame, vol: Volume, dt: float) -> NeedleEstimate:
        p = self.params
        level = threshold(vol, p.measurement)  # eq. (B1)
        m = measure(vol, None, level, p, self.rng, max_trials=p.measurement.max_trials)
        if not m.ok:
            return self._report(frame, self._not_found(), m)
        return self._report(frame, Status.TRACKING, m, m.tip, m.direction,
                            p.roi_rk.r_position * np.eye(3))
