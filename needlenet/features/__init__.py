"""Feature sources: classical features from the papers and learned ONNX likelihood maps."""

from ._base import FeatureSource, Frame, FrameError, IntensityFeatures, Likelihood, check_frame

__all__ = ["FeatureSource", "Frame", "FrameError", "IntensityFeatures", "Likelihood",
           "check_frame"]
