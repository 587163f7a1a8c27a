"""Feature sources: classical features from the papers and learned ONNX likelihood maps."""

from ._base import FeatureSource, Frame, FrameError, IntensityFeatures, Likelihood, check_frame
from ._frangi import FrangiFeatures, FrangiParams
from ._learned import SHIPPED_MODELS, LearnedFeatures, ModelError, shipped_model_path, wall_offsets
from ._line_contrast import line_contrast
from ._resample import NORMALIZATIONS, frame_statistics, image_statistics, normalize, to_model_grid
from ._variance import VarianceFeatures

__all__ = ["FeatureSource", "Frame", "FrameError", "IntensityFeatures", "Likelihood",
           "check_frame", "learned_features", "LearnedFeatures", "ModelError", "line_contrast",
           "VarianceFeatures", "FrangiFeatures", "FrangiParams", "SHIPPED_MODELS",
           "shipped_model_path", "wall_offsets", "NORMALIZATIONS", "frame_statistics",
           "image_statistics", "normalize", "to_model_grid"]


def learned_features(modality: str, model: str | None = None, threads: int = 2) -> FeatureSource:
    """The learned FeatureSource of a modality: the shipped ONNX model, or ``model``."""
    from ._learned import LearnedFeatures, shipped_model_path

    path = model if model is not None else shipped_model_path(modality)
    return LearnedFeatures(path, modality=modality, threads=threads)
