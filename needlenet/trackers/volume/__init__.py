"""Needle trackers for 3D ultrasound volumes: Uhercik 2010's RANSAC, Zhao 2013's ROI-RK and
Chatelain 2013's insertion detection + Kalman-predicted VOI.

``VolumeTracker(method, ...)`` makes one of three trackers, each in its own module and owning
its own state:

- :mod:`.ransac` (``"ransac"``): whole-volume RANSAC on every volume (Zhao App. B);
- :mod:`.roi_rk` (``"roi-rk"``): Zhao 2013's ROI-based RANSAC and Kalman filter on the axis
  angles and the tip;
- :mod:`.chatelain` (``"chatelain"``): Chatelain 2013's insertion detection and Kalman filter
  on the needle curve's control points.

They share one measurement (:mod:`._measure`: candidates, RANSAC, least squares, the tip
where the feature drops), the image's placement of a learned map's needle
(:mod:`._placement`) and the geometry of the volume's grid (:mod:`._geometry`). The
parameters are grouped in :mod:`.params`; ``docs/notes/volume-tracker.md`` has the
measurements behind their defaults. The only Python loops run over RANSAC batches,
initialisation attempts and Kalman steps, never over voxels or hypotheses.

Known behaviour. On physical needle echoes (``volume-motion``) the fitted axis follows the wall
facing the probe, about 0.5 mm (one radius of the 18 G needle) above the centre line; the
learned placement keeps the map's depth for that reason. At CR 2.5 the classical roi-rk
initialisation fails or locks on a tissue structure; Chatelain's detection of the moving needle
does not.
"""

from ._base import VolumeTracker
from .chatelain import ChatelainTracker
from .params import (
    ChatelainParams,
    LearnedPlacementParams,
    MeasurementParams,
    RoiRkParams,
    VolumeTrackerParams,
)
from .ransac import RansacTracker
from .roi_rk import RoiRkTracker

__all__ = ["ChatelainParams", "ChatelainTracker", "LearnedPlacementParams", "MeasurementParams",
           "RansacTracker", "RoiRkParams", "RoiRkTracker", "VolumeTracker", "VolumeTrackerParams"]
