"""Trackers: in-plane (Mathiassen 2017), volume (Uhercik/Zhao 2013/Chatelain 2013) and axial
(Carriere 2016), all behind one interface and each taking a FeatureSource."""

from ._axial import AxialParams, AxialTracker
from ._base import NeedleEstimate, Status, Tracker, frames_from_sequence
from ._details import (
    AxialDetails,
    AxialModel,
    EstimateDetails,
    InplaneDetails,
    LineDetails,
    VolumeDetails,
)
from ._inplane import InplaneParams, InplaneTracker
from ._registry import TRACKERS, make_tracker, tracker_class, tracker_params
from .volume import VolumeTracker, VolumeTrackerParams

__all__ = ["AxialDetails", "AxialModel", "AxialParams", "AxialTracker", "EstimateDetails",
           "InplaneDetails", "InplaneParams", "InplaneTracker", "LineDetails", "NeedleEstimate",
           "Status", "TRACKERS", "Tracker", "VolumeDetails", "VolumeTracker",
           "VolumeTrackerParams", "frames_from_sequence", "make_tracker", "tracker_class",
           "tracker_params"]
