"""The external set's sequences: the probes and one spec per sequence (fixed seeds)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["PROBES", "SPECS", "VALIDATION_SPECS", "SETS", "ProbeSetup", "SequenceSpec"]


@dataclass(frozen=True)
class ProbeSetup:
    """A PyMUST probe, its transmits and the image it makes."""

    model: str  # pymust.getparam name
    tilts_deg: tuple[float, ...]  # steering of the compounded transmits
    diverging_width_deg: float | None  # angular width of diverging waves; None: plane waves
    spacing_mm: float  # output pixel size, both axes
    x_range_mm: tuple[float, float]  # lateral extent of the output image
    z_range_mm: tuple[float, float]  # depth extent of the output image
    sector_half_angle_deg: float | None  # sector probes: half opening of the scan-converted fan
    polar_step_deg: float = 0.4  # sector probes: angle between beamformed lines
    margin_mm: float = 1.0  # scatterers extend this far beyond the image
    element_splitting: int | None = None  # simus ElementSplitting; None: PyMUST's rule
    attenuation_db_cm_mhz: float = 0.5
    db_thresh: float = -40.0  # simus keeps the frequencies of the spectrum above this level
    scatterers_per_cell: float = 10.0  # per -6 dB resolution cell, measured on a point target


PROBES = {
    # 128 elements, 7.6 MHz, 0.3 mm pitch; three plane waves compounded. The 0.27 mm elements
    # are in their far field (w^2 / lambda = 0.36 mm) at every simulated depth, so simus need
    # not split them.
    "L11-5v": ProbeSetup("L11-5v", (-5.0, 0.0, 5.0), None, 0.10, (-12.5, 12.5), (1.0, 31.0),
                         None, element_splitting=1),
    # 64 elements, 2.7 MHz; three diverging waves, beamformed on a polar grid and scan-converted
    "P4-2v": ProbeSetup("P4-2v", (-10.0, 0.0, 10.0), 75.0, 0.15, (-26.25, 26.25), (0.0, 45.0),
                        35.0),
    # 192 elements, 7.5 MHz, 0.2 mm pitch; two plane waves only (a coarser compounding than the
    # L11-5v's), 0.12 mm pixels. Used by the validation set only.
    "L12-3v": ProbeSetup("L12-3v", (-8.0, 8.0), None, 0.12, (-15.0, 15.0), (1.0, 33.0),
                         None, element_splitting=1),
}


@dataclass(frozen=True)
class SequenceSpec:
    """One sequence of the set. Lines are given by a point and a slope (degrees from +x towards
    +z: positive descends to the right)."""

    name: str
    probe: str  # key of PROBES
    seed: int
    needle: bool = True
    side: str = "left"  # the needle comes from the left (travels to +x) or from the right
    entry_x_mm: float = 0.0  # where the needle axis crosses the skin line z = 0
    angle_deg: float = 30.0  # angle between needle and skin
    start_mm: float = 10.0  # inserted length (from the skin line) at frame 0
    step_mm: float = 1.5  # insertion per frame
    n_frames: int = 14
    frame_rate_hz: float = 20.0
    gauge: int = 18
    target_cr: float = 2.5  # needle-to-tissue contrast on the last frame (see _local_contrast)
    roughness: float = 1.5  # sd of the wall scatterers' random amplitude around the coherent 1
    bevel_gain: float = 2.0  # sd of the bevel scatterers' (random) amplitude over roughness
    bevel_length_mm: float = 1.5
    reverb_gain: float = 0.35  # amplitude ratio of successive reverberation copies
    n_reverb: int = 3
    interface: tuple[float, float, float] | None = None  # (x_mm, z_mm, slope_deg)
    interface_cr: float = 2.5  # interface-to-tissue contrast, as the needle's
    vessel: tuple[float, float, float] | None = None  # (x_mm, z_mm, radius_mm), anechoic
    inhomogeneity: float = 0.25  # sd of the log echogenicity (smooth, ~4 mm correlation)
    snr_db: float = 40.0  # tissue RF rms over electronic noise rms, per channel
    dynamic_range_db: float = 55.0
    gamma: float = 1.0  # grey map: grey = 255 * ((dB + DR) / DR) ** gamma
    tissue_grey: float = 85.0  # mean grey of the tissue, set by the display gain
    feature: str = "plain"  # a word for the README table


SPECS = (
    SequenceSpec("lin_left_top_30", "L11-5v", 101, side="left", entry_x_mm=-10.0, angle_deg=30,
                 start_mm=7.0, step_mm=1.3, target_cr=2.6, dynamic_range_db=55, tissue_grey=85),
    SequenceSpec("lin_right_side_12", "L11-5v", 102, side="right", entry_x_mm=40.0,
                 angle_deg=12, start_mm=33.0, step_mm=1.5, target_cr=2.8, gauge=20,
                 dynamic_range_db=60, gamma=1.2, tissue_grey=70, feature="shallow"),
    SequenceSpec("lin_left_side_22_faint", "L11-5v", 103, side="left", entry_x_mm=-25.0,
                 angle_deg=22, start_mm=18.0, step_mm=1.4, target_cr=1.9, gauge=21,
                 dynamic_range_db=50, gamma=0.9, tissue_grey=95, feature="faint"),
    SequenceSpec("lin_right_top_40_interface", "L11-5v", 104, side="right", entry_x_mm=11.0,
                 angle_deg=40, start_mm=5.0, step_mm=1.2, target_cr=2.6, gauge=18,
                 interface=(0.0, 13.0, -40.0), interface_cr=2.2, dynamic_range_db=55,
                 tissue_grey=80, feature="bright interface 2.9 mm below, parallel"),
    SequenceSpec("lin_vessel_no_needle", "L11-5v", 105, needle=False,
                 interface=(0.0, 7.0, 8.0), interface_cr=2.4, vessel=(3.0, 19.0, 3.0),
                 dynamic_range_db=55, tissue_grey=85, feature="no needle; vessel, interface"),
    SequenceSpec("ph_right_side_45_vessel", "P4-2v", 201, side="right", entry_x_mm=26.0,
                 angle_deg=45, start_mm=25.6, step_mm=1.5, target_cr=2.6, gauge=18,
                 vessel=(-0.2, 26.2, 3.5), dynamic_range_db=55, tissue_grey=85,
                 feature="crosses a vessel"),
    SequenceSpec("ph_left_side_65_steep", "P4-2v", 202, side="left", entry_x_mm=-14.0,
                 angle_deg=65, start_mm=17.0, step_mm=1.5, target_cr=2.8, gauge=18,
                 dynamic_range_db=60, gamma=1.1, tissue_grey=75, feature="steep"),
    SequenceSpec("ph_left_side_35_interface", "P4-2v", 203, side="left", entry_x_mm=-30.0,
                 angle_deg=35, start_mm=30.0, step_mm=1.8, target_cr=2.4, gauge=17,
                 interface=(0.0, 25.0, 35.0), interface_cr=2.2, dynamic_range_db=50,
                 gamma=0.9, tissue_grey=90, feature="bright interface 3.3 mm below, parallel"),
    SequenceSpec("ph_right_side_55", "P4-2v", 204, side="right", entry_x_mm=22.0, angle_deg=55,
                 start_mm=23.0, step_mm=2.0, target_cr=2.8, gauge=16, dynamic_range_db=55,
                 tissue_grey=80, feature="plain"),
    SequenceSpec("ph_interface_no_needle", "P4-2v", 205, needle=False,
                 interface=(0.0, 22.0, -20.0), interface_cr=2.4, vessel=(6.0, 34.0, 3.5),
                 dynamic_range_db=55, tissue_grey=85, feature="no needle; interface, vessel"),
)


# The validation set (8 sequences, 7 with a needle): other seeds, angles, gauges, echo models,
# grey maps and a third probe, for choosing between trained models (``needlenet bench external
# --data needlenet/data/validation``). The test set above stays for the final report; neither
# is ever trained on.
VALIDATION_SPECS = (
    SequenceSpec("val_lin_right_top_25", "L11-5v", 301, side="right", entry_x_mm=16.0,
                 angle_deg=25, start_mm=8.0, step_mm=1.4, n_frames=10, target_cr=2.4, gauge=19,
                 n_reverb=2, reverb_gain=0.45, dynamic_range_db=65, gamma=1.1,
                 tissue_grey=75),
    SequenceSpec("val_lin_left_side_8", "L11-5v", 302, side="left", entry_x_mm=-60.0,
                 angle_deg=8, start_mm=52.0, step_mm=1.6, n_frames=10, target_cr=3.2,
                 gauge=18, dynamic_range_db=55, tissue_grey=100, feature="shallow"),
    SequenceSpec("val_lin_left_top_50_interface", "L11-5v", 303, side="left", entry_x_mm=-11.0,
                 angle_deg=50, start_mm=6.0, step_mm=1.5, n_frames=10, target_cr=2.6,
                 gauge=20, interface=(0.0, 20.0, 44.0), interface_cr=2.4, n_reverb=4,
                 reverb_gain=0.3, dynamic_range_db=50, tissue_grey=90,
                 feature="bright interface below, 6 degrees off parallel"),
    SequenceSpec("val_l12_right_side_18_faint", "L12-3v", 304, side="right", entry_x_mm=55.0,
                 angle_deg=18, start_mm=45.0, step_mm=1.5, n_frames=10, target_cr=2.0,
                 gauge=22, roughness=2.5, n_reverb=1, dynamic_range_db=60, gamma=0.9,
                 tissue_grey=85, feature="faint"),
    SequenceSpec("val_ph_left_side_45", "P4-2v", 401, side="left", entry_x_mm=-24.0,
                 angle_deg=45, start_mm=24.0, step_mm=1.8, n_frames=10, target_cr=2.5,
                 gauge=17, reverb_gain=0.5, dynamic_range_db=60, gamma=1.2, tissue_grey=70),
    SequenceSpec("val_ph_right_side_70_steep", "P4-2v", 402, side="right", entry_x_mm=13.0,
                 angle_deg=70, start_mm=17.0, step_mm=1.6, n_frames=10, target_cr=3.0,
                 gauge=18, dynamic_range_db=55, tissue_grey=90, feature="steep"),
    SequenceSpec("val_ph_right_side_30_interface", "P4-2v", 403, side="right", entry_x_mm=36.0,
                 angle_deg=30, start_mm=33.5, step_mm=1.8, n_frames=10, target_cr=2.6,
                 gauge=16, interface=(0.0, 24.0, -27.0), interface_cr=2.6, n_reverb=2,
                 dynamic_range_db=55, tissue_grey=85,
                 feature="bright interface below, 3 degrees off parallel"),
    SequenceSpec("val_ph_no_needle", "P4-2v", 404, needle=False,
                 interface=(0.0, 16.0, 15.0), interface_cr=2.6, dynamic_range_db=50,
                 gamma=0.9, tissue_grey=95, feature="no needle; interface"),
    # added in a second round (specs fixed before any model or tracker was run on them)
    SequenceSpec("val_ph_left_side_55", "P4-2v", 405, side="left", entry_x_mm=-14.0,
                 angle_deg=55, start_mm=17.0, step_mm=1.5, n_frames=10, target_cr=2.6,
                 gauge=18, dynamic_range_db=60, tissue_grey=80),
    SequenceSpec("val_ph_right_side_25_vessel", "P4-2v", 406, side="right", entry_x_mm=36.0,
                 angle_deg=25, start_mm=33.5, step_mm=1.8, n_frames=10, target_cr=2.5,
                 gauge=19, vessel=(-2.0, 18.5, 3.0), dynamic_range_db=55, tissue_grey=85,
                 feature="crosses a vessel"),
    SequenceSpec("val_ph_right_side_40_faint", "P4-2v", 407, side="right", entry_x_mm=30.0,
                 angle_deg=40, start_mm=28.0, step_mm=1.6, n_frames=10, target_cr=2.0,
                 gauge=21, roughness=2.0, dynamic_range_db=55, gamma=1.1, tissue_grey=90,
                 feature="faint"),
    SequenceSpec("val_ph_left_side_20_shallow", "P4-2v", 408, side="left", entry_x_mm=-45.0,
                 angle_deg=20, start_mm=42.0, step_mm=1.6, n_frames=10, target_cr=2.7,
                 gauge=17, n_reverb=2, dynamic_range_db=50, tissue_grey=80,
                 feature="shallow"),
    SequenceSpec("val_lin_right_side_60_steep", "L11-5v", 305, side="right", entry_x_mm=16.0,
                 angle_deg=60, start_mm=14.0, step_mm=1.3, n_frames=10, target_cr=2.4,
                 gauge=21, dynamic_range_db=60, tissue_grey=80, feature="steep"),
    SequenceSpec("val_lin_left_top_35_vessel", "L11-5v", 306, side="left", entry_x_mm=-8.0,
                 angle_deg=35, start_mm=8.0, step_mm=1.4, n_frames=10, target_cr=2.6,
                 gauge=18, vessel=(5.5, 9.8, 2.5), dynamic_range_db=55, gamma=0.9,
                 tissue_grey=95, feature="crosses a vessel"),
    SequenceSpec("val_lin_no_needle", "L11-5v", 307, needle=False, n_frames=10,
                 interface=(0.0, 12.0, -10.0), interface_cr=2.4, vessel=(-4.0, 20.0, 3.0),
                 dynamic_range_db=60, tissue_grey=80, feature="no needle; interface, vessel"),
    # a third round: shallow needles from the right near the skin, as in-plane recordings of
    # biopsies show them (specs fixed before any model or tracker was run on them)
    SequenceSpec("val_lin_right_side_6", "L11-5v", 308, side="right", entry_x_mm=60.0,
                 angle_deg=6, start_mm=51.8, step_mm=1.5, n_frames=10, target_cr=2.6,
                 gauge=21, n_reverb=3, reverb_gain=0.4, dynamic_range_db=60, tissue_grey=90,
                 feature="shallow, near the skin"),
    SequenceSpec("val_l12_right_side_12_reverb", "L12-3v", 309, side="right", entry_x_mm=55.0,
                 angle_deg=12, start_mm=45.0, step_mm=1.5, n_frames=10, target_cr=3.0,
                 gauge=18, n_reverb=4, reverb_gain=0.5, dynamic_range_db=55, tissue_grey=100,
                 feature="shallow, four reverberations"),
    SequenceSpec("val_lin_right_side_10_faint", "L11-5v", 310, side="right", entry_x_mm=60.0,
                 angle_deg=10, start_mm=52.3, step_mm=1.5, n_frames=10, target_cr=2.0,
                 gauge=22, roughness=2.0, dynamic_range_db=50, tissue_grey=110,
                 feature="shallow, faint, bright display"),
    # a fourth round: needles beside a bright interface that runs with them, below or above
    # (specs fixed before any model or tracker was run on them)
    SequenceSpec("val_lin_right_top_45_interface", "L11-5v", 311, side="right", entry_x_mm=12.0,
                 angle_deg=45, start_mm=5.0, step_mm=1.3, n_frames=10, target_cr=2.5,
                 gauge=19, interface=(0.0, 15.5, -45.0), interface_cr=2.3, dynamic_range_db=55,
                 tissue_grey=85, feature="bright interface 2.5 mm below, parallel"),
    SequenceSpec("val_lin_left_top_30_interface", "L11-5v", 312, side="left", entry_x_mm=-12.0,
                 angle_deg=30, start_mm=6.0, step_mm=1.5, n_frames=10, target_cr=2.3,
                 gauge=20, interface=(0.0, 9.24, 30.0), interface_cr=2.6, dynamic_range_db=60,
                 gamma=1.1, tissue_grey=80, feature="bright interface 2 mm below, parallel"),
    SequenceSpec("val_lin_right_side_20_interface", "L11-5v", 313, side="right",
                 entry_x_mm=35.0, angle_deg=20, start_mm=27.0, step_mm=1.5, n_frames=10,
                 target_cr=2.6, gauge=18, interface=(0.0, 10.1, -20.0), interface_cr=2.4,
                 dynamic_range_db=55, tissue_grey=90,
                 feature="bright interface 2.5 mm above, parallel"),
    SequenceSpec("val_ph_left_side_40_interface", "P4-2v", 409, side="left", entry_x_mm=-28.0,
                 angle_deg=40, start_mm=25.0, step_mm=1.6, n_frames=10, target_cr=2.5,
                 gauge=17, interface=(0.0, 27.4, 40.0), interface_cr=2.5, dynamic_range_db=55,
                 tissue_grey=85, feature="bright interface 3 mm below, parallel"),
)

SETS = {"test": SPECS, "validation": VALIDATION_SPECS}
