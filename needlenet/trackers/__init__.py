"""Trackers: in-plane (Mathiassen 2017), volume (Uhercik/Zhao 2013/Chatelain 2013) and axial
(Carriere 2016), all behind one interface and each taking a FeatureSource."""

from ._axial import AxialParams, AxialTracker
from ._base import NeedleEstimate, Status, Tracker, frames_from_sequence
from ._inplane import InplaneParams, InplaneTracker
from ._registry import TRACKERS, make_tracker, tracker_class, tracker_params
from .volume import VolumeTracker, VolumeTrackerParams

__all__ = ["AxialParams", "AxialTracker", "InplaneParams", "InplaneTracker", "NeedleEstimate",
           "Status", "TRACKERS", "Tracker", "VolumeTracker", "VolumeTrackerParams",
           "frames_from_sequence", "make_tracker", "tracker_class", "tracker_params"]
