"""Feature sources: classical features from the papers and learned ONNX likelihood maps."""

from ._base import FeatureSource, Frame, FrameError, IntensityFeatures, Likelihood, check_frame
from ._frangi import FrangiFeatures, FrangiParams
from ._learned import LearnedFeatures, ModelError
from ._line_contrast import line_contrast
from ._variance import VarianceFeatures

__all__ = ["FeatureSource", "Frame", "FrameError", "IntensityFeatures", "Likelihood",
           "check_frame", "learned_features", "LearnedFeatures", "ModelError", "line_contrast",
           "VarianceFeatures", "FrangiFeatures", "FrangiParams"]


def learned_features(modality: str, model: str | None = None, threads: int = 2) -> FeatureSource:
    """The learned FeatureSource of a modality: the shipped ONNX model, or ``model``."""
    from ._learned import LearnedFeatures, shipped_model_path

    path = model if model is not None else shipped_model_path(modality)
    return LearnedFeatures(path, modality=modality, threads=threads)
