"""The default in-plane tracker: the needle found wherever it enters, its tip filtered along it.

Each frame: the feature source's shaft map (a learned shaft probability, or for classical
features a line-contrast map of the image) is searched for the needle's line over the whole
frame, every direction and offset (:func:`~needlenet.backends._line_search.find_needle_line`),
or, while a needle is tracked, within a window around its last line. The line is accepted as a
needle only when its supported segment is at least ``min_length_mm`` long with mean evidence at
or above the level that marks a needle (probability 0.5 for a learned map; for the classical
map ``classical_level`` local standard deviations above the surrounding tissue), or, while no
needle is tracked, when a shorter learned mark entering through the edge of the view has grown
where it was first seen (a needle coming in; :mod:`._inplane_growing`). A new learned track
on a segment shorter than ``settled_length_mm`` must grow as well: one that has not grown by a
millimetre in half a second (``growing.prove_within_s``) is a still tissue line, dropped and
not taken again until it grows (a needle-like line in tissue where no needle is, a few
millimetres under the skin, is otherwise tracked for as long as it is in view). The tip is the
segment's end away from the entry, refined by the tip map where the source has one (with
classical features: moved on to where the echo along the line ends; on a new learned
track's first frame not past the segment's end) and bounded by where the
needle's echo ends in the image (the streak of unfocused imaging past a tip looks like shaft;
:mod:`._inplane_line_tip`), and a constant-velocity Kalman filter on the tip's (x, z) smooths
it between frames. A segment that
runs across the imaged region from edge to edge shows no tip (a bright tissue interface, or a
needle whose tip has left the view, or the edge of a capture margin or sector mask) and is not
taken for one; nor is a segment whose deeper end, where a needle's tip would be, lies at that
edge (the tip is out of view), nor, as a new needle, one whose echo in the image goes on past
its end to that edge (a shaft map may mark only part of an interface) or that ends too near
it for the image to show whether the echo ends there. A line shorter than
``settled_length_mm`` that runs along the beams is a reverberation tail, not a shaft, whose
echo comes back across them (:mod:`._beams`). A needle comes in
through the skin or the side of the view and goes in along its axis, so a segment floating in
the tissue (its entry end away from the edge of the view) is never taken for a new needle, and
once a needle has been tracked it is taken only as the continuation of the needle seen on the
frame before: on its axis, and ending where its tip is tracked (the same needle, partly out of
the plane). A new learned line that enters where the confirmed needle still held by the
filter entered (``confirm_after_frames`` tip measurements accepted in a row), but is longer
than that needle could have grown since it was seen, is the needle merged on the map
with a tissue line that runs on beside it (a bright interface): the frame is `lost`. A
confirmed needle seen running on out of view along its line (its tip has left the view), or
whose weaker continuation on a learned map runs on to the edge of the view, is `lost` too,
and while it is seen so no other line is taken for it: one needle is there. The edge
of the view is the edge of the frame, of a black capture margin or of a
sector mask; a black vessel inside the image is tissue. One needle is tracked: a needle-like
line seen beside it while it advanced is tissue, and is not taken for the needle when the
needle leaves the plane (:mod:`._inplane_still`). Where the search offers no needle line (a
needle merged with an interface, or one whose echo fades while it advances), the tip is read
where echo was gained since the frame before, on the tracked needle's line or, once seen
advancing, on a refused line that enters through the edge (:mod:`._inplane_line_motion`).

Which end is the tip. A needle goes in from the skin (the top of the image) or from beyond a
side edge and goes deeper as it advances, so of a segment that descends by more than
``orientation_min_angle_deg`` the deeper end is the tip. A near-horizontal segment's entry is
the end nearer the edge of the imaged region (black capture margins and sector masks are not
imaged region). Once a needle is tracked its orientation is kept.

Status. ``tracking`` only on a frame that shows the needle: a frame whose search finds no
needle segment reports ``lost`` (or ``searching`` before any detection) with no tip. The
filter is kept for ``forget_after_frames`` such frames, so the tip is picked up again at the
prediction when the needle reappears; after that the tracker searches the whole frame anew.
The covariance is the filter's actual error covariance (:mod:`._inplane_line_filter`),
where the centre line lies across the echo or map of a needle of unknown gauge
(``gauge_radii_mm``), and what the frame leaves unknown (:mod:`._inplane_line_tip`): along the
line, the spread of the places it offered for the tip; across it, a map band wider than a
needle's.

Mathiassen 2017's methods (``om``, ``kf+f``, ...) stay in :mod:`._inplane`, with the paper's
entry corner and 20-70 degree search; this tracker makes none of those assumptions.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from ..backends import NeedleLine, WorkingMap, chi2_gate, find_needle_line, working_map
from ..features import FeatureSource, Frame, line_contrast
from ._base import NeedleEstimate, Status, Tracker
from ._beams import along_beams
from ._details import LineDetails
from ._inplane_geometry import AROUND, behind_on_line, distance_to_edge, entry_to_tip, on_line
from ._inplane_growing import GrowingMark, StillMarks
from ._inplane_line_confirmed import ConfirmedTrack, PausedProbation
from ._inplane_line_echo import echo_along
from ._inplane_line_filter import TipKalman
from ._inplane_line_motion import MovingTip
from ._inplane_line_params import LineTrackerParams
from ._inplane_line_tip import LineTip, tip_spread_covariance
from ._inplane_motion import MotionMark, MotionTip
from ._inplane_still import StillLines
from ._margins import inner_region

__all__ = ["LineTrackerParams", "LineTracker"]

class LineTracker(LineTip, ConfirmedTrack, MovingTip, TipKalman, Tracker):
    """Whole-frame needle line search with a Kalman filter on the tip (the default in-plane
    tracker; see the module's doc).

    Parameters
    ----------
    method : ``"line"``
    features : FeatureSource, default :class:`IntensityFeatures`
    expected_angle_deg : float or None
        The insertion angle to the skin, when the user knows it: the search then takes lines
        within ``angle_window_deg`` of it, entering from either side.
    params : LineTrackerParams
    rng, seed : the common tracker interface (:class:`Tracker`); nothing here is random.
    """

    modality = "inplane"
    methods = ("line",)
    angle_window_deg = 10.0

    def __init__(self, method: str = "line", features: FeatureSource | None = None, *,
                 expected_angle_deg: float | None = None,
                 params: LineTrackerParams | None = None,
                 rng: np.random.Generator | int | None = None, seed: int | None = None):
        self.params = LineTrackerParams() if params is None else params
        if expected_angle_deg is not None and not 0.0 <= float(expected_angle_deg) <= 90.0:
            raise ValueError(f"expected_angle_deg must lie in [0, 90], got {expected_angle_deg}")
        self.expected_angle_deg = None if expected_angle_deg is None else float(
            expected_angle_deg)
        self._last_t: float | None = None
        self._dt: float | None = None
        super().__init__(method, features, rng=rng, seed=seed)

    # ------------------------------------------------------------------ state

    def reset(self) -> None:
        super().reset()
        self._axis: tuple[np.ndarray, np.ndarray] | None = None  # (point, unit direction)
        self._still = StillLines(self.params.still)
        self._still_search: tuple | None = None  # the last whole-frame frame's, not yet run
        self._growing = GrowingMark(self.params.growing)
        self._reappearing = GrowingMark(self.params.growing)  # a line after a needle left
        self._still_marks = StillMarks(self.params.growing)  # short new lines that never grew
        self._change = MotionTip(self.params.motion)  # the echo gained since the frame before
        self._motion_mark = MotionMark()  # the tip read so on the frame before
        self._held_confirmed = False  # this track has been confirmed once
        self._paused = PausedProbation(self.params.growing.near_mm)  # short tracks lost early
        self._forget()
        self._departed: tuple | None = None  # the confirmed needle last forgotten

    def _forget(self) -> None:
        self._note_departure()
        self._x: np.ndarray | None = None  # (x, z, vx, vz), mm and mm/s
        self._P: np.ndarray | None = None
        self._dir: np.ndarray | None = None  # unit, entry -> tip
        self._entry_mm: np.ndarray | None = None  # the tracked segment's entry end
        self._seen_t: float | None = None  # when the tracked needle was last seen
        self._longest_mm = 0.0  # the tracked needle's longest segment
        self._line_point: np.ndarray | None = None
        self._misses = 0
        self._rejects = 0
        self._accepted_run = 0  # tip measurements accepted by the gate in a row
        self._out_of_sight = False  # the tracked needle was last seen running out of view
        self._since_full = 0
        self._held_confirmed = False  # this track has been confirmed once
        self._pause_probation()

    @property
    def dt_s(self) -> float:
        return self._dt if self._dt is not None else 1.0 / 20.0

    def _update_dt(self, t: float) -> float:
        """Seconds since the last frame (the frame period before two frames are seen)."""
        if self.params.frame_rate_hz is not None:
            self._dt = 1.0 / self.params.frame_rate_hz
            step = self._dt
        elif self._last_t is not None and t > self._last_t:
            step = float(t - self._last_t)
            if self._dt is None:
                self._dt = step
        else:
            step = self.dt_s
        self._last_t = float(t)
        return step

    # ------------------------------------------------------------------ evidence

    def _level(self) -> float:
        return self.params.learned_level if self.features.kind == "learned" else \
            self.params.classical_level

    def _evidence(self, shaft: np.ndarray, grid, inner: np.ndarray) -> WorkingMap:
        """The evidence map (``shaft`` on ``grid``: the frame's, or the learned model's own)
        on the working grid, zero outside ``inner`` (on the frame's grid: the imaged region
        less ``mask_edge_mm`` at the edges of capture margins and sector masks, which are
        steps in the image, not echoes)."""
        p = self.params
        wm = working_map(shaft, grid, p.search.work_spacing_mm)
        values = wm.values
        if self.features.kind != "learned":
            values = line_contrast(values, int(round(p.contrast_window_mm / wm.step)))
        if not inner.all():
            keep = cv2.resize(inner.astype(np.float32), values.shape[::-1],
                              interpolation=cv2.INTER_AREA) > 0.5
            values = np.where(keep, values, 0.0).astype(np.float32)
        return WorkingMap(np.ascontiguousarray(values), wm.x0, wm.z0, wm.step)

    def _inner_region(self, frame: Frame) -> np.ndarray:
        """The imaged region less ``mask_edge_mm`` along the edges of margins and masks (the
        frame's own border is no such edge)."""
        return inner_region(frame, self.params.mask_edge_mm)

    def _validity(self, frame: Frame, inner: np.ndarray):
        """Five functions of a segment, from where its ends lie against the edge of the
        region ``inner`` (where evidence is read) and its echo in the image:

        - the test it must pass to be a needle whose tip is in view: it must not run across
          the region from edge to edge (both ends within ``edge_margin_mm`` of the edge,
          outwards along the line): that is an interface, a mask's edge, or a needle whose
          tip is out of view; nor may its deeper end, where a needle's tip would be, lie
          there; nor may its echo go on past its end to that edge (a learned map may mark
          only part of an interface; a learned segment on the axis of the needle tracked on
          the frame before is not read), nor, as a new line, may it end too near that edge
          for the echo's end to be read (``tip_room_sections``), and with classical features
          it must show along the line; it must not lie on a line seen standing still beside
          the needle; and a segment floating in the tissue is taken only as the
          continuation of the needle seen on the frame before (see the module's doc);
        - its priority: 1 when it enters through the edge (its shallower end within
          ``entry_margin_mm`` of the edge, along the line or straight: a shallow needle comes
          in through the skin a few millimetres along its own line from the top of the
          view), else 0;
        - its look alone, at a given level (long and strong enough, tip in view, echo): the
          test of a line beside the needle (:class:`StillLines`), wherever it lies.
        - whether its deeper end lies at the edge of the view (a needle running on out of
          view, :class:`~._inplane_line_confirmed.ConfirmedTrack`);
        - whether it enters within ``entry_margin_mm`` of where the tracked needle entered.
        """
        p = self.params
        reach = max(p.edge_margin_mm, p.entry_margin_mm) + 1.0
        sin_min = np.sin(np.deg2rad(p.orientation_min_angle_deg))
        cache: dict = {}

        def straight_mm(point: np.ndarray) -> float:
            """Distance (mm) from ``point`` to the edge of ``inner`` in any direction (up to
            ``reach``)."""
            return distance_to_edge(inner, frame, point, AROUND, max_mm=reach)

        def ends(seg: NeedleLine) -> tuple[float, float, float]:
            """(start's and end's distance outwards along the line, the entry end's distance
            along the line or straight, whichever is less); the entry is the shallower end of
            a descending segment, either end of a near-horizontal one."""
            key = (*seg.start_mm, *seg.end_mm)
            if key not in cache:
                a = distance_to_edge(inner, frame, seg.start_mm, -seg.direction, max_mm=reach)
                b = distance_to_edge(inner, frame, seg.end_mm, seg.direction, max_mm=reach)
                d = seg.direction
                if abs(d[1]) < sin_min:
                    entry = min(a, b, straight_mm(seg.start_mm), straight_mm(seg.end_mm))
                elif d[1] > 0:
                    entry = min(a, straight_mm(seg.start_mm))
                else:
                    entry = min(b, straight_mm(seg.end_mm))
                cache[key] = (a, b, entry)
            return cache[key]

        def enters(seg: NeedleLine) -> bool:
            return ends(seg)[2] <= p.entry_margin_mm

        def shape(seg: NeedleLine) -> str:
            a, b, _ = ends(seg)
            if abs(seg.direction[1]) < sin_min and all(
                    straight_mm(q) <= p.edge_margin_mm
                    for q in (seg.start_mm, 0.5 * (seg.start_mm + seg.end_mm), seg.end_mm)):
                return (f"the {seg.length_mm:.0f} mm line lies flat along the edge of the view "
                        "(the probe face's reverberation): no needle")
            if a <= p.edge_margin_mm and b <= p.edge_margin_mm:
                return (f"no needle tip in view: the {seg.length_mm:.0f} mm line runs across the "
                        "image from edge to edge")
            d = seg.direction
            if abs(d[1]) >= sin_min and (b if d[1] > 0 else a) <= p.edge_margin_mm:
                return (f"no needle tip in view: the {seg.length_mm:.0f} mm line's deeper end, "
                        "where a needle's tip would be, lies at the edge of the view")
            return ""

        def place(seg: NeedleLine) -> str:
            if self._still.holds(seg) and not (self._axis is not None and on_line(
                    seg, *self._axis, p.track_window_deg, p.track_window_mm)):
                return (f"the {seg.length_mm:.0f} mm line stood still beside the needle tracked "
                        "before: tissue")
            if not enters(seg):
                if self._axis is None:
                    return (f"the {seg.length_mm:.0f} mm line floats in the tissue; a needle is "
                            "first taken where it enters through the edge of the view")
                if not on_line(seg, *self._axis, p.track_window_deg, p.track_window_mm):
                    return (f"the {seg.length_mm:.0f} mm line floats in the tissue off the axis "
                            "of the needle seen entering")
                if not self._continues_track(seg):
                    return (f"the {seg.length_mm:.0f} mm line floats in the tissue on the "
                            "needle's axis, but its end is not where the tracked tip is")
            return ""

        def echo(seg: NeedleLine) -> str:
            a, b, _ = ends(seg)
            d = seg.direction
            entry_first = d[1] > 0 if abs(d[1]) >= sin_min else a <= b
            if self.features.kind != "learned":
                seen, share = echo_along(frame, seg, entry_first, p.echo)
                if not seen:
                    return (f"the {seg.length_mm:.0f} mm line's echo stands out of the tissue "
                            f"in {100 * share:.0f}% of its sections (needs "
                            f"{100 * p.echo.coverage:.0f}%, and of its entry half)")
            elif self._continues_axis(seg):
                return ""  # the needle tracked on the frame before goes on (see _continues_axis)
            oriented = seg if entry_first else seg.reversed()
            # the room past the end first: it needs no read of the image
            far = self._room_beyond(frame, inner, oriented)
            if far < p.edge_margin_mm + p.tip_room_sections * p.echo.section_mm and \
                    not self._continues_axis(seg):
                return (f"no needle tip in view: the {seg.length_mm:.0f} mm line ends "
                        f"{far:.1f} mm from the edge of the view, too near to see its echo end")
            more, far = self._echo_beyond(frame, inner, oriented)
            if more > 0 and far - more <= p.edge_margin_mm + p.echo.section_mm:
                return (f"no needle tip in view: the {seg.length_mm:.0f} mm line's echo "
                        "goes on past its end to the edge of the view")
            return ""

        def check(seg: NeedleLine) -> str:
            return shape(seg) or place(seg) or along_beams(
                frame, seg, p.beam_min_angle_deg, p.settled_length_mm) or echo(seg)

        def looks(seg: NeedleLine, level: float) -> str:
            if not (seg.length_mm >= p.min_length_mm and seg.support >= level):
                return f"the {seg.length_mm:.1f} mm line is too short or too faint for a needle"
            return shape(seg) or echo(seg)

        def priority(seg: NeedleLine) -> int:
            return int(enters(seg))

        def shares_entry(seg: NeedleLine, entry_mm: np.ndarray | None = None) -> bool:
            """It enters within ``entry_margin_mm`` of where the tracked needle (or the
            needle of ``entry_mm``) entered."""
            entry_mm = self._entry_mm if entry_mm is None else entry_mm
            if entry_mm is None:
                return False
            fresh = entry_to_tip(seg, frame, p.orientation_min_angle_deg, inner)
            return float(np.linalg.norm(fresh.start_mm - entry_mm)) <= p.entry_margin_mm

        def runs_out(seg: NeedleLine) -> bool:
            """Its deeper end (either end of a near-horizontal one) lies at the edge of the
            view: a needle whose tip is out of view, if it is a needle."""
            a, b, _ = ends(seg)
            d = seg.direction
            if abs(d[1]) < sin_min:
                return min(a, b) <= p.edge_margin_mm
            return (b if d[1] > 0 else a) <= p.edge_margin_mm

        return check, priority, looks, runs_out, shares_entry

    def _continues_axis(self, seg: NeedleLine) -> bool:
        """Whether a segment lies on the axis of the needle tracked on the frame before. A
        learned segment whose echo goes on past its end to the edge of the view is refused
        as a new needle (a piece of an interface the map marks only in part), not as the
        needle already tracked: past a needle's tip plane-wave imaging leaves a streak along
        its line, which a strong needle's echo can carry to the edge of the view."""
        p = self.params
        return self._dir is not None and not self._misses and self._axis is not None and \
            on_line(seg, *self._axis, p.track_window_deg, p.track_window_mm)

    def _continues_track(self, seg: NeedleLine) -> bool:
        """Whether a segment continues the needle seen on the frame before: its end away from
        the entry passes the filter's gate on the tip. A needle leaving the plane shows a
        floating piece of its axis, which ends at the tip only where the tip is; a piece
        elsewhere on the axis shows no tip, and once the needle has been missed nothing tells
        such a piece from tissue on the axis."""
        if self._x is None or self._dir is None or self._misses:
            return False
        end = seg.end_mm if float(seg.direction @ self._dir) >= 0 else seg.start_mm
        return self._gate_distance(end) <= chi2_gate(2, self.params.gate_probability)

    # ------------------------------------------------------------------ one frame

    def _step(self, frame: Frame) -> NeedleEstimate:
        if frame.grid.ndim != 2:
            raise ValueError(f"LineTracker needs 2-D images, got a {frame.grid.ndim}-D grid")
        dt = self._update_dt(frame.t)
        self._change.observe(frame)
        if self._still_search is not None:
            # the search for still lines beside the needle of the frame before, run before
            # this frame's lines are judged: a frame of the whole-frame search does not
            # carry it too
            args, self._still_search = self._still_search, None
            self._still.observe(*args)
        lik, map_grid = self.features.native_likelihood(frame)
        self._beyond: dict = {}  # _echo_beyond's memo for this frame
        self._out_of_view = False  # set by _search: the tracked needle's tip is out of view
        inner = self._inner_region(frame)
        wm = self._evidence(lik.shaft, map_grid, inner)
        if self._x is not None:
            self._predict_tip(dt)
        is_valid, priority, looks, runs_out, shares_entry = self._validity(frame, inner)
        seg, new_line = self._search(wm, is_valid, priority, runs_out, shares_entry)
        if self._is_needle(seg):
            self._growing.clear()
        elif not self._grown(seg, priority):
            return self._moving_tip(frame, seg, wm, inner, priority) or \
                self._missed(frame, seg, keep=self._out_of_view)
        if new_line:
            reason = self._not_inserted(seg, shares_entry)
            if reason:
                return self._missed(frame, seg, reason)
        if new_line and self._dir is not None:
            if self._outgrown(seg, frame.t, shares_entry):
                return self._moving_tip(frame, seg, wm, inner, priority) or self._missed(
                    frame, seg, (
                    f"no needle: the {seg.length_mm:.0f} mm line enters where the needle "
                    f"entered, {seg.length_mm - self._longest_mm:.0f} mm longer than the needle "
                    "could have grown since it was seen"))
            self._forget()  # another line than the one tracked: start anew
        if new_line:
            self._reappearing.clear()
        seg = self._orient(seg, frame, inner)
        reach, runs_on = self._reach_mm(seg, wm, frame, inner)
        if runs_on and self._confirmed and self._may_have_left_view(seg, frame, inner, frame.t):
            # the confirmed needle's weaker continuation runs on to an edge its tip can have
            # reached since it was seen: where the map fades at depth while the needle goes
            # on, its tip is out of view (an edge farther off: the continuation is no needle,
            # and the tip is looked for without it)
            self._out_of_view = self._out_of_sight = True
            return self._missed(frame, seg, (
                f"no needle tip in view: the {seg.length_mm:.0f} mm needle's weaker "
                "continuation on the map runs on to the edge of the view"), keep=True)
        # a new learned track's tip is not read on its weaker continuation: on one frame
        # nothing tells that from the streak past a tip of plane-wave imaging (classical
        # features read the echo on past a line-contrast segment that stops short of the tip)
        first = new_line and self.features.kind == "learned"
        tip_mm, used_tip_map, at_echo_end, spread = self._tip(
            frame, seg, lik.tip, map_grid, 0.0 if first else reach)
        reason = self._proven(seg, tip_mm, new_line, frame.t)
        if reason:
            return self._missed(frame, seg, reason)
        past = self._runs_past_gain(frame, seg, tip_mm, inner) if new_line else 0.0
        if past:
            return self._tip_before_line_end(frame, seg, past, wm, inner, priority)
        if priority(seg):  # it enters through the edge of the view: the insertion's axis
            self._axis = (0.5 * (seg.start_mm + seg.end_mm), seg.direction.copy())
        self._misses = 0
        measured, accepted, restarted, moved = self._measure(frame, seg, tip_mm, inner)
        ambiguity = tip_spread_covariance(seg.direction, spread) + \
            self._band_covariance(wm, seg, self._level())
        est = self._estimate(frame, seg, measured, used_tip_map, accepted, restarted,
                             at_echo_end, spread, ambiguity, from_motion=moved)
        if self._since_full == 0:
            # the whole frame was searched: look beside the needle for still tissue lines
            # (at the start of the next frame)
            self._still_search = (wm, self._level(), self.params.search,
                                  self._line_point.copy(), self._dir.copy(),
                                  self._x[:2].copy(), looks)
        return est

    def _search(self, wm: WorkingMap, is_valid, priority, runs_out,
                shares_entry) -> tuple[NeedleLine, bool]:
        """The needle segment of this frame, and whether it is another line than the one
        tracked (the track then starts anew). While tracking, the window around the last line
        is searched, and every ``full_search_every_frames`` frames (every frame until the
        tracked needle's segment has once been ``settled_length_mm`` long, or when the window
        holds no needle) the whole frame as well: a clearly stronger segment elsewhere
        (``switch_ratio`` times the evidence) takes over, so that a track started on a
        needle-like tissue line does not hold out against the needle; so does a segment of
        higher priority (one that enters through the edge of the view), unless it lies on the
        window's line behind its end: the same needle, whose map is split in two."""
        p = self.params
        level = self._level()

        def full():
            # while a needle is tracked its own line is read, and when it is rejected (its tip
            # has left the view) no other line is voted for in its place: one needle is there
            search = p.search if self._dir is None else replace(p.search, votes=1)
            return find_needle_line(wm, level, search, self._expected_thetas(),
                                    is_valid=is_valid, priority=priority)

        if self._dir is None:
            return full(), True
        self._since_full += 1
        th = np.arctan2(self._dir[1], self._dir[0]) % np.pi
        half = np.deg2rad(p.track_window_deg)
        thetas = th + np.linspace(-half, half, 2 * int(round(p.track_window_deg)) + 1)
        # the window around one line holds one Hough peak worth reading
        near = find_needle_line(wm, level, replace(p.search, peaks=1), thetas % np.pi,
                                prior=(self._line_point, p.track_window_mm),
                                is_valid=is_valid)
        settled = self._longest_mm >= p.settled_length_mm
        if self._is_needle(near) and self._since_full < p.full_search_every_frames and settled:
            return near, False
        if self._runs_out_on_axis(near, runs_out):
            self._since_full = 0
            return near, False
        self._since_full = 0
        other = full()
        if self._is_needle(near) and not (self._is_needle(other) and not behind_on_line(
                other, near, self._dir, p.track_window_mm) and (
                priority(other) > priority(near) or (priority(other) == priority(near) and
                                                     other.score > p.switch_ratio * near.score))):
            return near, False
        self._runs_out_on_axis(other, runs_out)
        if self._out_of_sight and self._is_needle(other) and not self._same_line(other) and \
                not shares_entry(other):
            return NeedleLine(False, (
                f"the {other.length_mm:.0f} mm line is not taken for the needle: the needle "
                "tracked runs on out of view, and one needle is there")), False
        return other, not self._same_line(other)

    def _expected_thetas(self) -> np.ndarray | None:
        """Line directions within ``angle_window_deg`` of the expected insertion angle, from
        either side; None (every direction) without one."""
        if self.expected_angle_deg is None:
            return None
        a = np.arange(-self.angle_window_deg, self.angle_window_deg + 1e-9, 1.0)
        ang = np.clip(self.expected_angle_deg + a, 0.0, 90.0)
        return np.deg2rad(np.concatenate([ang, 180.0 - ang])) % np.pi

    def _same_line(self, seg: NeedleLine) -> bool:
        """Whether ``seg`` lies within the tracking window of the tracked line."""
        if not seg or self._dir is None:
            return False
        return on_line(seg, self._line_point, self._dir, self.params.track_window_deg,
                        self.params.track_window_mm)

    def _is_needle(self, seg: NeedleLine) -> bool:
        return bool(seg) and seg.length_mm >= self.params.min_length_mm and \
            seg.support >= self._level()

    def _grown(self, seg: NeedleLine, priority) -> bool:
        """Whether ``seg``, shorter than a needle segment, is a needle's first mark: while no
        needle is tracked, a learned mark at the needle's level that enters through the edge
        of the view and has grown from there since it was first seen (:mod:`._inplane_growing`).
        Not with classical features: the ends of short segments on the line-contrast map move
        by millimetres from frame to frame on still tissue, as much as a needle grows."""
        g = self.params.growing
        if self.features.kind != "learned" or self._dir is not None or not seg or \
                seg.support < self._level() or \
                seg.length_mm < g.min_length_mm or not priority(seg):
            self._growing.missed()
            return False
        if self._growing.growth_mm(seg) < g.growth_mm:
            return False
        self._growing.clear()
        return True

    def _missed(self, frame: Frame, seg: NeedleLine, reason: str | None = None,
                keep: bool = False) -> NeedleEstimate:
        """A frame without the needle: ``lost`` (``searching`` before any detection). The
        track is forgotten after ``forget_after_frames`` such frames in a row, except while
        ``keep``: the tracked needle is seen running on out of view."""
        had = self._x is not None
        if not keep:
            self._misses += 1
        if self._misses >= self.params.forget_after_frames:
            self._forget()
        if reason is None and seg:
            reason = (f"no needle: the best line's segment is {seg.length_mm:.1f} mm long with "
                      f"mean evidence {seg.support:.2f} (needs {self.params.min_length_mm:g} mm "
                      f"at {self._level():g})")
        elif reason is None:
            reason = f"no needle: {seg.reason}"
        status = Status.LOST if had or self.status == Status.TRACKING else Status.SEARCHING
        return NeedleEstimate(t=frame.t, status=status, reason=reason)

    # ------------------------------------------------------------------ geometry

    def _orient(self, seg: NeedleLine, frame: Frame, valid: np.ndarray) -> NeedleLine:
        """The segment from its entry end to its tip end (see the module's doc)."""
        if self._dir is not None:
            return seg if float(seg.direction @ self._dir) >= 0 else seg.reversed()
        return entry_to_tip(seg, frame, self.params.orientation_min_angle_deg, valid)

    def _estimate(self, frame: Frame, seg: NeedleLine, measured_mm: np.ndarray,
                  used_tip_map: bool, accepted: bool | None, restarted: bool,
                  at_echo_end: bool, spread_mm: float, ambiguity: np.ndarray,
                  from_motion: bool = False) -> NeedleEstimate:
        self._dir = seg.direction.copy()
        self._out_of_sight = False
        self._entry_mm = seg.start_mm.copy()
        self._seen_t = frame.t
        self._longest_mm = max(self._longest_mm, seg.length_mm)
        self._line_point = 0.5 * (seg.start_mm + seg.end_mm)
        normal = np.array([-seg.direction[1], seg.direction[0]])
        if normal[1] < 0:
            normal = -normal
        entry = seg.start_mm + self._offset_mm() * normal
        tip = self._x[:2].copy()
        return NeedleEstimate(
            t=frame.t, status=Status.TRACKING, tip_mm=tip, direction=seg.direction.copy(),
            covariance=self._reported_covariance(measured_mm, accepted, restarted)
            + self._centre_line_covariance(seg.direction) + ambiguity,
            axis_point_mm=entry,
            details=LineDetails(
                entry_mm=entry,
                theta_deg=float(np.degrees(np.arctan2(seg.direction[1], abs(seg.direction[0])))),
                tip_velocity_mm_s=self._x[2:].copy(), shaft_support=seg.support,
                segment_length_mm=seg.length_mm, tip_measurement_mm=measured_mm,
                tip_from_tip_map=used_tip_map, measurement_accepted=accepted,
                restarted=restarted, tip_at_echo_end=at_echo_end, tip_spread_mm=spread_mm,
                tip_from_motion=from_motion))
