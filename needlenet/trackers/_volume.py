"""Needle trackers for 3D ultrasound volumes: Uhercik 2010's RANSAC, Zhao 2013's ROI-RK and
Chatelain 2013's insertion detection + Kalman-predicted VOI.

Three methods behind one :class:`VolumeTracker`:

``"ransac"``
    The model-fitting RANSAC of Uhercik 2010 as Zhao 2013 describes it (Appendix B), on every
    volume from scratch: threshold the imaged sector at the 99th percentile (eq. (B1)), fit a
    line with the adaptive trial count (eq. (B8)) capped at Zhao's 50 trials, refine it by
    least squares on the inliers (local optimisation, eq. (B6)) and find the tip where the
    intensity along the axis drops below the threshold.

``"roi-rk"``
    Zhao 2013: initialise on the tubularness of the whole first volume (Frangi's line filter,
    Appendix A), then in each volume run the same RANSAC inside a cylindrical ROI around the
    axis predicted by the Kalman filter (eq. (1)), measure the tip velocity by 3-D speckle
    tracking (eq. (5)) and correct the state ``[beta, alpha, v_beta, v_alpha, p_t, v_t]`` of
    eqs. (2)-(4). When the ROI loses the needle the tracker reports ``lost`` and initialises
    again on the next volume.

``"chatelain"``
    Chatelain 2013, II-B to II-D: detect an insertion from volume differences (fixed-size
    candidate set, variance test, geometric median, entry on the boundary), then track the
    n control points of the needle curve with a constant-velocity Kalman filter, select a
    fixed number of the brightest voxels inside a VOI around the predicted curve (eq. (15)),
    fit the curve by RANSAC with the angle constraint to the predicted direction (eq. (22)),
    refine it by least squares and find the tip by the intensity drop, bridging small gaps.
    A withdrawal moves the measured tip back; a needle that vanishes is reported ``lost`` and
    the tracker waits for a new insertion.

All three share one measurement (:func:`_measure`): candidates, batched RANSAC, least
squares on the inliers, an axis oriented from the entry to the tip, and the tip where the
maximum of the feature over the needle's cross-section drops below the threshold for good
(gaps shorter than ``max_gap_mm`` bridged), one needle-image cap (``tip_cap_mm``) short of
the drop. The least squares is repeated on the inliers between the entry and the tip: the
inliers of the infinite line beyond the needle are background. With learned features the map
finds the needle and the B-mode image places it (``image_refine``): the axis is refitted on
the image's voxels in narrowing tubes around it (across the beam; along it the map's depth
stands, as a needle's echo comes from its wall facing the probe) and the tip is the change
point of the image along the axis, where that change is clear.

Choices where the papers are silent are fields of :class:`VolumeTrackerParams`, each with its
reason. Three are not in the papers at all: the initialisations accept only a needle that
starts near the sector's boundary (Zhao: "the needle is inserted from the outside"), trying
the next RANSAC hypothesis otherwise; Chatelain's delta test measures the distance of the
change to the sector's boundary, not to the faces of the array; and after a detection the
needle's tip is its end nearer to the change (the needle changes the volume where it moves).

Everything is in millimetres in the probe frame, point order (x, y, z), through the frame's
:class:`synth.Grid` (voxels are anisotropic). Scan-converted sector volumes are exactly 0
outside the sector: those voxels are not tissue and never become candidates or thresholds.
The only Python loops run over RANSAC batches, initialisation attempts and Kalman steps,
never over voxels or hypotheses.

Known behaviour. Whole-volume RANSAC capped at 50 trials misses most short needles, as Zhao
reports (inlier ratio ~0.05, eq. (B8) asks for ~1800 trials); with enough trials it still
prefers a bright line-like tissue structure when that is longer than the needle. On physical
needle echoes (``volume-motion``) the fitted axis follows the wall facing the probe, about
0.5 mm (one radius of the 18 G needle) above the centre line. At CR 2.5 the 99th-percentile
threshold sits at the needle's own level (Zhao's Table 3: thresholds above ~70 fail at CR
2.5) and the line filter's strongest tubes are tissue, so the roi-rk initialisation fails or
locks on a tissue structure; Chatelain's detection of the moving needle does not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from ..backends._insertion import InsertionDetector, InsertionParams
from ..backends._kalman import (
    KalmanFilter,
    angles_to_direction,
    chatelain_control_points_model,
    direction_to_angles,
    zhao_model,
)
from ..backends._ncc import tip_velocity
from ..backends._ransac import LineModel, PolyCurveModel, RansacResult, ransac, tip_along_axis
from ..features._base import FeatureSource, Frame, Likelihood
from ..features._frangi import FrangiFeatures, FrangiParams
from ._base import NeedleEstimate, Status, Tracker

__all__ = ["VolumeTracker", "VolumeTrackerParams"]

# The insertion detector's own distance test is switched off with this (see _search_chatelain).
_NO_LIMIT_MM = 1e9
# Fewest candidates of the insertion detection: a geometric median needs a few points.
_MIN_INSERTION_CANDIDATES = 10
# A ray has left the sector where it stays outside for this long (_run_out_distance).
_RUN_OUT_MM = 1.0
# The tissue that start_min_contrast compares the needle with: a ring this far from the axis.
_CONTRAST_RING_MM = (2.0, 3.0)
# Directions of the rays along which the distance to the sector's boundary is measured: the
# 26 neighbours of a voxel.
_RAYS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                  if (i, j, k) != (0, 0, 0)], float)
_RAYS /= np.linalg.norm(_RAYS, axis=1, keepdims=True)
# Learned initialisation (init_select = "likelihood"): the structures that compete with a
# needle already found are looked for among this many of the most likely voxels left, with a
# quarter of init_max_trials (a needle needs a few hundred of the map's most likely voxels; the
# competition costs 4 RANSAC runs at the first volume, 3.8 s on a 128^3 volume at full size).
_SELECT_CANDIDATES = 5000
# A tip hint decides the orientation when it projects farther than this fraction of the
# needle's length from its middle.
_HINT_MARGIN = 0.1
# The tissue around the needle (image_tip_background_mm): lines on a ring around the axis,
# this many angles at each of three radii; a position counts where this many are in the sector.
_RING_ANGLES = 12
_RING_MIN_SAMPLES = 6
# Offsets, perpendicular to the axis and in units of ``profile_radius_mm``, of the lines along
# which the tip profile is sampled: the axis itself and six lines around it.
_PROFILE_OFFSETS = np.array(
    [[0.0, 0.0]] + [[math.cos(a), math.sin(a)] for a in np.arange(6) * math.pi / 3]
)


@dataclass(frozen=True)
class VolumeTrackerParams:
    """Parameters of the three volume trackers, with the papers' values where they give them.

    Zhao 2013 / Uhercik 2010 (Appendix B)
    -------------------------------------
    threshold_percentile : float
        T_I of eq. (B1): "99% of the voxels are from the background", taken over the imaged
        sector only (voxels outside the sector are 0 and are not tissue).
    intensity_threshold : float or None
        A fixed T_I in gray levels (0-255) instead of the percentile, as Zhao's Table 3 varies
        it from 60 to 100 (intensity features only).
    percentile_stride : int
        T_I is estimated on every ``stride``-th voxel per axis (1/8 of them for 2): a
        percentile over ~10^5 voxels, at a fraction of the cost. 1 uses every voxel.
    inlier_radius_mm : float
        r of eq. (B5) (Chatelain's f0, eq. (19)): "the expected radius of the needle in the
        image". Ours: the 0.5 mm radius plus half a voxel diagonal of a 128^3 volume.
    min_sample_distance_mm : float
        d_min of Appendix B (not given by Zhao); 2 mm: two points closer than four needle
        radii define the direction poorly.
    max_trials : int
        J_max: Zhao caps RANSAC at 50 trials ("to limit the processing time").
    init_max_trials : int
        Cap for the initialisations (roi-rk on the tubularness, chatelain after an
        insertion), where the inlier ratio is lowest. Ours.
    init_attempts : int
        Initialisations are sequential RANSAC: a hypothesis that is not a needle inserted from
        outside is set aside with its inliers and RANSAC runs again, this many times at most.
    init_select, init_select_ratio : str, float
        Which needle the roi-rk initialisation takes. ``"support"``: the first hypothesis that
        passes, RANSAC's largest support (Zhao). ``"likelihood"`` (used with learned features
        only): the attempts go on after a needle is found, among the most likely voxels left
        (``_SELECT_CANDIDATES``, a quarter of the trials), and a hypothesis that passes
        replaces RANSAC's choice when the median of the map along it is more than
        ``init_select_ratio`` times that choice's. A long tissue structure can out-support a
        short needle that the map finds far more likely; at CR 2.0 the two medians are within a
        few percent (0.19 against 0.20 on one training volume), where the support decides. On
        15 seeded backgrounds of the Table 3 protocol drawn from training seeds (5,000,000,
        6,000,000, 7,000,000), the learned roi-rk failed on 52 / 33% of volumes at CR 2.0 / 2.5
        with ``"support"`` and 48 / 25% with ``"likelihood"`` (0-1% both at CR 3.0 and 3.5).
        The ratio 1.2 was read from the competing hypotheses of a few training volumes and of
        the benchmark's CR 3.0 volumes, whose diagnosis prompted this option (so Table 3 is
        not an independent test of it; the 7,000,000 backgrounds are: 34 / 32% against
        34 / 31%). It costs the first volume about 0.35 s more (1.0 against 0.7 s, 128^3).
    entry_margin_mm : float
        A needle found at initialisation must start within this distance of the sector's
        boundary (it is inserted from outside, Zhao App. B). Ours: 5 mm, as a moving phantom
        carries the visible entry up to ~4 mm into the sector.
    success_probability : float
        eta of eq. (B8) (1 - epsilon of Chatelain eq. (21)).
    batch_size : int
        Hypotheses drawn and scored at once; the adaptive count of eq. (B8) is checked between
        batches, so small batches let RANSAC stop early.
    refine_iterations : int
        Least-squares refinements of the winner (local optimisation, eq. (B6)).
    min_inliers : int
        Fewer inliers than this and the needle is not found.
    min_length_mm : float
        Shortest visible needle (entry to tip) that counts as a needle.
    max_gap_mm : float
        Gaps in the intensity along the axis shorter than this are bridged when looking for the
        tip (Chatelain II-D: "we discard small intensity gaps"); it also splits the inliers into
        pieces, of which the largest is the needle.
    profile_radius_mm : float
        The profile along the axis is the maximum over the axis and six parallel lines this
        far from it (half the needle radius): a dark needle voxel or a sub-voxel error of the
        axis does not look like a drop.
    tip_cap_mm : float
        The bright region along the axis ends this far beyond the tip, which is subtracted.
        Zhao's needle voxels are those closer than the radius to the axis segment (eq. (9)),
        so its image ends in a cap of one radius (0.5 mm), which the linear interpolation of
        the profile stretches by about 0.1 mm more (measured on 128^3 CR 4.7 volumes: the
        median error along the axis is then 0). 0.6 mm.
    likelihood_threshold : float
        For learned features: likelihood above which a voxel is needle (candidates and tip)
        when ``likelihood_relative`` is None.
    likelihood_relative : float or None
        For learned features: the tip is where the likelihood along the axis drops below this
        fraction of its median over the fitted needle (default a half-maximum).
    likelihood_floor : float
        For learned features: voxels below this never become weighted candidates.
    max_candidates : int
        For learned features: at most this many candidates (the most likely ones) are kept.
    tip_window_mm, tip_min : float
        For learned features with a tip channel: the tip is moved to the tip map's maximum
        along the axis within this distance of the shaft's drop, when that maximum reaches
        ``tip_min``. Off by default (0): the shipped 3D model's tip channel puts the tip
        within 1 mm in only 7.5% of held-out volumes, and with a 3 mm window on Zhao's
        Table 2 volumes (ROI-RK) it moved the median tip error from 0.40-0.77 mm to
        1.09-2.68 mm.
    image_refine : bool
        For learned features: the map finds the needle, the B-mode image places it. After
        the least squares on the likelihood-weighted inliers, a straight axis is refitted on
        the image inside a narrowing tube around it (``image_refine_radii_mm``; weighted
        total least squares of the voxels, each weighted by its excess over the tube's
        ``image_refine_percentile``), and the tip is the change point of the image along the
        axis (:func:`_image_tip`). Zhao's local optimisation (App. B, eq. (B6)) refits on the
        image's own inliers; the learned map's needle is a blurred, stride-2 output, whose
        axis lay a median 0.56-0.58 mm off the needle on the held-out CR 3.0 and 5.0 volumes
        of ``needlenet bench models`` and whose half-maximum drop fell a median 1.8 mm short
        of the tip at CR 2.0. Curved models keep their axis and get the image's tip.
    image_refine_radii_mm : tuple of float
        Radii of the successive tubes (mm), widest first: the first catches an axis a few
        tenths of a millimetre off, the last (about 1.5 needle radii) keeps the tissue
        beside the needle out of the fit.
    image_refine_percentile : float
        Voxels of the tube above this percentile of the tube's intensities pull the axis,
        each by its excess: the needle fills a small part of the widest tube.
    image_refine_keep_depth : bool
        The image moves the axis across the beam only; along the depth axis of the probe
        frame (z, made perpendicular to the needle) the map's position stands. A physical
        needle's echo comes from its wall facing the probe, a radius above the centre line
        that the map was trained on. In Chatelain's servo (``volume-motion``, misalignment,
        seeds 0-3) the P-hat RMSE was 0.49-0.63 mm with the map's axis and tip, 0.62-0.63 mm
        with the image's axis and tip, 0.39-0.49 mm with the map's axis and the image's tip,
        and 0.36-0.38 mm with the image's axis across the beam only and the image's tip.
    image_tip_radius_mm : float
        The image along the axis is averaged over the axis and six parallel lines this far
        from it (about the needle's radius).
    image_tip_window_mm : float
        The change point maximises the mean of the image over this length behind it minus the
        mean over this length ahead of it.
    image_tip_search_mm : float
        The change point is looked for within this distance of where the learned map's
        likelihood drops (which can fall short of the tip where the contrast is low).
    image_tip_track_search_mm : float
        While roi-rk or chatelain track a needle, the change point is looked for within this
        distance of the Kalman filter's predicted tip instead (the ROI's prior along the axis,
        where eq. (1) gives the one across it). On 12 seeded backgrounds of the Table 3
        protocol from training seeds (6,000,000 and 7,000,000) the learned roi-rk failed on
        35.5 / 21.5% of volumes at CR 2.0 / 2.5 searching around the map's drop, 36.5 / 14.5%
        within 4 mm of the prediction and 30 / 16% within 6 mm. 6 mm.
    image_tip_cap_mm : float
        The image's change point lies this far beyond the tip (the needle's echo spreads
        past its end), which is subtracted: a median 0.32-0.35 mm on ``volume`` sequences of
        training seeds (5,000,000-5,000,005; CR 3.0, 4.7 and 5.0, 96^3 and 128^3 volumes,
        alpha 0 and 60 degrees), not on the held-out seeds the benchmarks report; with the
        tissue ring subtracted (``image_tip_background_mm``) 0.34 mm on seeds 5,000,000-
        5,000,005 at CR 2.0 and 5.0 (96^3) and CR 2.0 (128^3, alpha 0). 0.35 mm.
    image_tip_min_effect : float
        The image's change must be at least this many pooled standard deviations of the
        profile within its two windows, or the learned drop stands. Measured with the known
        axis on training seeds (5,000,000-5,000,005, CR 2.0, 128^3, alpha 0: the Table 3
        set-up), searching 8 mm either side of the tip: along the needle the change reached
        4.8 (median) and 3.0 (5th percentile) standard deviations, along single lines 4 mm
        beside it 1.3 (median) and 2.5 (95th percentile); with the raw profile (no
        ``image_tip_background_mm``) 4.4 / 1.2 and 1.6 / 3.8. A needle's tip pushed into
        brighter tissue shows less (1-2 while roi-rk tracked a stalled tip on a training
        background). On 12 seeded backgrounds of the Table 3 protocol from training seeds
        (6,000,000 and 7,000,000) the learned roi-rk failed on 30 / 16% of volumes at CR 2.0
        / 2.5 with 2.5 and the raw profile, 30 / 10.5% with 2.5 and the background removed,
        24 / 11% with 2.0 and 21.5 / 11% with 1.5; 1.0 gave 21 / 11.5%. 1.5.
    image_tip_background_mm : (float, float) or None
        Inner and outer radius (mm) of a ring of lines around the axis (12 directions at
        three radii) whose mean, the tissue beside the needle, is subtracted from the profile
        before the change point is looked for, so that the tissue's own brightness changes
        along the axis (a tip entering a brighter region) do not pass for the needle's end.
        Outside the needle's echo (its radius plus the lateral resolution), inside Zhao's ROI.
        With the true axis on the 40 held-out volumes of ``needlenet bench models`` (CR 2.0)
        the change point put the tip within 1 mm in 92.5% of them without it and 95% with it;
        the ransac tracker's one-volume tip there went from 45% to 52.5%. None: the raw
        profile.

    Zhao 2013 ROI-RK
    ----------------
    roi_radius_mm : float
        R_ROI of eq. (1). Zhao does not give it; we take five needle radii, the cylinder Zhao
        uses for the contrast ratio (eq. (9)): wide enough for the axis error of the Frangi
        initialisation and for a tip moving 1 mm per volume, narrow enough to keep the
        inlier ratio above Zhao's 0.4.
    max_axis_jump_deg, max_axis_shift_mm : float
        The ROI has lost the needle when the fitted axis turns more than this from the
        predicted one, or passes farther than this from the predicted tip.
    frangi : FrangiParams
        Line filter of the initialisation (Appendix A).
    speckle_kernel_mm, speckle_search_mm : float
        Half sizes of the kernel region around the tip and of the extra search margin for the
        speckle tracking (eq. (5)); the search margin bounds the tip displacement per volume.
    q_angle, q_tip, r_angle, r_position, r_velocity : float
        Noise of the Kalman filter of eqs. (2)-(3) (:func:`zhao_model`), in rad^2/s^3,
        mm^2/s^3, rad^2, mm^2 and mm^2/s^2. Zhao estimated them "by a large number of repeat
        trials" and does not report them; so did we, on CR 4.7 volumes: the measured tip is
        within 0.1-0.2 mm of the truth (r_position = 0.2^2), while the speckle-tracked
        velocity is either the needle's or 0, the static speckle around the tip competing
        with the needle (r_velocity = 2^2, so that the tip positions carry the velocity).
    p0_angle_rate, p0_velocity : float
        Initial variances of the angular rates (rad^2/s^2) and tip velocity (mm^2/s^2); Zhao
        starts the rates at zero.

    Chatelain 2013
    --------------
    insertion : InsertionParams
        Insertion detection (II-B): variance threshold tau and distance delta (to the sector's
        boundary). tau = 110 mm^2 separates, on Zhao volumes, a moving needle (at most 75
        mm^2) from a static needle-free volume (at least 167 mm^2) with 100 candidates.
    insertion_candidates_mm3 : float or None
        Size of the candidate set of eq. (1) as a volume (2.7 mm^3: the 100 voxels of a
        128^3 volume, which best separated the two cases above); None keeps
        ``insertion.n_candidates``.
    n_control_points : int
        n of eq. (3): 2 for a straight needle, 3 for a flexible one.
    voi_radius_mm, voi_margin_mm : float
        VOI: voxels closer than the radius to the predicted curve, extended by the margin
        beyond both ends (the tip moves 0.6 mm per volume at 3 mm/s and 5 volumes/s).
    voi_candidates_mm3 : float
        Fixed size of the candidate set of eq. (15) (as eq. (1)), given as the volume of the
        voxels so that it means the same at every voxel size: 10 mm^3 is about 11 mm of a
        0.5-mm-radius needle (400 voxels of a 128^3 Zhao volume).
    init_voi_radius_mm : float
        Radius of the ball around the detected change in which the needle is first fitted.
    max_angle_deg : float
        alpha_0 of eq. (22).
    detection_window : int
        Volumes after a detection during which the needle is looked for.
    start_length_mm : float
        Chatelain II-A: "the tracking algorithm then only starts when the needle has been
        inserted with a sufficient length"; the paper gives no figure. Ours: 5 mm visible
        (``min_length_mm`` still applies while tracking). A 3 mm piece fixes no direction:
        with the elongated cross-section a needle shows where it crosses the volume's face,
        a learned model's 3 mm first fit lay along that face (servo, seed 2: the axis came
        out reversed, the tip sat on the entry and the probe chased it, P-hat RMSE 25 mm;
        with 5 mm, 0.8 mm).
    start_min_likelihood : float
        For learned features: Chatelain's tracker starts only on a needle whose likelihood
        along the fitted axis (median, as ``likelihood_relative``) reaches this level; 0: no
        floor. In the moving phantom (servo, motion run) tissue moving near the volume's face
        passes the insertion detector on the map's change: on seeds 2 and 3 the tracker
        started on such structures 20-23 mm from the tip, while the needle was out of the
        volume, with medians of 0.03-0.11 (the needle's own starts on seeds 0, 2 and 3:
        0.56-0.62). P-hat RMSE on seeds 0-6 without the floor 0.61, 0.30, 12.3, 7.2, 0.70,
        11.4, 0.48 mm; with 0.25: 0.61, 0.30, 0.27, 0.35, 0.70, 11.4, 0.48 mm (seed 5 started on
        the needle while its tip was outside the volume: ``start_tip_margin_mm``).
        Not used by roi-rk's initialisation: at Zhao's CR 2.0 a needle's median can be 0.1-0.2,
        and a floor of 0.2 there moved the learned roi-rk's failures on 18 training backgrounds
        (Table 3 protocol, seeds from 6,000,000, 7,000,000 and 8,000,000) from 38 / 8% to
        43 / 3% at CR 2.0 / 2.5.
    start_tip_margin_mm : float
        Chatelain's tracker starts only on a needle whose tip is at least this far inside the
        sector, measured along the needle (0: no test). Chatelain tracks a needle inserted
        into the volume; a needle that runs on out of the volume shows its exit, not its tip,
        and a tracker started there follows the exit. In the moving phantom (servo, motion
        run, seed 5) the tissue's motion carried the tip out of the volume before 5 mm were
        in (4.86 mm at the last volume), and 16 volumes later the learned tracker started on
        the needle crossing the volume, its "tip" on the face: P-hat RMSE 11.4 mm; with the
        margin it waited until the tip was back in view, 0.43 mm. The boundary is where the
        ray leaves the sector for 1 mm (``_run_out_distance``): measured to the first zero
        voxel, dark speckle refused a correct start (classical, misalignment run, seed 1, "0.6
        mm from the boundary"). A fit oriented backwards has its "tip" on the entry's face
        and is refused too. Ours: 1.5 mm, beyond the tip cap (0.6 mm) and a voxel: a needle
        cut by the boundary is refused, a real tip waits a volume or two.
    start_min_contrast : float
        For classical features: Chatelain's tracker starts only on a needle whose image is
        at least this many times the tissue 2-3 mm around it (median along the fit of the
        cross-section's mean over the ring's; 0: no test). The insertion detector fires on
        any change, and a moving phantom changes everywhere: on the motion run's seed 5,
        with the needle out of the volume, the classical tracker started on a 25-inlier line
        of tissue along the volume's deep face and the probe followed it (P-hat RMSE 25.5
        mm). Its ratio was 1.45; the needle's own starts on seeds 0-6 of both runs
        2.51-5.17. Ours: 1.8, between the two. A needle fainter than that next to its tissue
        is not started on; lower it (or 0) for such data. The learned tracker has
        ``start_min_likelihood``.
    q_control, r_control : float
        Noise of the constant-velocity model of eqs. (4)-(9) (mm^2/s^3, mm^2); q allows the
        velocity reversal of a withdrawal within a volume or two.
    p0_control_velocity : float
        Initial variance of the control-point velocities (mm^2/s^2).
    max_coast_volumes : int
        Volumes without a measurement (reported ``lost``) before the Kalman state is dropped
        and the tracker waits for a new insertion.

    Common
    ------
    default_dt_s : float
        Time step used when timestamps do not advance.
    """

    threshold_percentile: float = 99.0
    intensity_threshold: float | None = None  # Zhao Table 3: a fixed gray level, 0-255
    percentile_stride: int = 2
    inlier_radius_mm: float = 0.75
    min_sample_distance_mm: float = 2.0
    max_trials: int = 50
    init_max_trials: int = 1000
    init_attempts: int = 5
    entry_margin_mm: float = 5.0
    success_probability: float = 0.99
    batch_size: int = 16
    refine_iterations: int = 2
    min_inliers: int = 10
    min_length_mm: float = 3.0
    max_gap_mm: float = 1.0
    profile_radius_mm: float = 0.25
    tip_cap_mm: float = 0.6
    likelihood_threshold: float = 0.5
    likelihood_floor: float = 0.05
    likelihood_relative: float | None = 0.5
    max_candidates: int = 20_000
    tip_window_mm: float = 0.0
    tip_min: float = 0.3
    init_select: str = "likelihood"
    init_select_ratio: float = 1.2
    image_refine: bool = True
    image_refine_radii_mm: tuple[float, ...] = (1.5, 1.0, 0.75)
    image_refine_percentile: float = 70.0
    image_refine_keep_depth: bool = True
    image_tip_radius_mm: float = 0.5
    image_tip_window_mm: float = 4.0
    image_tip_search_mm: float = 8.0
    image_tip_track_search_mm: float = 6.0
    image_tip_cap_mm: float = 0.35
    image_tip_min_effect: float = 1.5
    image_tip_background_mm: tuple[float, float] | None = (2.0, 3.0)
    # roi-rk
    roi_radius_mm: float = 2.5
    max_axis_jump_deg: float = 15.0
    max_axis_shift_mm: float = 2.5
    frangi: FrangiParams = FrangiParams()
    speckle_kernel_mm: float = 1.5
    speckle_search_mm: float = 2.0
    q_angle: float = 1e-3
    q_tip: float = 1.0
    r_angle: float = math.radians(1.0) ** 2
    r_position: float = 0.04
    r_velocity: float = 4.0
    p0_angle_rate: float = math.radians(5.0) ** 2
    p0_velocity: float = 25.0
    # chatelain
    insertion: InsertionParams = InsertionParams(n_candidates=100, variance_threshold_mm2=110.0,
                                                 distance_threshold_mm=15.0)
    insertion_candidates_mm3: float | None = 2.7
    n_control_points: int = 2
    voi_radius_mm: float = 3.0
    voi_margin_mm: float = 5.0
    voi_candidates_mm3: float = 10.0
    init_voi_radius_mm: float = 20.0
    max_angle_deg: float = 10.0
    detection_window: int = 10
    start_length_mm: float = 5.0
    start_min_likelihood: float = 0.25
    start_tip_margin_mm: float = 1.5
    start_min_contrast: float = 1.8
    q_control: float = 50.0
    r_control: float = 0.25
    p0_control_velocity: float = 100.0
    max_coast_volumes: int = 2
    default_dt_s: float = 1.0

    def __post_init__(self):
        positive = ("inlier_radius_mm", "min_length_mm", "start_length_mm",
                    "profile_radius_mm", "roi_radius_mm", "max_axis_jump_deg",
                    "max_axis_shift_mm", "speckle_kernel_mm", "q_angle",
                    "q_tip", "r_angle", "r_position", "r_velocity", "p0_angle_rate",
                    "p0_velocity", "voi_radius_mm", "voi_candidates_mm3", "init_voi_radius_mm",
                    "max_angle_deg", "q_control", "r_control", "p0_control_velocity",
                    "default_dt_s", "image_tip_radius_mm", "image_tip_window_mm",
                    "image_tip_search_mm", "image_tip_min_effect", "init_select_ratio",
                    "image_tip_track_search_mm")
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"VolumeTrackerParams.{name} must be finite and > 0, "
                                 f"got {value}")
        for name in ("min_sample_distance_mm", "max_gap_mm", "speckle_search_mm",
                     "voi_margin_mm", "tip_cap_mm", "entry_margin_mm", "tip_window_mm",
                     "image_tip_cap_mm", "start_min_likelihood", "start_tip_margin_mm",
                     "start_min_contrast"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"VolumeTrackerParams.{name} must be finite and >= 0, "
                                 f"got {value}")
        radii = self.image_refine_radii_mm
        if not (isinstance(radii, tuple) and all(
                isinstance(r, (int, float)) and np.isfinite(r) and r > 0 for r in radii)):
            raise ValueError(f"VolumeTrackerParams.image_refine_radii_mm must be a tuple of "
                             f"finite radii > 0 (mm), got {radii!r}")
        if not 0.0 <= self.image_refine_percentile < 100.0:
            raise ValueError(f"image_refine_percentile must be in [0, 100), "
                             f"got {self.image_refine_percentile}")
        if not 0.0 < self.threshold_percentile < 100.0:
            raise ValueError(f"threshold_percentile must be in (0, 100), "
                             f"got {self.threshold_percentile}")
        if not 0.0 <= self.success_probability < 1.0:
            raise ValueError(f"success_probability must be in [0, 1), "
                             f"got {self.success_probability}")
        for name, low in (("percentile_stride", 1), ("max_trials", 1), ("init_max_trials", 1),
                          ("init_attempts", 1), ("batch_size", 1), ("refine_iterations", 0),
                          ("min_inliers", 2), ("max_candidates", 2), ("detection_window", 1),
                          ("max_coast_volumes", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < low:
                raise ValueError(f"VolumeTrackerParams.{name} must be an integer >= {low}, "
                                 f"got {value!r}")
        if self.insertion_candidates_mm3 is not None and not (
                np.isfinite(self.insertion_candidates_mm3) and self.insertion_candidates_mm3 > 0):
            raise ValueError(f"insertion_candidates_mm3 must be None or finite and > 0, "
                             f"got {self.insertion_candidates_mm3}")
        ring = self.image_tip_background_mm
        if ring is not None and not (
                isinstance(ring, tuple) and len(ring) == 2
                and all(isinstance(r, (int, float)) and np.isfinite(r) for r in ring)
                and 0.0 < ring[0] < ring[1]):
            raise ValueError(f"VolumeTrackerParams.image_tip_background_mm must be None or "
                             f"(inner, outer) radii in mm with 0 < inner < outer, got {ring!r}")
        if self.init_select not in ("support", "likelihood"):
            raise ValueError(f"init_select must be 'support' or 'likelihood', "
                             f"got {self.init_select!r}")
        if self.n_control_points not in (2, 3):
            raise ValueError(f"n_control_points must be 2 or 3, got {self.n_control_points!r}")
        if not 0.0 < self.likelihood_floor <= self.likelihood_threshold < 1.0:
            raise ValueError("need 0 < likelihood_floor <= likelihood_threshold < 1")


# --------------------------------------------------------------------------------------------
# Geometry on the frame's grid
# --------------------------------------------------------------------------------------------


class _Volume:
    """One volume with what every method needs: the feature map, the sector, mm conversions."""

    def __init__(self, frame: Frame, likelihood: Likelihood, learned: bool):
        self.image = np.asarray(frame.image)
        self.grid = frame.grid
        self.spacing = np.asarray(self.grid.spacing_mm, float)  # array order
        self.origin = np.asarray(self.grid.origin_mm, float)
        self.shape = np.asarray(self.grid.shape)
        self.values = np.asarray(likelihood.shaft, dtype=np.float32)
        # a learned source's tip channel (None for classical features)
        tip = getattr(likelihood, "tip", None)
        self.tip = (np.asarray(tip, dtype=np.float32)
                    if learned and tip is not None and np.shape(tip) == self.values.shape
                    else None)
        self.learned = learned
        self.sector = self.image > 0  # scan-converted volumes are 0 outside the sector

    def points(self, flat_index: np.ndarray) -> np.ndarray:
        """Voxel centres (N, 3) in mm, point order, of flat indices."""
        idx = np.stack(np.unravel_index(flat_index, self.grid.shape), axis=-1)
        return (self.origin + idx * self.spacing)[:, ::-1]

    def to_index(self, points_mm: np.ndarray) -> np.ndarray:
        """Fractional array indices (..., 3) of points (..., 3) in mm, point order."""
        return (np.asarray(points_mm, float)[..., ::-1] - self.origin) / self.spacing

    def sample(self, array: np.ndarray, points_mm: np.ndarray, order: int = 1,
               output=None) -> np.ndarray:
        """Values of ``array`` at points (..., 3) in mm; 0 outside the volume. ``output``: the
        values' dtype (e.g. float32 for a uint8 image, interpolated without rounding and
        without converting the whole array first); the array's own when None."""
        pts = np.asarray(points_mm, float)
        idx = self.to_index(pts.reshape(-1, 3))
        out = ndimage.map_coordinates(array, idx.T, output=output, order=order,
                                      mode="constant", cval=0.0)
        return out.reshape(pts.shape[:-1])


def _count(volume_mm3: float, vol: _Volume, minimum: int) -> int:
    """Number of voxels that make up ``volume_mm3`` (at least ``minimum``)."""
    return max(int(minimum), round(volume_mm3 / float(np.prod(vol.spacing))))


def _threshold(vol: _Volume, p: VolumeTrackerParams) -> float:
    """T_I of eq. (B1): the ``threshold_percentile`` of the feature over the sector, or the
    fixed gray level ``intensity_threshold`` (Zhao Table 3) on [0, 1] features."""
    if p.intensity_threshold is not None:
        return float(p.intensity_threshold) / 255.0
    s = p.percentile_stride
    sub = vol.values[::s, ::s, ::s][vol.sector[::s, ::s, ::s]]
    if sub.size == 0:
        return math.inf
    return float(np.percentile(sub, p.threshold_percentile))


def _cylinder(vol: _Volume, point_mm, direction, radius_mm: float,
              t_range: tuple[float, float] = (-math.inf, math.inf)) -> np.ndarray:
    """Flat indices of the sector voxels within ``radius_mm`` of a line (Zhao eq. (1)).

    The line is ``point + t * direction`` (mm, point order), restricted to ``t_range``. The
    volume is walked one slice at a time along the axis the line crosses fastest; in each
    slice only a window around the crossing, the bounding box of the cylinder's elliptic
    section, is tested, so the cost is that of the cylinder, not of the volume.
    """
    p = np.asarray(point_mm, float)[::-1]  # array order
    u = np.asarray(direction, float)[::-1]
    u = u / np.linalg.norm(u)
    sp, org, shape = vol.spacing, vol.origin, vol.shape
    a = int(np.argmax(np.abs(u)))
    b, c = (ax for ax in range(3) if ax != a)
    coord_a = org[a] + np.arange(shape[a]) * sp[a]
    t = (coord_a - p[a]) / u[a]
    lo, hi = t_range
    slack = 2.0 * radius_mm  # a slice holds points whose t differs from its crossing by < sqrt(2) R
    k = np.flatnonzero((t >= lo - slack) & (t <= hi + slack))
    if k.size == 0:
        return np.zeros(0, np.int64)
    centre = p + t[k, None] * u  # (K, 3) crossing points
    # Half-widths of the section along b and c: R sqrt(u_a^2 + u_x^2) / |u_a|.
    half = radius_mm * np.sqrt(u[a] ** 2 + u[[b, c]] ** 2) / abs(u[a])
    wb, wc = (np.ceil(half / sp[[b, c]]).astype(int) + 1)
    ib = np.rint((centre[:, b] - org[b]) / sp[b]).astype(np.int64)[:, None, None] + \
        np.arange(-wb, wb + 1)[None, :, None]
    ic = np.rint((centre[:, c] - org[c]) / sp[c]).astype(np.int64)[:, None, None] + \
        np.arange(-wc, wc + 1)[None, None, :]
    ia = k[:, None, None]
    ib, ic, ia = np.broadcast_arrays(ib, ic, ia)
    d_a = org[a] + ia * sp[a] - p[a]
    d_b = org[b] + ib * sp[b] - p[b]
    d_c = org[c] + ic * sp[c] - p[c]
    tt = d_a * u[a] + d_b * u[b] + d_c * u[c]
    dist2 = d_a**2 + d_b**2 + d_c**2 - tt**2
    keep = ((dist2 <= radius_mm**2) & (tt >= lo) & (tt <= hi)
            & (ib >= 0) & (ib < shape[b]) & (ic >= 0) & (ic < shape[c]))
    index = np.zeros((3, int(keep.sum())), np.int64)
    index[a], index[b], index[c] = ia[keep], ib[keep], ic[keep]
    flat = np.ravel_multi_index(tuple(index), vol.grid.shape)
    return flat[vol.sector.reshape(-1)[flat]]


def _ball(vol: _Volume, centre_mm, radius_mm: float) -> np.ndarray:
    """Flat indices of the sector voxels within ``radius_mm`` of a point."""
    c = vol.to_index(np.asarray(centre_mm, float))
    half = radius_mm / vol.spacing
    lo = np.maximum(np.floor(c - half), 0).astype(int)
    hi = np.minimum(np.ceil(c + half) + 1, vol.shape).astype(int)
    if np.any(hi <= lo):
        return np.zeros(0, np.int64)
    axes = [np.arange(lo[i], hi[i]) for i in range(3)]
    d = [((axes[i] - c[i]) * vol.spacing[i]) ** 2 for i in range(3)]
    inside = d[0][:, None, None] + d[1][None, :, None] + d[2][None, None, :] <= radius_mm**2
    idx = np.nonzero(inside)
    flat = np.ravel_multi_index(tuple(idx[i] + lo[i] for i in range(3)), vol.grid.shape)
    return flat[vol.sector.reshape(-1)[flat]]


# --------------------------------------------------------------------------------------------
# One measurement: candidates -> RANSAC -> axis -> tip
# --------------------------------------------------------------------------------------------


@dataclass
class _Measurement:
    """A needle found in one volume (mm, point order)."""

    ok: bool
    reason: str | None = None
    model: LineModel | PolyCurveModel | None = None
    entry: np.ndarray | None = None  # where the visible needle starts on the axis
    tip: np.ndarray | None = None
    direction: np.ndarray | None = None  # unit, entry -> tip
    inliers: int = 0
    trials: int = 0
    roi_voxels: int = 0
    a_entry: float = math.nan
    a_tip: float = math.nan
    entry_gap_mm: float = math.nan  # from the visible entry back to the sector's boundary


def _fail(reason: str, trials: int = 0, roi_voxels: int = 0, inliers: int = 0) -> _Measurement:
    return _Measurement(False, reason, trials=trials, roi_voxels=roi_voxels, inliers=inliers)


def _candidates(vol: _Volume, region: np.ndarray | None, threshold: float,
                p: VolumeTrackerParams, fixed_size: int | None = None):
    """Candidate voxels and their RANSAC weights.

    Classical features: voxels at or above ``threshold`` (eq. (B1)), or the ``fixed_size``
    brightest (Chatelain eq. (15)); unweighted. Learned features: voxels above the
    likelihood floor, the most likely first, weighted by their likelihood.
    """
    if region is None:
        flat_values = vol.values.reshape(-1)
        in_sector = vol.sector.reshape(-1)
        if vol.learned:
            region = np.flatnonzero((flat_values >= p.likelihood_floor) & in_sector)
        elif fixed_size is None:
            region = np.flatnonzero((flat_values >= threshold) & in_sector)
        else:
            region = np.flatnonzero(in_sector)
    values = vol.values.reshape(-1)[region]
    if vol.learned:
        keep = values >= p.likelihood_floor
        region, values = region[keep], values[keep]
        n = min(p.max_candidates if fixed_size is None else fixed_size, region.size)
        if n < region.size:
            top = np.argpartition(values, region.size - n)[region.size - n:]
            region, values = region[top], values[top]
        return region, values.astype(float)
    if fixed_size is not None:  # Chatelain eq. (15): the fixed_size brightest voxels
        n = min(fixed_size, region.size)
        top = np.argpartition(values, region.size - n)[region.size - n:] if n else []
        region = region[top]
        values = values[top]
        region = region[values > 0]
        return region, None
    return region[values >= threshold], None


def _main_piece(a: np.ndarray, gap: float) -> tuple[float, float, int]:
    """The longest run (by count) of sorted coordinates ``a`` without a gap above ``gap``."""
    s = np.sort(a)
    breaks = np.flatnonzero(np.diff(s) > gap)
    starts = np.r_[0, breaks + 1]
    ends = np.r_[breaks, s.size - 1]
    counts = ends - starts + 1
    j = int(np.argmax(counts))
    return float(s[starts[j]]), float(s[ends[j]]), int(counts[j])


def _needle_run(profile, a_values, level: float, max_gap: float, a0: float,
                a1: float) -> int | None:
    """Index of the first sample of the run of the profile that overlaps [a0, a1] most.

    Runs are the samples at or above ``level``, joined across gaps shorter than ``max_gap``
    (as :func:`tip_along_axis` joins them); None when no sample reaches the level.
    """
    above = np.greater_equal(profile, level, where=np.isfinite(profile),
                             out=np.zeros(profile.shape, bool))
    on = np.flatnonzero(above)
    if on.size == 0:
        return None
    gap = a_values[on[1:]] - a_values[on[:-1] + 1]  # first sample below to next above
    split = np.flatnonzero((np.diff(on) > 1) & (gap >= max_gap))
    starts = on[np.r_[0, split + 1]]
    ends = on[np.r_[split, on.size - 1]]
    overlap = np.minimum(a_values[ends], a1) - np.maximum(a_values[starts], a0)
    length = a_values[ends] - a_values[starts]
    best = np.lexsort((-length, -overlap))[0]  # most overlap, then longest
    return int(starts[best])


def _perpendiculars(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``u`` and to each other."""
    helper = np.eye(3)[int(np.argmin(np.abs(u)))]
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


def _profile(vol: _Volume, model, a_values: np.ndarray, radius_mm: float,
             array: np.ndarray | None = None) -> np.ndarray:
    """Feature (or ``array``, e.g. a tip map) along the axis: the maximum over the centre
    line and six parallel lines.

    A maximum over the needle's cross-section: the needle is there if any of its voxels is
    bright, which keeps the profile above the threshold where single needle voxels are dark
    (Zhao's needle voxels are drawn independently) or the axis is a fraction of a voxel off.
    """
    pts = _cross_section(model, a_values, radius_mm)
    return vol.sample(vol.values if array is None else array, pts).max(axis=0)


def _cross_section(model, a_values: np.ndarray, radius_mm: float) -> np.ndarray:
    """Points (7, K, 3) of the axis and of six lines ``radius_mm`` around it at ``a_values``."""
    e1, e2 = _perpendiculars(model.principal_direction)
    offsets = radius_mm * (_PROFILE_OFFSETS[:, :1] * e1 + _PROFILE_OFFSETS[:, 1:] * e2)
    return model.points_at(a_values)[None, :, :] + offsets[:, None, :]


def _median_profile(vol: _Volume, model, a0: float, a1: float,
                    p: VolumeTrackerParams) -> float:
    """The median of the map along the axis from ``a0`` to ``a1`` (as :func:`_profile`)."""
    step = 0.5 * float(vol.spacing.min())
    a = np.arange(a0, a1 + step, step)
    if a.size == 0:
        return 0.0
    return float(np.median(_profile(vol, model, a, p.profile_radius_mm)))


def _first_run_out(inside: np.ndarray, n: int) -> np.ndarray:
    """Per ray (rows of ``inside``, (..., S) samples along each): the index of the first
    sample from which the ray stays outside the sector for ``n`` samples (samples past the
    end count as outside, so a ray still inside at its end gives ``S``)."""
    inside = np.asarray(inside, bool)
    S = inside.shape[-1]
    out = np.concatenate([(~inside).astype(np.int32),
                          np.ones(inside.shape[:-1] + (n,), np.int32)], axis=-1)
    c = np.concatenate([np.zeros(inside.shape[:-1] + (1,), np.int64),
                        np.cumsum(out, axis=-1)], axis=-1)
    run = (c[..., n:n + S] - c[..., :S]) == n  # samples i .. i + n - 1 all outside
    return np.where(run.any(axis=-1), np.argmax(run, axis=-1), S)


def _ray_step(vol: _Volume) -> float:
    """Sample spacing along the rays that look for the sector's boundary (mm)."""
    return 0.25 * float(vol.spacing.min())


def _sector_run_out(vol: _Volume, pts: np.ndarray) -> np.ndarray:
    """Per ray of samples ``pts`` (..., S, 3) spaced :func:`_ray_step` apart: the index of the
    sample where it leaves the sector for good, staying outside for ``_RUN_OUT_MM``
    (:func:`_first_run_out`; ``S`` when it does not).

    Not the first zero voxel: scan-converted volumes are 0 outside the sector, but dark
    speckle inside it is 0 too (a tenth of a Cartesian volume's voxels in the servo's phantom,
    mostly alone or in small clusters; 0.08% in the synth sector volumes), and a first-zero
    test ends the sector at the first of them."""
    inside = vol.sample(vol.sector.view(np.uint8), pts, order=0) > 0
    return _first_run_out(inside, max(int(round(_RUN_OUT_MM / _ray_step(vol))), 1))


def _run_out_distance(vol: _Volume, point, u, max_mm: float) -> float:
    """Distance from ``point`` along ``u`` to the sector's boundary (:func:`_sector_run_out`;
    outside the array counts as outside); ``max_mm`` when it is not within that distance."""
    step = _ray_step(vol)
    s = np.arange(1, int((max_mm + _RUN_OUT_MM) / step) + 1) * step
    first = int(_sector_run_out(vol, point + s[:, None] * u))
    return float(min(s[first], max_mm)) if first < s.size else max_mm


def _measure(vol: _Volume, region: np.ndarray | None, threshold: float,
             p: VolumeTrackerParams, rng, *, max_trials: int, predicted_direction=None,
             max_angle_deg: float | None = None, fixed_size: int | None = None,
             model: str = "line", tip_hint=None, predicted_tip=None) -> _Measurement:
    """One localisation: candidates -> RANSAC -> least squares -> oriented axis -> tip.

    ``region``: flat indices of the ROI/VOI (None: the whole sector); ``threshold``: T_I of
    eq. (B1) (for learned features the likelihood threshold is used instead);
    ``fixed_size``: take that many brightest voxels instead (Chatelain eq. (15));
    ``predicted_direction``: orients the axis (and, with ``max_angle_deg``, constrains it,
    Chatelain eq. (22)). Without it, the tip is the end of the needle nearer to
    ``tip_hint`` when that point projects clearly off the needle's middle, and otherwise the
    entry is the end nearer to the sector's boundary. ``predicted_tip`` (mm): while tracking,
    where the image's tip is looked for with learned features (:func:`_image_tip`).
    """
    roi_voxels = 0 if region is None else int(region.size)
    cand, weights = _candidates(vol, region, threshold, p, fixed_size)
    pts = vol.points(cand)
    r_in = p.inlier_radius_mm
    if len(pts) < p.min_inliers:
        return _fail(f"too few candidates: {len(pts)} < {p.min_inliers}", 0, roi_voxels)
    res: RansacResult = ransac(
        pts, model, residual_threshold=r_in, weights=weights,
        min_sample_distance=p.min_sample_distance_mm,
        predicted_direction=predicted_direction, max_angle_deg=max_angle_deg,
        success_probability=p.success_probability, max_trials=max_trials,
        batch_size=p.batch_size, order=p.n_control_points,
        refine_iterations=p.refine_iterations, rng=rng)  # Zhao App. B, Chatelain II-D
    if not res:
        return _fail(f"RANSAC: {res.reason}", res.n_trials, roi_voxels)
    fitted = res.model
    a = fitted.parameter(pts[res.inliers])
    a0, a1, n_in = _main_piece(a, p.max_gap_mm)  # the needle: the largest piece of inliers
    if n_in < p.min_inliers:
        return _fail(f"too few inliers: {n_in} < {p.min_inliers}", res.n_trials, roi_voxels,
                     n_in)
    if predicted_direction is None:
        u = fitted.principal_direction
        flip = None
        if tip_hint is not None and a1 > a0:
            f = (float(fitted.parameter(np.asarray(tip_hint, float)[None])[0]) - a0) / (a1 - a0)
            if abs(f - 0.5) > _HINT_MARGIN:
                flip = f < 0.5
        if flip is None:
            # The needle comes in through the sector's boundary, so its entry is the end of
            # the inliers nearer to the boundary along the axis.
            far = float(np.linalg.norm(vol.spacing * vol.shape))
            to_lo = _run_out_distance(vol, fitted.points_at(np.array([a0]))[0], -u, far)
            to_hi = _run_out_distance(vol, fitted.points_at(np.array([a1]))[0], u, far)
            flip = to_hi < to_lo
        if flip:
            fitted = fitted.oriented(-u)
            a0, a1, n_in = _main_piece(fitted.parameter(pts[res.inliers]), p.max_gap_mm)
    level = threshold
    if vol.learned:
        level = p.likelihood_threshold
        if p.likelihood_relative is not None:
            # the needle's own likelihood sets the level (a half-maximum): a learned map's
            # absolute scale varies with the contrast and the scanner, its drop at the tip
            # does not
            level = max(p.likelihood_floor,
                        p.likelihood_relative * _median_profile(vol, fitted, a0, a1, p))
    found = _locate(vol, fitted, a0, a1, level, p, r_in)
    if found is None:
        return _fail("no sample of the axis reaches the threshold", res.n_trials, roi_voxels,
                     n_in)
    # Local optimisation on the needle itself: least squares on the inliers between the entry
    # and the tip (Zhao App. B minimises eq. (B6) over the inliers; the inliers beyond the
    # needle's ends, along the infinite line, are background).
    a_entry, a_drop = found
    on_needle = res.inliers & _between(fitted.parameter(pts), a_entry - r_in, a_drop + r_in)
    if np.count_nonzero(on_needle) >= p.min_inliers:
        w = None if weights is None else weights[on_needle]
        try:
            refit = (LineModel.from_inliers(pts[on_needle], w) if model == "line"
                     else PolyCurveModel.from_inliers(pts[on_needle], w, order=fitted.order))
        except ValueError:
            refit = None
        if refit is not None:
            refit = refit.oriented(fitted.principal_direction)
            a_refit = refit.parameter(pts[on_needle])
            again = _locate(vol, refit, float(a_refit.min()), float(a_refit.max()), level, p,
                            r_in)
            if again is not None:
                fitted, (a_entry, a_drop) = refit, again
    if vol.learned and p.image_refine:
        # the learned map found the needle; the image places its axis and its tip
        if model == "line":
            fitted, a_entry, a_drop = _refine_on_image(vol, fitted, a_entry, a_drop, p)
        predicted = None
        if predicted_tip is not None:
            predicted = float(fitted.parameter(np.asarray(predicted_tip, float)[None])[0])
        a_tip = _image_tip(vol, fitted, a_entry, a_drop, p, predicted)
    else:
        a_tip = a_drop - p.tip_cap_mm  # the image of the needle ends one cap beyond its tip
    if vol.tip is not None and p.tip_window_mm > 0:
        a_tip = _tip_on_map(vol, fitted, a_entry, a_tip, p)
    length = a_tip - a_entry
    if length < p.min_length_mm:
        return _fail(f"needle too short: {length:.2f} mm < {p.min_length_mm} mm", res.n_trials,
                     roi_voxels, n_in)
    entry, tip = fitted.points_at(np.array([a_entry, a_tip]))
    direction = (tip - entry) / np.linalg.norm(tip - entry)
    n_inliers = int(np.count_nonzero(fitted.residuals(pts) < r_in))
    far = float(np.linalg.norm(vol.spacing * vol.shape))
    gap = _run_out_distance(vol, entry, -direction, far)
    return _Measurement(True, None, fitted, entry, tip, direction, n_inliers, res.n_trials,
                        roi_voxels, a_entry, a_tip, gap)


def _refine_on_image(vol: _Volume, fitted: LineModel, a_entry: float, a_drop: float,
                     p: VolumeTrackerParams) -> tuple[LineModel, float, float]:
    """A straight axis refitted on the image in narrowing tubes around ``fitted`` between the
    entry and the drop (1 mm beyond each): weighted total least squares of the voxels above
    the tube's ``image_refine_percentile``, each weighted by its excess (Zhao App. B's local
    optimisation, on the image's needle voxels). Returns the axis, oriented as ``fitted``,
    with the entry and the drop carried onto it; ``fitted`` unchanged when a tube holds
    too few voxels above the level (``min_inliers``)."""
    u = fitted.principal_direction
    entry_pt, drop_pt = fitted.points_at(np.array([a_entry, a_drop]))
    image = vol.image.reshape(-1)
    model = fitted
    for radius in p.image_refine_radii_mm:
        start = model.points_at(np.array([model.parameter(entry_pt[None])[0]]))[0]
        length = float(model.parameter(drop_pt[None])[0] - model.parameter(entry_pt[None])[0])
        idx = _cylinder(vol, start, model.principal_direction, float(radius),
                        (-1.0, length + 1.0))
        if idx.size < p.min_inliers:
            break
        values = image[idx].astype(float)
        w = np.maximum(values - np.percentile(values, p.image_refine_percentile), 0.0)
        if np.count_nonzero(w) < p.min_inliers:
            break
        model = LineModel.from_inliers(vol.points(idx), w).oriented(u)
    if model is not fitted and p.image_refine_keep_depth:
        v = model.principal_direction
        mid = 0.5 * (entry_pt + drop_pt)
        gap = mid - model.points_at(model.parameter(mid[None]))[0]  # map axis - image axis
        depth = np.array([0.0, 0.0, 1.0]) - v[2] * v
        if np.linalg.norm(depth) > 1e-6:
            depth /= np.linalg.norm(depth)
            model = LineModel(model.origin + (gap @ depth) * depth, v)
    a = model.parameter(np.stack([entry_pt, drop_pt]))
    return model, float(a[0]), float(a[1])


def _image_tip(vol: _Volume, fitted, a_entry: float, a_drop: float,
               p: VolumeTrackerParams, predicted: float | None = None) -> float:
    """The tip along the axis from the image: the change point of the image's profile along
    the axis (at each position the mean over the axis and six lines ``image_tip_radius_mm``
    around it, less the tissue's mean on a ring around the needle, ``image_tip_background_mm``;
    :func:`_axis_change`), the position within ``image_tip_search_mm`` of the likelihood's drop
    ``a_drop`` (while tracking, within ``image_tip_track_search_mm`` of the filter's predicted
    tip, ``predicted``; and at least one window beyond the entry) that maximises the mean of the
    profile over ``image_tip_window_mm`` behind it minus the mean over the same length ahead,
    less ``image_tip_cap_mm``.

    The change stands only when it is clear: the step is at least ``image_tip_min_effect``
    times the pooled standard deviation of the profile within the two windows. Otherwise,
    or when no position has a quarter of a window of profile inside the sector on each side,
    the likelihood's drop less ``tip_cap_mm`` is the tip: a map that sees a needle the image
    does not show keeps its own tip."""
    fallback = a_drop - p.tip_cap_mm
    step = 0.5 * float(vol.spacing.min())
    w = max(1, int(round(p.image_tip_window_mm / step)))
    middle, search = a_drop, p.image_tip_search_mm
    if predicted is not None:  # tracking: the filter's predicted tip is the better prior
        middle, search = predicted, p.image_tip_track_search_mm
    lo = max(middle - search, a_entry + p.image_tip_window_mm)
    hi = middle + search
    if hi <= lo:
        return fallback
    a = np.arange(lo - w * step, hi + (w + 1) * step, step)
    found = _axis_change(vol, fitted, a, w, p)
    if found is None:
        return fallback
    k, effect = found
    if not effect >= p.image_tip_min_effect:
        return fallback
    boundary = a[k] - 0.5 * step  # between samples k - 1 and k
    return float(boundary) - p.image_tip_cap_mm


def _axis_change(vol: _Volume, fitted, a: np.ndarray, w: int,
                 p: VolumeTrackerParams) -> tuple[int, float] | None:
    """The largest drop of the image's profile along the axis at ``a`` (mm, evenly spaced):
    ``(k, effect)``, the drop between samples ``k - 1`` and ``k`` of the mean over the ``w``
    samples behind minus the mean over the ``w`` ahead, and that drop in pooled standard
    deviations of the profile within the two windows. The profile is the mean over the axis
    and six lines ``image_tip_radius_mm`` around it, less (``image_tip_background_mm``) the
    mean over a ring of lines around the needle. None when no boundary has a quarter of a
    window of profile inside the sector on each side."""
    prof, valid = _section_mean(vol, _cross_section(fitted, a, p.image_tip_radius_mm), 1)
    if p.image_tip_background_mm is not None:
        # the needle's excess over the tissue around it: a change of the tissue's brightness
        # along the axis (the tip entering a brighter region) is not the needle's end
        ring, ring_valid = _section_mean(vol, _ring_section(fitted, a, p.image_tip_background_mm),
                                         _RING_MIN_SAMPLES)
        valid &= ring_valid
        prof = np.where(valid, prof - ring, 0.0)

    def csum(x):
        return np.concatenate([[0.0], np.cumsum(x)])

    s1, s2, cnt = csum(prof), csum(prof * prof), csum(valid.astype(float))
    c = np.arange(w, a.size - w + 1)  # boundary before sample c
    nb, na = cnt[c] - cnt[c - w], cnt[c + w] - cnt[c]
    ok = (nb >= max(1.0, 0.25 * w)) & (na >= max(1.0, 0.25 * w))
    if not ok.any():
        return None
    nb_, na_ = np.maximum(nb, 1.0), np.maximum(na, 1.0)
    mb, ma = (s1[c] - s1[c - w]) / nb_, (s1[c + w] - s1[c]) / na_
    change = np.where(ok, mb - ma, -np.inf)
    k = int(np.argmax(change))
    var = ((s2[c[k]] - s2[c[k] - w]) - nb[k] * mb[k] ** 2
           + (s2[c[k] + w] - s2[c[k]]) - na[k] * ma[k] ** 2) / (nb[k] + na[k])
    sd = math.sqrt(max(var, 0.0))
    if sd > 0.0:
        return int(c[k]), float(change[k] / sd)
    return int(c[k]), (math.inf if change[k] > 0 else 0.0)  # a noiseless profile


def _section_mean(vol: _Volume, pts: np.ndarray, min_samples: int):
    """The image's mean over the lines ``pts`` (L, K, 3) at each of the K positions, over the
    samples inside the sector, and where at least ``min_samples`` of them are."""
    values = vol.sample(vol.image, pts, output=np.float32)
    inside = vol.sample(vol.sector.view(np.uint8), pts, order=0) > 0
    n_in = inside.sum(0)
    valid = n_in >= min_samples
    return np.where(valid, np.where(inside, values, 0.0).sum(0) / np.maximum(n_in, 1), 0.0), valid


def _needle_contrast(vol: _Volume, model, a0: float, a1: float,
                    p: VolumeTrackerParams) -> float:
    """The median along the axis from ``a0`` to ``a1`` of the image's mean over the needle's
    cross-section (``image_tip_radius_mm``) over its mean on a ring 2-3 mm around it
    (``_CONTRAST_RING_MM``, ``_ring_section``); NaN-free: 0 where no position has both inside
    the sector."""
    step = 0.5 * float(vol.spacing.min())
    a = np.arange(a0, a1 + step, step)
    core, v1 = _section_mean(vol, _cross_section(model, a, p.image_tip_radius_mm), 1)
    ring, v2 = _section_mean(vol, _ring_section(model, a, _CONTRAST_RING_MM), _RING_MIN_SAMPLES)
    ok = v1 & v2
    if not ok.any():
        return 0.0
    return float(np.median(core[ok] / np.maximum(ring[ok], 1e-3)))


def _ring_section(model, a_values: np.ndarray, radii_mm: tuple[float, float]) -> np.ndarray:
    """Points (L, K, 3) of lines parallel to the axis on a ring around it: ``_RING_ANGLES``
    lines at each of three radii from ``radii_mm[0]`` to ``radii_mm[1]``."""
    e1, e2 = _perpendiculars(model.principal_direction)
    ang = np.arange(_RING_ANGLES) * (2.0 * math.pi / _RING_ANGLES)
    r = np.linspace(radii_mm[0], radii_mm[1], 3)
    rr, aa = (x.ravel() for x in np.meshgrid(r, ang, indexing="ij"))
    offsets = (rr * np.cos(aa))[:, None] * e1 + (rr * np.sin(aa))[:, None] * e2
    return model.points_at(a_values)[None, :, :] + offsets[:, None, :]


def _tip_on_map(vol: _Volume, fitted, a_entry: float, a_tip: float,
                p: VolumeTrackerParams) -> float:
    """The tip along the fitted axis from a learned tip channel: the maximum of the tip map
    (over the needle's cross-section, as :func:`_profile`) within ``tip_window_mm`` of the
    tip where the shaft likelihood drops, refined by a parabola through its neighbours. The
    drop stands when the tip map has no clear peak there (below ``tip_min``)."""
    step = 0.5 * float(vol.spacing.min())
    a = np.arange(max(a_tip - p.tip_window_mm, a_entry), a_tip + p.tip_window_mm + step, step)
    if a.size < 3:
        return a_tip
    prof = _profile(vol, fitted, a, p.profile_radius_mm, vol.tip)
    k = int(np.argmax(prof))
    if prof[k] < p.tip_min:
        return a_tip
    if 0 < k < a.size - 1:
        y0, y1, y2 = prof[k - 1], prof[k], prof[k + 1]
        den = y0 - 2.0 * y1 + y2
        if den < 0:
            return float(a[k] + 0.5 * step * (y0 - y2) / den)
    return float(a[k])


def _between(a: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (a >= lo) & (a <= hi)


def _locate(vol: _Volume, fitted, a0: float, a1: float, level: float, p: VolumeTrackerParams,
            r_in: float) -> tuple[float, float] | None:
    """Where the needle starts and where its image ends along a fitted axis.

    The profile along the axis is split into runs of samples at or above ``level``, gaps
    shorter than ``max_gap_mm`` bridged (Chatelain II-D: "we discard small intensity gaps");
    the needle is the run that overlaps the inliers [a0, a1] most (a bright structure
    crossing the axis is not). Its end is where the feature "drops below the threshold" for
    good (Zhao App. B), interpolated by :func:`tip_along_axis`.
    """
    step = 0.5 * float(vol.spacing.min())
    span = float(np.linalg.norm(vol.spacing * vol.shape))
    a_values = np.arange(a0 - p.max_gap_mm - 2.0 * r_in, a0 + span, step)
    profile = _profile(vol, fitted, a_values, p.profile_radius_mm)
    run = _needle_run(profile, a_values, level, p.max_gap_mm, a0, a1)
    if run is None:
        return None
    found = tip_along_axis(profile[run:], a_values[run:], level, p.max_gap_mm)
    return float(a_values[run]), float(found.position)


def _angles(u) -> tuple[float, float]:
    beta, alpha = direction_to_angles(np.asarray(u, float))  # Zhao eq. (4)
    return float(beta), float(alpha)


def _wrap(angle: float) -> float:
    """Angle in (-pi, pi]."""
    return float(math.pi - (math.pi - angle) % (2.0 * math.pi))


# --------------------------------------------------------------------------------------------
# The tracker
# --------------------------------------------------------------------------------------------


class VolumeTracker(Tracker):
    """Needle tracking in 3D ultrasound volumes: ``"ransac"``, ``"roi-rk"`` or ``"chatelain"``.

    Parameters
    ----------
    method : {"ransac", "roi-rk", "chatelain"}
        See the module documentation.
    features : FeatureSource, optional
        Default :class:`IntensityFeatures`. A learned source (``kind == "learned"``) turns the
        threshold into likelihood-weighted candidates, replaces the line filter of the roi-rk
        initialisation and the volume differences of the insertion detection.
    params : VolumeTrackerParams, optional
    rng, seed : numpy.random.Generator or int or None
        RANSAC's random generator (``seed`` is an alias of ``rng``, as for every tracker).

    Each :meth:`update` returns a :class:`NeedleEstimate` with the tip (mm, x, y, z), the unit
    direction from the entry to the tip, the tip covariance (mm^2; the Kalman filter's for
    roi-rk and chatelain, ``r_position * I`` for ransac) and extras ``axis_point_mm`` (where
    the visible needle starts on the axis), ``alpha_deg``, ``beta_deg`` (eq. (4)),
    ``inliers``, ``ransac_trials`` (minimal samples drawn, initialisation included),
    ``roi_voxels`` (voxels of the ROI/VOI; 0 for the whole volume), ``measured_tip_mm``
    (the tip before the Kalman filter) and ``reason`` when nothing was measured.

    A learned source must return a new array from each ``likelihood`` call: chatelain keeps
    the previous map for the difference of the next volume.
    """

    modality = "volume"
    methods = ("ransac", "roi-rk", "chatelain")

    def __init__(self, method: str, features: FeatureSource | None = None,
                 params: VolumeTrackerParams | None = None,
                 rng: np.random.Generator | int | None = None, seed: int | None = None):
        self.params = VolumeTrackerParams() if params is None else params
        self._rng = np.random.default_rng(seed if rng is None else rng)
        self._frangi = FrangiFeatures(self.params.frangi)
        super().__init__(method, features)

    # -- state ---------------------------------------------------------------------------

    def reset(self) -> None:
        super().reset()
        self._kf: KalmanFilter | None = None
        self._t_prev: float | None = None
        self._prev_image: np.ndarray | None = None  # roi-rk: speckle tracking
        self._prev_map: np.ndarray | None = None  # chatelain: insertion detection
        self._detector: InsertionDetector | None = None  # made for the first volume's grid
        self._pending: tuple[np.ndarray, int] | None = None  # chatelain: detection, volumes left
        self._misses = 0

    def move_frame(self, D) -> None:
        """Re-express the tracker's state in the probe frame after the probe moved.

        ``D`` (4, 4) is the rigid motion of the probe: new pose = old pose @ D, so a point p
        of the old probe frame is ``inv(D) @ p`` in the new one. The Kalman state follows:
        chatelain's control points (positions transformed, velocities rotated) and roi-rk's
        tip (transformed), tip velocity (rotated) and axis angles (beta, alpha of Zhao eq. (4)
        recomputed from the rotated direction; their rates and covariance carried by the
        Jacobian of that map); the covariance is B P B^T with B that linear map. A pending
        chatelain detection moves with it. What compares two volumes voxel by voxel (roi-rk's
        speckle tracking, chatelain's change map) needs both from the same pose, so a
        non-trivial motion drops the previous volume: the next one starts afresh. ransac keeps
        no state. A bad ``D`` raises ``ValueError``.
        """
        D = np.asarray(D, float)
        if D.shape != (4, 4) or not np.all(np.isfinite(D)):
            raise ValueError(f"move_frame needs a finite 4x4 rigid transform, got shape "
                             f"{D.shape}")
        R0 = D[:3, :3]
        if (not np.allclose(R0.T @ R0, np.eye(3), atol=1e-6) or np.linalg.det(R0) <= 0
                or not np.allclose(D[3], [0.0, 0.0, 0.0, 1.0])):
            raise ValueError("move_frame needs a rigid transform (a rotation and a "
                             "translation, last row 0 0 0 1)")
        if np.allclose(D, np.eye(4), atol=1e-12):
            return
        R = R0.T  # inv(D): p_new = R p_old + t
        t = -R @ D[:3, 3]
        kf = self._kf
        if kf is not None and self.method == "chatelain":
            n3 = len(kf.x) // 2
            n = n3 // 3
            pos = kf.x[:n3].reshape(n, 3) @ R.T + t
            vel = kf.x[n3:].reshape(n, 3) @ R.T
            kf.x = np.r_[pos.reshape(-1), vel.reshape(-1)]
            B = np.kron(np.eye(2 * n), R)
            kf.P = B @ kf.P @ B.T
        elif kf is not None and self.method == "roi-rk":
            # x = [beta, alpha, beta', alpha', tip (3), tip velocity (3)] (Zhao eqs. (2)-(3))
            x = kf.x
            ang = np.asarray(x[:2], float)

            def new_angles(a):
                b, al = _angles(R @ angles_to_direction(a[0], a[1]))
                return np.array([b, float(x[1]) + _wrap(al - float(x[1]))])

            a_new = new_angles(ang)
            J = np.empty((2, 2))
            h = 1e-6
            for j in range(2):
                e = np.zeros(2)
                e[j] = h
                J[:, j] = (new_angles(ang + e) - new_angles(ang - e)) / (2 * h)
            B = np.zeros((10, 10))
            B[:2, :2] = J
            B[2:4, 2:4] = J
            B[4:7, 4:7] = R
            B[7:10, 7:10] = R
            kf.x = np.r_[a_new, J @ x[2:4], R @ x[4:7] + t, R @ x[7:10]]
            kf.P = B @ kf.P @ B.T
        if self._pending is not None:
            self._pending = (R @ self._pending[0] + t, self._pending[1])
        self._prev_image = None
        self._prev_map = None

    @property
    def _learned(self) -> bool:
        return getattr(self.features, "kind", "classical") == "learned"

    def _not_found(self) -> Status:
        """``searching`` until the needle is first found, ``lost`` after that."""
        return Status.SEARCHING if self.status == Status.SEARCHING else Status.LOST

    def _dt(self, t: float) -> float:
        dt = self.params.default_dt_s if self._t_prev is None else t - self._t_prev
        return dt if dt > 0 else self.params.default_dt_s

    # -- one frame -----------------------------------------------------------------------

    def _step(self, frame: Frame) -> NeedleEstimate:
        if frame.grid.ndim != 3:
            raise ValueError(f"VolumeTracker needs 3D volumes, got a {frame.grid.ndim}D frame")
        vol = _Volume(frame, self.features.likelihood(frame), self._learned)
        dt = self._dt(frame.t)
        if self.method == "ransac":
            est = self._step_ransac(frame, vol)
        elif self.method == "roi-rk":
            est = self._step_roi_rk(frame, vol, dt)
        else:
            est = self._step_chatelain(frame, vol, dt)
        self._t_prev = frame.t
        return est

    def _report(self, frame: Frame, status: Status, m: _Measurement | None, tip=None,
                direction=None, covariance=None, reason: str | None = None,
                axis_point=None) -> NeedleEstimate:
        extras = {"inliers": 0, "ransac_trials": 0, "roi_voxels": 0}
        if m is not None:
            extras.update(inliers=m.inliers, ransac_trials=m.trials, roi_voxels=m.roi_voxels)
        if tip is None:
            extras["reason"] = reason if reason is not None else (m.reason if m else None)
            return NeedleEstimate(t=frame.t, status=status, extras=extras)
        beta, alpha = _angles(direction)
        if axis_point is None:  # the visible entry, on the reported axis
            length = float(m.a_tip - m.a_entry) if (m is not None and m.ok) else 0.0
            axis_point = np.asarray(tip, float) - length * np.asarray(direction, float)
        point = axis_point
        extras.update(axis_point_mm=np.asarray(point, float), alpha_deg=math.degrees(alpha),
                      beta_deg=math.degrees(beta))
        if m is not None and m.ok:
            extras["measured_tip_mm"] = np.asarray(m.tip, float)
        if reason is not None:
            extras["reason"] = reason
        return NeedleEstimate(t=frame.t, status=status, tip_mm=np.asarray(tip, float),
                              direction=np.asarray(direction, float),
                              covariance=np.asarray(covariance, float), extras=extras)

    # -- ransac (Uhercik 2010 / Zhao Appendix B) -----------------------------------------

    def _step_ransac(self, frame: Frame, vol: _Volume) -> NeedleEstimate:
        p = self.params
        threshold = _threshold(vol, p)  # eq. (B1)
        m = _measure(vol, None, threshold, p, self._rng, max_trials=p.max_trials)
        if not m.ok:
            status = self._not_found()
            return self._report(frame, status, m)
        return self._report(frame, Status.TRACKING, m, m.tip, m.direction,
                            p.r_position * np.eye(3))

    # -- roi-rk (Zhao 2013) --------------------------------------------------------------

    def _initialise_roi_rk(self, frame: Frame, vol: _Volume, threshold: float) -> _Measurement:
        """Step 1 of Zhao: RANSAC on the tubularness of the whole volume places the first ROI,
        in which the needle is measured on the intensity.

        The hypothesis must look like a needle inserted from outside (Zhao App. B: "the
        needle is inserted from the outside"): bright along its axis, at least
        ``min_length_mm`` long, starting within ``entry_margin_mm`` of the sector's boundary.
        A hypothesis that is not (a tubular structure of the tissue) is set aside with its
        inliers and RANSAC runs again, up to ``init_attempts`` times (sequential RANSAC).
        """
        p = self.params
        if self._learned:  # a learned map already says where the needle is
            cand, weights = _candidates(vol, None, threshold, p)
            pts, r_in = vol.points(cand), p.inlier_radius_mm
        else:
            tub = self._frangi.tubularness(frame)  # Appendix A, whole volume
            sector = _block_sector(vol.sector, tub.factor) & (tub.values > 0)
            values = tub.values[sector]
            if values.size < p.min_inliers:
                return _fail("no tubular structure in the volume")
            t_tub = float(np.percentile(values, p.threshold_percentile))  # eq. (B1)
            idx = np.flatnonzero(sector.reshape(-1) & (tub.values.reshape(-1) >= t_tub))
            pts = tub.grid.index_to_points(np.stack(np.unravel_index(idx, tub.values.shape), -1))
            weights = tub.values.reshape(-1)[idx].astype(float)
            # Inliers on the block-averaged grid lie up to a working voxel from the axis.
            r_in = max(p.inlier_radius_mm, float(np.max(tub.grid.spacing_mm)))
        keep = np.ones(len(pts), bool)
        trials = 0
        m = _fail("no candidates")
        # learned maps: every hypothesis that passes competes on its likelihood
        choose = self._learned and p.init_select == "likelihood"
        found: list[tuple[float, _Measurement]] = []
        for _ in range(p.init_attempts):
            active = np.flatnonzero(keep)
            if active.size < p.min_inliers:
                break
            max_trials = p.init_max_trials
            if found:  # competitors of a found needle: the most likely voxels, fewer trials
                max_trials = max(1, p.init_max_trials // 4)
                if active.size > _SELECT_CANDIDATES:
                    top = np.argpartition(weights[active], active.size - _SELECT_CANDIDATES)
                    active = active[top[active.size - _SELECT_CANDIDATES:]]
            w = None if weights is None else weights[active]
            res = ransac(pts[active], "line", residual_threshold=r_in, weights=w,
                         min_sample_distance=p.min_sample_distance_mm,
                         success_probability=p.success_probability,
                         max_trials=max_trials, batch_size=p.batch_size,
                         refine_iterations=p.refine_iterations, rng=self._rng)
            trials += res.n_trials
            if not res:
                m = _fail(f"RANSAC: {res.reason}", trials)
                break
            region = _cylinder(vol, res.model.origin, res.model.direction, p.roi_radius_mm)
            m = _measure(vol, region, threshold, p, self._rng, max_trials=p.max_trials)
            m.trials += trials
            if m.ok and m.entry_gap_mm > p.entry_margin_mm:
                m = _fail(f"not a needle inserted from outside: it starts {m.entry_gap_mm:.1f} "
                          f"mm inside the sector", m.trials, m.roi_voxels, m.inliers)
            if m.ok and not choose:
                return m
            if m.ok:
                found.append((_median_profile(vol, m.model, m.a_entry, m.a_tip, p), m))
            keep[active[res.inliers]] = False  # set the structure aside
        if found:
            score, best = found[0]  # RANSAC's own choice: the most support
            for s, other in found[1:]:
                if s > p.init_select_ratio * score:
                    score, best = s, other
            best.trials = trials
            return best
        return m

    def _step_roi_rk(self, frame: Frame, vol: _Volume, dt: float) -> NeedleEstimate:
        p = self.params
        threshold = _threshold(vol, p)  # eq. (B1)
        if self._kf is None:  # Step 1: initialise the ROI
            m = self._initialise_roi_rk(frame, vol, threshold)
            if not m.ok:
                self._prev_image = None
                status = self._not_found()
                return self._report(frame, status, m)
            beta, alpha = _angles(m.direction)
            x = np.r_[beta, alpha, 0.0, 0.0, m.tip, 0.0, 0.0, 0.0]  # rates start at zero
            P = np.diag([p.r_angle] * 2 + [p.p0_angle_rate] * 2 + [p.r_position] * 3
                        + [p.p0_velocity] * 3)
            model = zhao_model(dt, q_angle=p.q_angle, q_tip=p.q_tip, r_angle=p.r_angle,
                               r_position=p.r_position, r_velocity=p.r_velocity)
            self._kf = KalmanFilter(x, P, model.F, model.H, model.Q, model.R)
            self._prev_image = vol.image
            return self._report(frame, Status.TRACKING, m, m.tip, m.direction,
                                self._kf.P[4:7, 4:7])
        # Step 2: predict (eqs. (2)-(3)), ROI (eq. (1)), RANSAC, speckle tracking, correct.
        kf = self._kf
        model = zhao_model(dt, q_angle=p.q_angle, q_tip=p.q_tip, r_angle=p.r_angle,
                           r_position=p.r_position, r_velocity=p.r_velocity)
        kf.F, kf.Q, kf.R = model.F, model.Q, model.R
        prev_tip = kf.x[4:7].copy()
        kf.predict()
        u_pred = angles_to_direction(kf.x[0], kf.x[1])
        tip_pred = kf.x[4:7]
        region = _cylinder(vol, tip_pred, u_pred, p.roi_radius_mm)  # eq. (1)
        m = _measure(vol, region, threshold, p, self._rng, max_trials=p.max_trials,
                     predicted_direction=u_pred, predicted_tip=tip_pred)
        reason = None
        if m.ok:
            turn = math.degrees(math.acos(min(1.0, abs(float(m.direction @ u_pred)))))
            w = tip_pred - m.entry
            shift = float(np.linalg.norm(w - (w @ m.direction) * m.direction))
            if turn > p.max_axis_jump_deg:
                reason = f"axis jump: {turn:.1f} deg > {p.max_axis_jump_deg} deg"
            elif shift > p.max_axis_shift_mm:
                reason = f"axis shift: {shift:.2f} mm > {p.max_axis_shift_mm} mm"
        else:
            reason = m.reason
        if reason is not None:  # the ROI has lost the needle: initialise again next volume
            self._kf = None
            self._prev_image = None
            return self._report(frame, Status.LOST, m, reason=reason)
        beta, alpha = _angles(m.direction)
        alpha = float(kf.x[1]) + _wrap(alpha - float(kf.x[1]))  # no 2 pi jump in the innovation
        velocity = self._speckle_velocity(vol, prev_tip, dt)  # eq. (5)
        if velocity is not None:
            kf.update(np.r_[beta, alpha, m.tip, velocity])  # eqs. (C5)-(C7)
        else:  # no velocity: update on the angles and the tip only
            kf.update(np.r_[beta, alpha, m.tip], R=kf.R[:5, :5], H=kf.H[:5])
        self._prev_image = vol.image
        return self._report(frame, Status.TRACKING, m, kf.x[4:7],
                            angles_to_direction(kf.x[0], kf.x[1]), kf.P[4:7, 4:7])

    def _speckle_velocity(self, vol: _Volume, tip_mm: np.ndarray, dt: float):
        """Tip velocity (mm/s, point order) by 3-D speckle tracking (Zhao eq. (5)), or None.

        The kernel is taken around the previous tip in the previous volume and searched for in
        the current one; only the search box is handed over, so no whole volume is copied.
        """
        if self._prev_image is None or self._prev_image.shape != vol.image.shape:
            return None
        p = self.params
        k_half = np.maximum(np.rint(p.speckle_kernel_mm / vol.spacing), 1).astype(int)
        s_half = k_half + np.ceil(p.speckle_search_mm / vol.spacing).astype(int)
        centre = np.rint(vol.to_index(tip_mm)).astype(int)
        if np.any(centre < 0) or np.any(centre >= vol.shape):
            return None
        lo = np.maximum(centre - s_half, 0)
        hi = np.minimum(centre + s_half + 1, vol.shape)
        box = tuple(slice(a, b) for a, b in zip(lo, hi, strict=True))
        try:
            res = tip_velocity(self._prev_image[box], vol.image[box], centre - lo, k_half,
                               s_half, vol.spacing, dt)
        except ValueError:  # constant kernel (outside the sector) or clipped away
            return None
        return res.velocity_mm_s[::-1]  # array order -> point order

    # -- chatelain (Chatelain 2013) ------------------------------------------------------

    def _control_points(self, m: _Measurement) -> np.ndarray:
        """Z_t: the n control points of eq. (3), entry to tip along the fitted curve."""
        a = np.linspace(m.a_entry, m.a_tip, self.params.n_control_points)
        return m.model.points_at(a).reshape(-1)

    def _voi_count(self, vol: _Volume) -> int:
        """Size of the fixed candidate set of eq. (15) on this grid."""
        return _count(self.params.voi_candidates_mm3, vol, 2 * self.params.min_inliers)

    def _tip_block(self) -> slice:
        n = self.params.n_control_points
        return slice(3 * (n - 1), 3 * n)

    def _step_chatelain(self, frame: Frame, vol: _Volume, dt: float) -> NeedleEstimate:
        p = self.params
        previous, self._prev_map = self._prev_map, vol.values
        if self._kf is None:
            return self._search_chatelain(frame, vol, previous, dt)
        n = p.n_control_points
        kf = self._kf
        model = chatelain_control_points_model(n, 3, dt=dt, q=p.q_control, r=p.r_control)
        kf.F, kf.Q, kf.R = model.F, model.Q, model.R
        kf.predict()  # eqs. (10)-(11)
        ctrl = kf.x[: 3 * n].reshape(n, 3)
        chord = ctrl[-1] - ctrl[0]
        length = float(np.linalg.norm(chord))
        if length > 0:
            k0 = chord / length  # predicted principal direction k0^- (eq. (22))
            bow = 0.0 if n == 2 else float(np.linalg.norm(ctrl[1] - 0.5 * (ctrl[0] + ctrl[-1])))
            # VOI around the predicted curve (its chord, widened by the bow of a curve).
            region = _cylinder(vol, ctrl[0], k0, p.voi_radius_mm + bow,
                               (-p.voi_margin_mm, length + p.voi_margin_mm))
            m = _measure(vol, region, _threshold(vol, p), p, self._rng,
                         max_trials=p.init_max_trials, predicted_direction=k0,
                         max_angle_deg=p.max_angle_deg, fixed_size=self._voi_count(vol),
                         model="line" if n == 2 else "curve",
                         predicted_tip=ctrl[-1])  # eqs. (15)-(22)
            if m.ok and np.linalg.norm(m.tip - ctrl[-1]) > p.voi_margin_mm:
                # a tip beyond the VOI's end: the profile ran along another structure
                m = _fail(f"tip jump: {np.linalg.norm(m.tip - ctrl[-1]):.1f} mm from the "
                          f"predicted tip > voi_margin_mm", m.trials, m.roi_voxels, m.inliers)
        else:
            m = _fail("the predicted needle has no length")
        if not m.ok:  # the needle has vanished (or was missed): coast, then wait for a new one
            self._misses += 1
            if self._misses > p.max_coast_volumes:
                self._kf = None
            return self._report(frame, Status.LOST, m)
        self._misses = 0
        kf.update(self._control_points(m))  # eqs. (12)-(14)
        ctrl = kf.x[: 3 * n].reshape(n, 3)
        chord = ctrl[-1] - ctrl[0]
        norm = float(np.linalg.norm(chord))
        direction = m.direction if norm == 0 else chord / norm
        block = self._tip_block()
        return self._report(frame, Status.TRACKING, m, ctrl[-1], direction,
                            kf.P[block, block], axis_point=ctrl[0])

    def _insertion_params(self, vol: _Volume) -> InsertionParams:
        """The detector's parameters for this grid: the candidate set covers
        ``insertion_candidates_mm3`` whatever the voxel size, and the delta test is left to
        :meth:`_search_chatelain`, which measures it to the sector's boundary."""
        p = self.params
        n = p.insertion.n_candidates
        if p.insertion_candidates_mm3 is not None:
            n = _count(p.insertion_candidates_mm3, vol, _MIN_INSERTION_CANDIDATES)
        n = min(n, int(np.prod(vol.shape)))
        return replace(p.insertion, n_candidates=int(n), distance_threshold_mm=_NO_LIMIT_MM)

    def _boundary_distance(self, vol: _Volume, point: np.ndarray) -> float:
        """Distance from a point to the sector's boundary, along the nearest of a fan of rays
        (the scan-converted sector is the volume whose boundary Chatelain's entry lies on)."""
        step = _ray_step(vol)
        reach = self.params.insertion.distance_threshold_mm
        s = np.arange(0, int(reach / step) + 2) * step
        first_out = _sector_run_out(vol, point + s[None, :, None] * _RAYS[:, None, :])
        return float(s[np.minimum(first_out, len(s) - 1)].min())

    def _search_chatelain(self, frame: Frame, vol: _Volume, previous, dt: float):
        """Chatelain II-B: wait for a localised change, then fit the needle around it.

        The change map is ``|I_t - I_(t-1)|`` (or the change of a learned likelihood). The
        detector keeps a fixed number of the largest changes (eq. (1)), tests their variance
        and takes their geometric median (eq. (2)); the median must lie within delta of the
        boundary of the imaged sector (the detector's own test uses the faces of the array,
        which a sector volume does not fill). After a detection, the needle is fitted in a
        ball around the median for ``detection_window`` volumes, and tracking starts once it
        is visible over ``min_length_mm``.
        """
        p = self.params
        status = self._not_found()
        reason = "first volume: nothing to compare with"
        if previous is not None and previous.shape == vol.values.shape:
            if self._detector is None:
                self._detector = InsertionDetector(self._insertion_params(vol))
            detection = self._detector.update_difference(np.abs(vol.values - previous),
                                                         vol.spacing)  # eqs. (1)-(2)
            reason = detection.reason
            if detection.median_mm is not None:
                median = (vol.origin + detection.median_mm)[::-1]  # array -> point order
                gap = self._boundary_distance(vol, median)
                if gap < p.insertion.distance_threshold_mm:  # ||E_t - Med|| < delta
                    self._pending = (median, p.detection_window)
                else:
                    reason = (f"median too far from the sector's boundary: {gap:.1f} mm >= "
                              f"delta = {p.insertion.distance_threshold_mm} mm")
        if self._pending is None:
            return self._report(frame, status, None, reason=reason)
        median, left = self._pending
        region = _ball(vol, median, p.init_voi_radius_mm)
        threshold = _threshold(vol, p)
        # tracking starts once the needle is in with a sufficient length (Chatelain II-A)
        p = replace(p, min_length_mm=max(p.min_length_mm, p.start_length_mm))
        # The change is where the needle moved, at its tip: it orients the needle.
        m = _measure(vol, region, threshold, p, self._rng, max_trials=p.init_max_trials,
                     fixed_size=self._voi_count(vol), tip_hint=median)
        if m.ok:
            w = median - m.entry
            off_axis = float(np.linalg.norm(w - (w @ m.direction) * m.direction))
            if off_axis > p.voi_radius_mm + p.inlier_radius_mm:
                m = _fail(f"the fitted axis passes {off_axis:.1f} mm from the detected change",
                          m.trials, m.roi_voxels, m.inliers)
            elif m.entry_gap_mm > p.entry_margin_mm:
                m = _fail(f"not a needle inserted from outside: it starts {m.entry_gap_mm:.1f} "
                          f"mm inside the sector", m.trials, m.roi_voxels, m.inliers)
            elif (tip_gap := _run_out_distance(vol, m.tip, m.direction,
                                               p.start_tip_margin_mm)) < p.start_tip_margin_mm:
                m = _fail(f"the needle runs out of the volume: its tip is {tip_gap:.1f} mm from "
                          f"the sector's boundary (< {p.start_tip_margin_mm} mm)", m.trials,
                          m.roi_voxels, m.inliers)
            elif not vol.learned and p.start_min_contrast > 0 and (
                    contrast := _needle_contrast(vol, m.model, m.a_entry, m.a_tip, p)) \
                    < p.start_min_contrast:
                m = _fail(f"not brighter than the tissue around it: the image along the fit is "
                          f"{contrast:.2f} times the tissue 2-3 mm away (< "
                          f"{p.start_min_contrast})", m.trials, m.roi_voxels, m.inliers)
            elif vol.learned and (level := _median_profile(vol, m.model, m.a_entry, m.a_tip, p)) \
                    < p.start_min_likelihood:
                m = _fail(f"the map does not see a needle there: median likelihood {level:.2f} "
                          f"< {p.start_min_likelihood}", m.trials, m.roi_voxels, m.inliers)
            elif p.n_control_points == 3:
                m = _measure(vol, region, threshold, p, self._rng, max_trials=p.init_max_trials,
                             predicted_direction=m.direction, max_angle_deg=p.max_angle_deg,
                             fixed_size=self._voi_count(vol), model="curve")
        if not m.ok:
            self._pending = (median, left - 1) if left > 1 else None
            return self._report(frame, status, m)
        self._pending = None
        n = p.n_control_points
        model = chatelain_control_points_model(n, 3, dt=dt, q=p.q_control, r=p.r_control)
        x = np.r_[self._control_points(m), np.zeros(3 * n)]  # velocities start at zero
        P = np.diag([p.r_control] * (3 * n) + [p.p0_control_velocity] * (3 * n))
        self._kf = KalmanFilter(x, P, model.F, model.H, model.Q, model.R)
        self._misses = 0
        block = self._tip_block()
        return self._report(frame, Status.TRACKING, m, m.tip, m.direction,
                            self._kf.P[block, block])


def _block_sector(sector: np.ndarray, f: int) -> np.ndarray:
    """Sector mask on the block-averaged working grid of the line filter (all of a block)."""
    if f == 1:
        return sector
    pad = [(0, (-n) % f) for n in sector.shape]
    s = np.pad(sector, pad, mode="constant")
    shape = []
    for n in s.shape:
        shape += [n // f, f]
    return s.reshape(shape).all(axis=tuple(range(1, 2 * sector.ndim, 2)))


