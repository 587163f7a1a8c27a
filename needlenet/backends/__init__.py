"""Estimation back ends of the five papers: RANSAC, Kalman filters, particle filters, EKF,
the bicycle model, insertion detection, line search and speckle tracking. Import them from
here; the modules behind (``_ransac``, ``_kalman``, ...) are private."""


from ._axis_profile import AxisTip, sample_along_axis, tip_along_axis
from ._bicycle import (
    CarriereParams,
    CarriereParticleFilter,
    bicycle_path,
    bicycle_step,
    curvature_radius,
    fit_plane_angle_pca,
    heading_increment,
    shape_error,
    tip_error,
    uv_to_xyz,
    xyz_to_uv,
)
from ._ekf import (
    AdaptiveNoise,
    EKFModel,
    EKFUpdate,
    ExtendedKalmanFilter,
    YeEKFParams,
    YeModel,
    ye_prv_model,
    ye_pv_model,
)
from ._insertion import (
    Detection,
    InsertionDetector,
    InsertionParams,
    candidate_set,
    detect_insertion,
    geometric_median,
)
from ._kalman import (
    KalmanFilter,
    LinearModel,
    UpdateResult,
    angles_to_direction,
    chatelain_control_points_model,
    chi2_gate,
    direction_to_angles,
    mahalanobis,
    predict,
    update,
    zhao_model,
)
from ._line_search import (
    LineSearchParams,
    NeedleLine,
    WorkingMap,
    extend_end,
    find_needle_line,
    hough_peaks,
    line_segment,
    refine_line,
    working_map,
)
from ._mathiassen_kf import (
    MathiassenAngleFilter,
    MathiassenAngleParams,
    MathiassenTipFilter,
    MathiassenTipParams,
    candidate_posterior,
    tip_candidates,
)
from ._ncc import (
    SpeckleMatch,
    TemplateMatch,
    TipVelocity,
    match_template_roi,
    speckle_track_3d,
    tip_velocity,
    variance_image,
)
from ._particle import (
    MathiassenPFParams,
    MathiassenTipParticleFilter,
    ParticleFilter,
    RngLike,
    UpdateOutcome,
    effective_sample_size,
    h_pdf,
    multinomial_resample,
    residual_resample,
    stratified_resample,
    systematic_resample,
)
from ._ransac import RansacResult, adaptive_trial_count, ransac
from ._ransac_checks import Check, max_curvature, min_sample_distance, within_angle
from ._ransac_models import LineModel, PolyCurveModel, RansacModel

__all__ = [
    "AdaptiveNoise", "AxisTip", "CarriereParams", "CarriereParticleFilter", "Check",
    "Detection", "EKFModel", "EKFUpdate", "ExtendedKalmanFilter", "InsertionDetector",
    "InsertionParams", "KalmanFilter", "LineModel", "LineSearchParams", "LinearModel",
    "MathiassenAngleFilter", "MathiassenAngleParams", "MathiassenPFParams",
    "MathiassenTipFilter", "MathiassenTipParams", "MathiassenTipParticleFilter", "NeedleLine",
    "ParticleFilter", "PolyCurveModel", "RansacModel", "RansacResult", "RngLike",
    "SpeckleMatch", "TemplateMatch", "TipVelocity", "UpdateOutcome", "UpdateResult",
    "WorkingMap", "YeEKFParams", "YeModel", "adaptive_trial_count", "angles_to_direction",
    "bicycle_path", "bicycle_step", "candidate_posterior", "candidate_set",
    "chatelain_control_points_model", "chi2_gate", "curvature_radius", "detect_insertion",
    "direction_to_angles", "effective_sample_size", "extend_end", "find_needle_line",
    "fit_plane_angle_pca", "geometric_median", "h_pdf", "heading_increment", "hough_peaks",
    "line_segment",
    "mahalanobis", "match_template_roi", "max_curvature", "min_sample_distance",
    "multinomial_resample", "predict", "ransac", "refine_line", "residual_resample",
    "sample_along_axis", "shape_error", "speckle_track_3d", "stratified_resample",
    "systematic_resample", "tip_along_axis", "tip_candidates", "tip_error", "tip_velocity",
    "update", "uv_to_xyz", "variance_image", "within_angle", "working_map", "xyz_to_uv",
    "ye_prv_model", "ye_pv_model", "zhao_model",
]
