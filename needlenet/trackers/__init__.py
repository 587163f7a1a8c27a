"""Trackers: in-plane (Mathiassen 2017), volume (Uhercik/Zhao 2013/Chatelain 2013) and axial
(Carriere 2016), all behind one interface and each taking a FeatureSource."""

from ._axial import AxialParams, AxialTracker
from ._base import NeedleEstimate, Status, Tracker, frames_from_sequence
from ._cross_section import below_top_edge, local_peak, subpixel_peak
from ._details import (
    AxialDetails,
    AxialModel,
    EstimateDetails,
    InplaneDetails,
    LineDetails,
    VolumeDetails,
)
from ._inplane import InplaneParams, InplaneTracker
from ._inplane_line_params import LineTrackerParams
from ._registry import (
    DEFAULT_FEATURES,
    DEFAULT_METHODS,
    TRACKERS,
    make_tracker,
    tracker_class,
    tracker_methods,
    tracker_params,
)
from .volume import VolumeTracker, VolumeTrackerParams

__all__ = ["AxialDetails", "AxialModel", "AxialParams", "AxialTracker", "below_top_edge",
           "DEFAULT_FEATURES", "DEFAULT_METHODS", "EstimateDetails", "frames_from_sequence",
           "InplaneDetails", "InplaneParams", "InplaneTracker", "LineDetails", "LineTrackerParams",
           "local_peak",
           "make_tracker", "NeedleEstimate", "Status", "subpixel_peak", "Tracker", "tracker_class",
           "tracker_methods", "tracker_params", "TRACKERS", "VolumeDetails", "VolumeTracker",
           "VolumeTrackerParams"]
