"""Probe servoing on the needle: Ye 2025 (2D transverse probe, EKF + PI/PD) and Chatelain 2013
(3-DOF visual servoing of a 3D probe), closed through the simulated scanner.

Public API (for ``needlenet servo``, ``bench servo`` and ``demo``)
------------------------------------------------------------------
``servo_rows(scenario, *, filters=("pv", "prv"), gains=("dynamic", "constant"),
features=("ideal",), runs=("misalignment", "motion"), repeats=None, seed=0, model=None,
quick=False, progress=None, traces=None, fault=None) -> list[dict]``
    One row per configuration. ``scenario="servo"`` (Ye): configurations features x filter x
    gain; features ``"ideal"`` (section 4.1's noisy measurement, Table 2; 100 repeats by
    default), ``"learned"`` (the shipped axial ONNX model, or ``model``) or ``"classical"``
    (Carriere's variance image), the last two imaging the world from the probe's pose each
    frame (3 repeats by default). Keys: ``gain, filter, features, rmse_p_mm, rmse_vx_mm_s,
    rmse_pux_mm, rmse_puy_mm, lead_lag_ratio`` (frames with the probe ahead of the tip /
    frames behind it, Ye's Table 2), ``behind_fraction`` (frames with the probe behind the
    tip), ``in_plane_fraction`` (frames with the tip inside the imaged slice: |p_x - p_ux| <=
    half the -6 dB elevation width of the scanner's pulse-echo PSF at the tip's depth; for
    ``ideal`` the servo world's scanner with the probe 10 mm above the tip's start),
    ``detected_fraction`` (frames counted as detected by eq. (13)), ``rmse_p_xyz_mm``,
    ``reach_mm`` (where the calibrated detector stops finding the needle, mm ahead of the tip
    on the calibration worlds; ~0), ``echo_threshold`` (the calibrated acceptance level),
    ``latency_median_ms, latency_p99_ms`` (per cycle without imaging),
    ``latency_with_imaging_median_ms, latency_with_imaging_p99_ms``, ``setup_s``,
    ``safety_stops``, ``stops`` (each stop's ``reason``: ``needle_lost``, ``never_found``,
    ``stale_feed``, ``stuck_detector`` or ``unconfirmed_travel``, its ``time_s`` and, with a
    fault, ``since_fault_s`` and ``travel_since_fault_mm``), ``frames``, ``repeats``,
    ``seed`` and Ye's figures as ``paper_*``.
    ``scenario="volume-motion"`` (Chatelain): configurations features (``"classical"``,
    ``"learned"``) x runs (``"misalignment"``: 40 degrees; ``"motion"``: moving phantom); keys
    ``features, run, rest_err_x_mm, rest_err_z_mm, rest_err_theta_deg`` (the estimated
    feature error at rest, as the paper reports it), ``rest_true_err_*`` (the true one),
    ``initial_theta_deg, rmse_p_mm, in_plane_fraction`` (cycles with the tip inside the
    volume), ``tracked_fraction``, the same latency keys, ``paper_rest_err_*``.
    ``quick=True`` shortens every run (all rows of a scenario in about a minute).
    ``fault`` (``FAULTS``: ``frozen-feed``, ``stuck-detector``, ``needle-lost``,
    ``never-found``) is injected half way through every run (the insertion's half for
    Chatelain) to exercise the watchdogs.
    ``progress(done, total, label)`` after each run; ``traces`` (a list) receives a
    :class:`ClosedLoopResult` per configuration (its first repeat) for plots.
    Bad options raise ``ValueError`` naming the value before any loop runs.
``run_closed_loop(scenario, *, filter="prv", gain="dynamic", features="learned",
run="misalignment", seed=0, model=None, quick=False) -> ClosedLoopResult``
    One run with arrays ``t``, ``p_true``, ``p_hat``, ``probe``, ``detected`` and the raw dict.
``plot_runs(traces, path, title="")``: a PNG of true, estimated and probe trajectories.
"""

from ._api import (
    FEATURES_2D,
    FEATURES_3D,
    FILTERS,
    GAINS,
    RUNS_3D,
    SCENARIOS,
    ClosedLoopResult,
    check_options,
    run_closed_loop,
    servo_rows,
)
from ._chatelain import (
    CHATELAIN_REST,
    ChatelainConfig,
    chatelain_features,
    control_velocity,
    interaction_matrix,
    move_probe,
    run_chatelain,
)
from ._faults import FAULTS, Fault
from ._images import (
    CALIBRATION_SEEDS,
    CrossSectionDetector,
    DetectorCalibration,
    EchoThreshold,
    ServoImaging,
    ServoWorld,
    calibrate_detector,
    calibrate_reach,
    in_slice,
    make_detector,
    servo_world,
    slice_half_width_mm,
)
from ._plot import plot_runs
from ._ye import (
    YE_TABLE2,
    Measurement,
    YeServoConfig,
    run_ye,
    table2,
    ye_insertion_velocity,
    ye_tip_path,
)
from ._ye_control import MassDamperAxis, PositionPD, SpeedGain, VelocityPI

__all__ = [
    "CALIBRATION_SEEDS", "CHATELAIN_REST", "FAULTS", "FEATURES_2D", "FEATURES_3D", "FILTERS",
    "Fault", "GAINS",
    "RUNS_3D", "SCENARIOS", "YE_TABLE2", "ChatelainConfig", "ClosedLoopResult",
    "CrossSectionDetector", "DetectorCalibration", "EchoThreshold", "MassDamperAxis",
    "Measurement", "PositionPD", "ServoImaging", "ServoWorld", "SpeedGain", "VelocityPI",
    "YeServoConfig", "calibrate_detector", "calibrate_reach", "chatelain_features",
    "check_options", "control_velocity", "in_slice", "interaction_matrix", "make_detector",
    "move_probe", "plot_runs", "run_chatelain", "run_closed_loop", "run_ye", "servo_rows",
    "servo_world", "slice_half_width_mm", "table2", "ye_insertion_velocity", "ye_tip_path",
]
