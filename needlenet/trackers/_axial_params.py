"""The parameters of Carriere 2016's axial tracker (:class:`~._axial.AxialTracker`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..backends import CarriereParams
from ._base import GAUGE_RADII_MM, radius_variance

__all__ = ["AxialParams"]


@dataclass(frozen=True)
class AxialParams:
    """Parameters of :class:`~._axial.AxialTracker`; mm, degrees. See the docstring of the
    ``_axial`` module for the method they tune."""

    template_mm: float = 3.0  # h = w of the template patch (rounded to an odd pixel count)
    warmup_depth_mm: float = 10.0  # ROI on the previous centre, no filter update before
    rotation_depth_mm: float | None = None  # D (60 or 80 mm in the paper): the filter stops
    # there and the predicted needle turns there; None: the filter never stops
    bevel_turn: bool = True  # False: stop at D without a turn (the paper's clinical data)
    final_depth_mm: float = 100.0  # the predicted shape runs to this depth
    shape_step_mm: float = 1.0  # sampling of the predicted shape
    step_mm: float = 0.5  # depth per frame when frames carry no probe pose
    insertion_sign: int | None = None  # +1/-1 along the elevation axis; None: from the motion
    needle_radius_mm: float = 0.635  # 18 G; the detector's Gaussian sigma
    # the radii of a needle whose gauge is not given (14-25 G): see centre_covariance
    gauge_radii_mm: tuple[float, float] = GAUGE_RADII_MM
    detect_score: float = 15.0  # robust score (max - median) / MAD of the smoothed feature
    lost_score: float = 8.0  # below this at the matched centre the cross-section vanished
    # a detection must be a compact spot (the smoothed map at detect_lateral_mm either side of
    # it below detect_compact of its score: a needle's cross-section is the needle's diameter
    # widened by the lateral beam, an interface cut across is a line) and, on a classical
    # map, stands out of the slice's other compact spots (its score at least detect_ratio
    # times the next one's, farther than detect_separation_mm: speckle's spots are alike)
    detect_lateral_mm: float = 2.0
    detect_compact: float = 0.5
    detect_ratio: float = 1.5
    detect_separation_mm: float = 2.0
    # evidence this close to the edge of a capture margin or sector mask is not detected (the
    # mask's step is no echo; the shipped model marks it within a millimetre of a sector's
    # edge on PyMUST's phased-array slices), as the in-plane tracker's mask_edge_mm
    mask_edge_mm: float = 1.5
    score_floor: float = 1e-3  # least MAD (feature units): a clean map has none
    min_peak: float | None = None  # least smoothed feature to detect; None: 0.3 for
    # learned sources (a probability has an absolute scale), 0 for classical ones
    ncc_min: float = 0.6  # an NCC peak below this is an outlier
    max_jump_mm: float = 1.0  # largest jump from the last accepted centre
    max_slope: float = 0.2  # |du/dv| allowed on top of max_jump_mm per mm of depth
    max_coast_frames: int = 2  # rejected frames in a row reported at the prediction
    drift_correction: bool = True  # False: the paper's plain update of the template
    drift_tolerance_mm: float = 0.6  # largest correction by the first template
    detect_anchor: str = "auto"  # "top_edge", "peak"; "auto": peak for learned sources
    # learned sources with learned_template = "map": move the NCC match to the likelihood's
    # sub-pixel maximum within one radius (a probability map says where the cross-section
    # is; its smooth blob makes the NCC peak wander by a tenth of a millimetre from slice
    # to slice, which the bicycle fit then extrapolates)
    learned_peak_refine: bool = True
    # learned sources: what the NCC templates are cut from. "variance": Carriere's variance
    # image (eq. 1) weighted by the likelihood: the map keeps the needle's cross-section and
    # drops the bright tissue that can capture a template, the variance image's speckle locks
    # the match from slice to slice as it does for the classical source. "texture": the
    # B-mode image weighted by the likelihood; "map": the likelihood itself (then moved to
    # its peak, learned_peak_refine). Measured on `needlenet bench axial`'s sequences (8 per
    # D; mean tip prediction error, D = 60/80 mm): "paper" filter 0.32/0.23 mm with
    # "variance", 0.38/0.24 with "texture"; "lsq" 0.050/0.005 vs 0.060/0.035.
    learned_template: str = "variance"
    # learned sources: while tracking, run the network on the box the step reads (the NCC
    # window, the drift correction's window, the template and the smoothed map around the
    # match: 37 x 37 px at 0.3 mm) plus the source's margin_mm of context, not on the whole
    # slice; detection and re-detection run on the whole slice. On `needlenet bench axial`'s
    # 16 sequences (128 x 128) the tracked centres stay within 0.006 mm of whole-slice
    # inference's and the network's input shrinks to ~80 x 80 px (docs/notes/axial.md).
    # False: the whole slice every time.
    learned_roi: bool = True
    # "lsq": steps 1-9, then the cloud moved onto the MAP least-squares fit of (theta_0, 1/R)
    # under the paper's prior (the default: it predicts the tip best on synth's sequences and
    # on PyMUST's validation slices, docs/notes/axial.md); "paper": steps 1-10 alone
    filter_update: str = "lsq"
    measurement_sd_mm: float = 0.1  # "lsq": sd of a centre, for the least-squares fit
    pf: CarriereParams = field(default_factory=CarriereParams)  # n, p, c, priors, gamma

    def centre_covariance(self) -> np.ndarray:
        """(x, z) covariance (mm^2) of where the needle's centre lies below the echo of its wall,
        once moved there by ``needle_radius_mm``: radii spread evenly over ``gauge_radii_mm`` =
        (a, b) leave it off in depth by a variance of (b - a)^2 / 12 (the in-plane tracker's
        :meth:`~._inplane_line_tip.LineTip._centre_line_covariance`, across the slice)."""
        return np.diag([0.0, radius_variance(self.gauge_radii_mm, "gauge_radii_mm")])

    def __post_init__(self) -> None:
        if self.filter_update not in ("paper", "lsq"):
            raise ValueError(f"filter_update must be 'paper' or 'lsq', got {self.filter_update!r}")
        if self.learned_template not in ("variance", "texture", "map"):
            raise ValueError(f"learned_template must be 'variance', 'texture' or 'map', got "
                             f"{self.learned_template!r}")
        if self.detect_anchor not in ("auto", "top_edge", "peak"):
            raise ValueError(f"detect_anchor must be 'auto', 'top_edge' or 'peak', got "
                             f"{self.detect_anchor!r}")
        if self.insertion_sign not in (None, 1, -1):
            raise ValueError(f"insertion_sign must be None, 1 or -1, got {self.insertion_sign}")
        radius_variance(self.gauge_radii_mm, "gauge_radii_mm")  # checks the range
        for name in ("template_mm", "step_mm", "needle_radius_mm", "shape_step_mm",
                     "max_jump_mm", "measurement_sd_mm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not (0.0 < self.detect_lateral_mm <= 100.0 and 0.0 < self.detect_separation_mm <= 100.0
                and 0.0 < self.detect_compact and self.detect_ratio >= 1.0
                and 0.0 <= self.mask_edge_mm <= 100.0):
            raise ValueError("detect_lateral_mm and detect_separation_mm must lie in (0, 100], "
                             "mask_edge_mm in [0, 100], detect_compact be positive and "
                             "detect_ratio at least 1")
