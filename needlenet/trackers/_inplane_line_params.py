"""Settings of the default in-plane tracker (:mod:`._inplane_line`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..backends import LineSearchParams
from ._base import GAUGE_RADII_MM, radius_variance
from ._inplane_echo_end import EchoEndParams
from ._inplane_growing import GrowingMarkParams
from ._inplane_line_echo import EchoTestParams
from ._inplane_motion import MotionTipParams
from ._inplane_still import StillLineParams

__all__ = ["LineTrackerParams", "MAX_DISTANCE_MM"]

MAX_DISTANCE_MM = 100.0  # the distances of the settings: a fraction of any image


@dataclass(frozen=True)
class LineTrackerParams:
    """Settings (units in the names).

    ``min_length_mm``: the shortest needle segment taken for a needle (5 mm: long enough to fix
    a direction, shorter than any needle a user would track). ``learned_level``: a learned
    shaft probability at or above this marks the needle (0.5: the map's decision level).
    ``learned_extend_level``: past a needle's segment, the tip is also looked for as far as
    the learned shaft probability stays at or above this along its line (Canny's hysteresis;
    half the decision level: the map of a needle shallower or fainter than those it was
    trained on hovers around 0.5 along it, tissue stays below 0.1); the tip moves there only
    where the tip map reaches ``tip_map_min``. Equal to ``learned_level``: off.
    ``classical_level``: the same for the classical line-contrast map, in speckle standard
    deviations above the tissue beside the echo (2 SD). ``contrast_window_mm``: the side of
    that map's tissue boxes. ``track_window_deg``/``track_window_mm``: while tracking,
    the line is searched within these of the last line; ``switch_ratio``: a segment elsewhere
    replaces it when its evidence sum is this many times larger; the whole frame is searched
    for one every ``full_search_every_frames`` frames (a quarter second at 20 frames/s), and
    on every frame until the tracked needle's segment has once been ``settled_length_mm``
    long (twice ``min_length_mm``: the direction of a shorter mark, a blob where a needle
    comes in bright near the edge of a sector, is a guess that the window would follow).
    ``tip_window_mm``: the tip map's maximum is looked for this far behind and ahead of the
    segment's end. ``tip_map_min``:
    the tip map must reach this there to move the tip. ``accel_std_mm_s2``: the filter's
    white-acceleration noise (a hand or robot changing the insertion speed within a fraction
    of a second); ``measurement_std_mm``: the tip measurement's noise; ``initial_speed_std_mm_s``:
    the speed's prior spread. ``gate_probability``: the chi-square gate of a tip measurement;
    ``reinit_after_rejects``: gated-out measurements in a row after which the filter restarts
    at the image's tip; ``noise_window_frames``: the accepted measurements whose innovations
    estimate the tip measurements' noise for the reported covariance (half a second at 20
    frames/s; :mod:`._inplane_line_filter`); ``confirm_after_frames``: measurements accepted
    in a row after which the track is confirmed (M-of-N track confirmation): a confirmed
    needle is not replaced by a line from its entry longer than it could have grown (see the
    tracker's doc), an unconfirmed first mark may be, its length along a guessed direction
    being no measure of the needle's.
    ``forget_after_frames``: frames without a needle after which the track
    is forgotten. ``needle_radius_mm``: maps that mark the wall facing the probe (learned
    ``target_reference = "wall"`` and the classical echo) are moved by it to the centre line
    (default 18 G). ``gauge_radii_mm``: the range of radii of the needle, when the tracker is
    not told its gauge (14-25 G): the centre line lies a radius from the wall's echo, which is
    that uncertain, and the reported tip covariance says so
    (:meth:`~._inplane_line_tip.LineTip._centre_line_covariance`). A needle of known radius r:
    ``gauge_radii_mm = (r, r)`` and ``needle_radius_mm = r``.
    ``frame_rate_hz``: None takes the rate from the timestamps (20 Hz until two frames have
    been seen). ``orientation_min_angle_deg``: see the module's doc.
    ``edge_margin_mm``: a segment whose two ends both lie this close to the edge of the imaged
    region runs across the image and shows no tip (an interface, or a needle whose tip is out
    of view; so is the edge of a capture margin or sector mask): no needle.
    ``tip_room_sections``: a new line (one that does not continue the needle tracked on the
    frame before) is taken only where the image past its end, before ``edge_margin_mm`` of
    the edge, holds this many of the echo test's sections (``echo.section_mm``): the fewest
    in which a run of echo past the end, and so whether the line ends there, can be read
    (one section is a single noisy reading). Nearer the edge the line may run on out of view,
    as an interface does, and its tip is not seen.
    ``entry_margin_mm``: a segment whose entry end lies this close to that edge (along the
    line or straight) enters through it, as an inserted needle does; a floating one is taken
    only as the continuation of the needle seen on the frame before (on its axis, within
    ``track_window_deg``/``track_window_mm``, its end inside the tip filter's gate).
    ``beam_min_angle_deg``: a line shorter than ``settled_length_mm`` that runs within this
    of the beams (:mod:`._beams`, where the imaged region shows them) is no needle: a needle's
    shaft echoes back to the probe where the beams meet it across, and one they graze within
    15 degrees reflects its echo away (its incidence 75 degrees or more from the normal, past
    the aperture's reach at any depth); a short line along the beams is the reverberation
    tail under a bright reflector (a needle's own, below its first millimetres of shaft).
    ``echo``: with classical features a line is a needle only where its echo shows along it
    (:mod:`._inplane_line_echo`). ``echo_end``: a tip past where the
    needle's echo ends in the image is moved back there (:mod:`._inplane_echo_end`).
    ``still``: lines seen standing still beside the advancing needle are tissue
    (:mod:`._inplane_still`). ``growing``: a learned mark shorter than ``min_length_mm`` is
    taken for a needle coming in once it has grown where it enters, and a new track on a line
    shorter than ``settled_length_mm`` must grow within ``growing.prove_within_s`` to stay
    (:meth:`~._inplane_line_confirmed.ConfirmedTrack._proven`).
    ``motion``: where the search offers no needle line, the tip is read where echo was gained
    since the frame before (:mod:`._inplane_line_motion`).
    ``mask_edge_mm``: evidence this close to the edge of a capture margin or sector mask is
    not read (the mask's step is no echo; the shipped in-plane model marks it up to 1.5 mm
    in, measured on needle-free synth frames with sector masks and margins)."""

    search: LineSearchParams = field(default_factory=LineSearchParams)
    echo: EchoTestParams = field(default_factory=EchoTestParams)
    echo_end: EchoEndParams = field(default_factory=EchoEndParams)
    still: StillLineParams = field(default_factory=StillLineParams)
    growing: GrowingMarkParams = field(default_factory=GrowingMarkParams)
    motion: MotionTipParams = field(default_factory=MotionTipParams)
    min_length_mm: float = 5.0
    learned_level: float = 0.5
    learned_extend_level: float = 0.25
    classical_level: float = 2.0
    contrast_window_mm: float = 2.0
    track_window_deg: float = 4.0
    track_window_mm: float = 2.0
    switch_ratio: float = 1.5
    full_search_every_frames: int = 5
    settled_length_mm: float = 10.0
    tip_window_mm: tuple[float, float] = (2.0, 1.0)
    tip_map_min: float = 0.3
    accel_std_mm_s2: float = 40.0
    measurement_std_mm: float = 0.3
    initial_speed_std_mm_s: float = 20.0
    gate_probability: float = 0.997
    reinit_after_rejects: int = 3
    noise_window_frames: int = 10
    confirm_after_frames: int = 3
    forget_after_frames: int = 5
    needle_radius_mm: float = 0.635
    gauge_radii_mm: tuple[float, float] = GAUGE_RADII_MM
    frame_rate_hz: float | None = None
    orientation_min_angle_deg: float = 5.0
    edge_margin_mm: float = 2.0
    tip_room_sections: int = 2
    entry_margin_mm: float = 3.0
    beam_min_angle_deg: float = 15.0
    mask_edge_mm: float = 1.5

    def __post_init__(self) -> None:
        if not 0.0 < self.learned_extend_level <= self.learned_level:
            raise ValueError(f"learned_extend_level must lie in (0, learned_level], got "
                             f"{self.learned_extend_level}")
        for name in ("min_length_mm", "learned_level", "classical_level", "contrast_window_mm",
                     "track_window_deg", "track_window_mm", "accel_std_mm_s2",
                     "measurement_std_mm", "initial_speed_std_mm_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not 0.0 < self.gate_probability < 1.0:
            raise ValueError(f"gate_probability must be in (0, 1), got {self.gate_probability}")
        if min(self.reinit_after_rejects, self.confirm_after_frames, self.forget_after_frames,
               self.full_search_every_frames) < 1:
            raise ValueError("reinit_after_rejects, confirm_after_frames, forget_after_frames "
                             "and full_search_every_frames must be >= 1")
        if not 0 <= self.tip_room_sections <= 20:
            raise ValueError(f"tip_room_sections must lie in [0, 20], got "
                             f"{self.tip_room_sections}")
        if not 2 <= self.noise_window_frames <= 10_000:
            raise ValueError(f"noise_window_frames must lie in [2, 10000], got "
                             f"{self.noise_window_frames}")
        if not 0.0 <= self.needle_radius_mm <= 10.0:
            raise ValueError(f"needle_radius_mm must lie in 0-10 mm, got {self.needle_radius_mm}")
        radius_variance(self.gauge_radii_mm, "gauge_radii_mm")  # checks the range
        if self.frame_rate_hz is not None and not self.frame_rate_hz > 0:
            raise ValueError(f"frame_rate_hz must be positive, got {self.frame_rate_hz}")
        for name in ("edge_margin_mm", "entry_margin_mm", "mask_edge_mm", "track_window_mm",
                     "contrast_window_mm", "min_length_mm", "settled_length_mm"):
            if not 0.0 <= getattr(self, name) <= MAX_DISTANCE_MM:
                raise ValueError(f"{name} must lie in 0-{MAX_DISTANCE_MM:g} mm, got "
                                 f"{getattr(self, name)}")
        if not 0.0 < self.track_window_deg <= 90.0:
            raise ValueError(f"track_window_deg must lie in (0, 90], got "
                             f"{self.track_window_deg}")
        if not 0.0 <= self.beam_min_angle_deg < 90.0:
            raise ValueError(f"beam_min_angle_deg must lie in [0, 90), got "
                             f"{self.beam_min_angle_deg}")
