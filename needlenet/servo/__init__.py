"""Probe servoing on the needle tip: Ye 2025's EKF + PI/PD tracking of a 2D transverse probe."""

from ._ye import (
    YE_TABLE2,
    MassDamperAxis,
    PositionPD,
    SpeedGain,
    VelocityPI,
    YeServoConfig,
    run_ye,
    table2,
    ye_insertion_velocity,
    ye_tip_path,
)

__all__ = [
    "YE_TABLE2",
    "MassDamperAxis",
    "PositionPD",
    "SpeedGain",
    "VelocityPI",
    "YeServoConfig",
    "run_ye",
    "table2",
    "ye_insertion_velocity",
    "ye_tip_path",
]
