"""Trackers: in-plane (Mathiassen 2017), volume (Uhercik/Zhao 2013/Chatelain 2013) and axial
(Carriere 2016), all behind one interface and each taking a FeatureSource."""

from ._base import NeedleEstimate, Status, Tracker, frames_from_sequence

__all__ = ["NeedleEstimate", "Status", "Tracker", "frames_from_sequence"]
