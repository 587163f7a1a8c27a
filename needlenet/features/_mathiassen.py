"""Mathiassen 2017's needle axis search and tip features (IEEE TCST 25(3), section II-A/B).

The axis search lives in :mod:`._mathiassen_axis`, the tip features and their weights in
:mod:`._mathiassen_tip`; this module gathers both. Read them in the paper's order:

- :func:`ray_profiles` and :func:`ray_scores`: one search step's rays through a rotated ROI,
  each averaged over 2s+1 samples along the needle (eq. 1), their derivative (eq. 2) and the
  score of a bright line (eqs. 3-5);
- :func:`axis_search_step`: Algorithm 1 for a batch of angles (histogram, smoothing, the points
  on the needle, their mean p_p);
- :func:`estimate_axis`: Algorithm 2, 1-degree steps then 0.1-degree steps around the best;
- :func:`tip_features` and :func:`tip_likelihood`: the five features E_1..E_5 along the axis
  (eqs. 7-10) and h(x) = w^T E(x) (eq. 6, Algorithm 3); :func:`tip_map_along_axis` is h(x)
  for a learned source that predicts a tip map.

Geometry. Everything is computed in millimetres in the probe frame (x lateral, z depth) and
sampled through the frame's :class:`synth.Grid`, one sample per image pixel (the smallest
spacing); the paper's pixel parameters (section III-B, 0.10 mm/px) are stored in mm. The
needle enters at the top right and goes down-left at the insertion angle theta to the skin:
v_n = (-cos theta, sin theta) points from the entry to the tip and v_p = (sin theta,
cos theta) is its normal pointing into the tissue. The ROI's top corner A is the anchor of
the axis coordinates: a point is A + y v_p + x v_n, the axis is {y = p_p} and the tip is at
x = p_n along it.

The search finds the brightest line echo, which for a needle is its upper wall (the lower one
is hidden by the reverberations): the needle's centre line lies ``axis_offset_mm`` further
along v_p, a calibration stored with the tip weights (see ``training/mathiassen_fit.py``).
"""

from ._mathiassen_axis import (
    N_FEATURES,
    PAPER_PX_MM,
    AxisEstimate,
    AxisSteps,
    MathiassenParams,
    axis_search_step,
    axis_vectors,
    estimate_axis,
    ray_positions_mm,
    ray_profiles,
    ray_scores,
    roi_anchor_mm,
)
from ._mathiassen_tip import (
    TipFeatures,
    TipWeights,
    kernel_gpp,
    kernel_sq,
    load_tip_weights,
    region_difference,
    tip_features,
    tip_likelihood,
    tip_map_along_axis,
    weights_path,
)

__all__ = [
    "N_FEATURES",
    "PAPER_PX_MM",
    "AxisEstimate",
    "AxisSteps",
    "MathiassenParams",
    "TipFeatures",
    "TipWeights",
    "axis_search_step",
    "axis_vectors",
    "estimate_axis",
    "kernel_gpp",
    "kernel_sq",
    "load_tip_weights",
    "ray_positions_mm",
    "ray_profiles",
    "ray_scores",
    "region_difference",
    "roi_anchor_mm",
    "tip_features",
    "tip_likelihood",
    "tip_map_along_axis",
    "weights_path",
]
