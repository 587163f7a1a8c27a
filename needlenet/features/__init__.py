"""Feature sources: classical features from the papers and learned ONNX likelihood maps."""

from ._base import FeatureSource, Frame, FrameError, IntensityFeatures, Likelihood, check_frame
from ._frangi import FrangiFeatures, FrangiParams
from ._hough import DFParams, ding_fenster
from ._learned import SHIPPED_MODELS, LearnedFeatures, ModelError, shipped_model_path, wall_offsets
from ._line_contrast import line_contrast
from ._mathiassen import (
    PAPER_PX_MM,
    AxisEstimate,
    MathiassenParams,
    TipFeatures,
    TipWeights,
    axis_vectors,
    estimate_axis,
    load_tip_weights,
    roi_anchor_mm,
    tip_features,
    tip_likelihood,
    tip_map_along_axis,
    weights_path,
)
from ._resample import (
    NORMALIZATIONS,
    frame_image_statistics,
    frame_statistics,
    image_statistics,
    normalize,
    to_model_grid,
)
from ._variance import VarianceFeatures

__all__ = ["axis_vectors", "AxisEstimate", "check_frame", "DFParams", "ding_fenster",
           "estimate_axis", "FeatureSource", "Frame", "frame_image_statistics", "frame_statistics",
           "FrameError",
           "FrangiFeatures", "FrangiParams", "image_statistics", "IntensityFeatures",
           "learned_features", "LearnedFeatures", "Likelihood", "line_contrast",
           "load_tip_weights", "MathiassenParams", "ModelError", "NORMALIZATIONS", "normalize",
           "PAPER_PX_MM", "roi_anchor_mm", "shipped_model_path", "SHIPPED_MODELS", "tip_features",
           "tip_likelihood", "tip_map_along_axis", "TipFeatures", "TipWeights", "to_model_grid",
           "VarianceFeatures", "wall_offsets", "weights_path"]


# onnxruntime threads per modality: the in-plane network on one 500 x 384 frame (252 x 192 on
# its grid) runs no faster on two threads than on one (0.83 ms at best either way, on the
# 2-core machine), and a second thread only contends with other work; the axial network on a
# 128 x 128 slice or the tracker's ~80 x 80 box neither (0.29 / 0.13 ms at best; medians at
# load 5: 0.30 / 0.14 ms on one thread, 0.40 / 0.23 on two); volumes do use two
DEFAULT_THREADS = {"inplane": 1, "axial": 1, "volume": 2}


def learned_features(modality: str, model: str | None = None,
                     threads: int | None = None) -> FeatureSource:
    """The learned FeatureSource of a modality: the shipped ONNX model, or ``model``;
    ``threads``: onnxruntime's intra-op threads (default :data:`DEFAULT_THREADS`)."""
    from ._learned import LearnedFeatures, shipped_model_path

    path = model if model is not None else shipped_model_path(modality)
    if threads is None:
        threads = DEFAULT_THREADS.get(modality, 2)
    return LearnedFeatures(path, modality=modality, threads=threads)
