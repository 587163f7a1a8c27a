"""The `line` tracker's rules for a confirmed track (``confirm_after_frames`` tip measurements
accepted in a row): a new line from its entry longer than the needle could have grown is the
needle merged with a tissue line beside it, a needle seen running on out of view (where its
tip can have reached the edge since it was seen) holds the track, and once a confirmed needle
has vanished, a line elsewhere is taken only when it grows as an insertion does; and before a
short new track may be confirmed it must grow at all (``_proven``). A mixin of
:class:`~._inplane_line.LineTracker`, whose state it reads (``params``, ``features``, the
filter and the tracked line) and whose frame flags it sets."""

from __future__ import annotations

import numpy as np

from ..backends import NeedleLine, chi2_gate
from ._inplane_geometry import distance_to_edge, on_line
from ._inplane_growing import line_middle, runs_along

__all__ = ["ConfirmedTrack", "PausedProbation"]


class ConfirmedTrack:
    """What a confirmed track rules out (see the module's doc)."""

    _unproven: _Unproven | None = None  # a new track on a short line, until it grows

    @property
    def _confirmed(self) -> bool:
        return self._accepted_run >= self.params.confirm_after_frames

    def _outgrown(self, seg: NeedleLine, t: float, shares_entry) -> bool:
        """Whether ``seg``, another line than the one tracked, enters within
        ``entry_margin_mm`` of where the confirmed needle still held by the filter entered
        (``confirm_after_frames``) but is longer
        than that needle could have grown since it was last seen: at the filter's speed prior
        (``initial_speed_std_mm_s``, at its gate's probability) plus the search's bridged gap.
        That is the same insertion merged on the map with a tissue line that runs on beside it
        (an interface), not the needle's new line. Learned features only: with classical ones
        a confirmed track can itself be a needle-like tissue line entering where the needle
        does, and the longer line from that entry the needle."""
        if self.features.kind != "learned" or self._x is None or self._entry_mm is None or \
                self._seen_t is None or not self._confirmed:
            return False
        if not shares_entry(seg):
            return False
        return seg.length_mm - self._longest_mm > self._growth_bound_mm(t)

    def _growth_bound_mm(self, t: float) -> float:
        """How far (mm) the needle can have advanced since it was last seen: the filter's
        speed prior (``initial_speed_std_mm_s``, at its gate's probability) times the time
        since, plus the search's bridged gap."""
        p = self.params
        speed = p.initial_speed_std_mm_s * chi2_gate(1, p.gate_probability)
        return speed * max(t - self._seen_t, self.dt_s) + p.search.gap_mm

    def _may_have_left_view(self, seg: NeedleLine, frame, inner: np.ndarray, t: float) -> bool:
        """Whether the confirmed needle's tip may lie out of view along ``seg`` (oriented
        entry to tip) where a weaker continuation of the map runs on to the edge. Not where
        the tip is seen advancing (the filter's speed along the needle above its uncertainty
        at the gate's probability) and the edge lies beyond :meth:`_growth_bound_mm` of the
        tip the filter predicts: the continuation then runs ahead of a tip that moves with
        the needle (the streak past the tip of plane-wave imaging, or tissue beyond it). A
        tip that has stopped while the map runs on may be a needle fading on the map as it
        goes on: its tip may be anywhere along the continuation."""
        if self._x is None or self._seen_t is None:
            return True
        d = np.asarray(seg.direction, float)
        speed = float(self._x[2:] @ d)
        spread = float(np.sqrt(max(d @ self._P[2:, 2:] @ d, 0.0)))
        if not speed > chi2_gate(1, self.params.gate_probability) * spread:
            return True
        bound = self._growth_bound_mm(t)
        room = distance_to_edge(inner, frame, self._x[:2], seg.direction, max_mm=bound + 1.0)
        return room <= bound

    def _runs_out_on_axis(self, seg: NeedleLine, runs_out) -> bool:
        """Whether the search result ``seg`` is the confirmed needle (``confirm_after_frames``)
        refused because it runs on out of view along its tracked line: its tip has left the
        view, and until it is seen again or forgotten no other line is taken for it (one
        needle is there). Sets ``_out_of_view`` for this frame and ``_out_of_sight`` until
        then."""
        r = seg.refused
        if seg or r is None or not self._confirmed or not runs_out(r) or \
                not self._same_line(r):
            return False
        self._out_of_view = self._out_of_sight = True
        return True

    def _note_departure(self) -> None:
        """Remember the needle about to be forgotten, if its track was ever confirmed: its line
        and its entry."""
        if self._held_confirmed and self._dir is not None and self._entry_mm is not None:
            self._departed = (self._line_point.copy(), self._dir.copy(), self._entry_mm.copy())

    def _not_inserted(self, seg: NeedleLine, shares_entry) -> str:
        """Why ``seg``, a new line, is not taken for a needle: '' when it may be. A confirmed
        needle does not give way within a frame to another needle elsewhere: a new insertion
        takes time and shows itself growing where it enters. What does appear when a needle
        leaves the plane is tissue: lines its shadow or its echo hid, or a needle-like line
        the search ranked below it. So once a needle whose track was confirmed is gone (or
        while it is tracked and the search offers another line), a line that neither lies on
        its line nor enters where it entered (the needle back in the plane) is taken only
        once it has grown by ``growing.growth_mm`` where it was first seen. The needle gone
        stays the reference until a new insertion is seen or another track is confirmed.
        Learned features only (see ``_grown``)."""
        p = self.params
        gone = self._departed
        if self._dir is not None and self._held_confirmed:
            gone = (self._line_point, self._dir, self._entry_mm)
        if gone is None or self.features.kind != "learned":
            return ""
        point, direction, entry = gone
        if on_line(seg, point, direction, p.track_window_deg, p.track_window_mm) or \
                shares_entry(seg, entry):
            return ""
        if self._reappearing.growth_mm(seg) >= p.growing.growth_mm:
            self._departed = None  # a new insertion: the needle gone is no reference now
            return ""
        return (f"no needle: the {seg.length_mm:.0f} mm line appeared elsewhere when the needle "
                "tracked was lost; it is taken once it grows where it enters, as an insertion")

    def _pause_probation(self) -> None:
        """The track is forgotten: a short one still on probation keeps it, paused."""
        if self._unproven is not None:
            self._paused.pause(self._unproven)
        self._unproven = None

    def _proven(self, seg: NeedleLine, tip_mm: np.ndarray, new_line: bool, t: float) -> str:
        """Why ``seg`` (oriented entry to tip), its tip measured at ``tip_mm``, is not (or no
        longer) taken for a needle: '' when it may be. A new learned track on a segment
        shorter than ``settled_length_mm`` must grow, as an insertion does, by
        ``growing.growth_mm`` along its line: its segment's far end, or its measured tip on
        two frames in a row. One that has not (nor come to be ``settled_length_mm`` long)
        ``growing.prove_within_s`` after it was first taken, and at least
        ``confirm_after_frames`` frame periods, is dropped as a still tissue line; a new line
        along it is taken once its far end or tip lies ``growing.growth_mm`` beyond the
        furthest the still line's reached, and is then a needle that has grown. A short track
        lost before either keeps its probation (:class:`PausedProbation`): a new track along
        it goes on from its first sighting. Either
        measure alone fails somewhere: the segment of a needle coming in bright at a corner
        runs millimetres past its tip and may keep its far end while the tip advances, and
        beside an interface it may slide along; the tip measured on a still line may jump by
        a millimetre between the segment's end and the tip map's maximum on alternate frames.
        Learned features only: a faint needle's line-contrast map splits into an entering
        piece that keeps its place and a distal piece that advances
        (``test_inplane_line_split.py``), so with classical features the piece tracked may
        show no advance of an insertion."""
        p = self.params
        g = p.growing.growth_mm
        if self.features.kind != "learned":
            return ""
        if new_line:
            self._unproven = None
            beyond = self._still_marks.advance_mm(seg, tip_mm)
            if beyond is not None and beyond < g:
                return (f"no needle: the {seg.length_mm:.0f} mm line lies on a short line that "
                        "stood still; it is taken once it grows, as an insertion")
            if beyond is not None:
                return ""  # grown past the still line: an insertion
            self._unproven = self._paused.resume(seg)
            if self._unproven is None:
                if seg.length_mm < p.settled_length_mm:
                    self._unproven = _Unproven(seg, tip_mm, t)
                return ""
        u = self._unproven
        if u is None:
            return ""
        end = float((seg.end_mm - u.end0_mm) @ seg.direction)
        tip = float((tip_mm - u.tip0_mm) @ seg.direction)
        tip_grown = tip >= g and u.tip_grown
        u.tip_grown = tip >= g
        u.far_end_mm, u.far_tip_mm = max(u.far_end_mm, end), max(u.far_tip_mm, tip)
        if end >= g or tip_grown or seg.length_mm >= p.settled_length_mm:
            self._unproven = None
            return ""
        if t - u.t0 < max((p.confirm_after_frames - 0.5) * self.dt_s,
                          p.growing.prove_within_s - 0.5 * self.dt_s):
            return ""
        self._still_marks.add(seg, u.end0_mm + max(u.far_end_mm, 0.0) * seg.direction,
                              u.tip0_mm + max(u.far_tip_mm, 0.0) * seg.direction)
        self._unproven = None  # judged: not kept on probation by _forget
        self._forget()
        return (f"no needle: the {seg.length_mm:.0f} mm line has not grown in "
                f"{t - u.t0:.2f} s: a still tissue line, not an insertion")


class _Unproven:
    """A new track on a short segment, until it grows: where its line lies (its first
    segment's middle and direction), its first far end and tip, and the furthest each has
    advanced since."""

    def __init__(self, seg: NeedleLine, tip_mm: np.ndarray, t: float):
        self.t0 = t
        self.middle_mm = line_middle(seg)
        self.direction = np.asarray(seg.direction, float).copy()
        self.end0_mm = np.asarray(seg.end_mm, float).copy()
        self.tip0_mm = np.asarray(tip_mm, float).copy()
        self.far_end_mm = self.far_tip_mm = 0.0
        self.tip_grown = False  # the tip was growth_mm on on the frame before


class PausedProbation:
    """Short new tracks lost before they grew or ran out their time: a line whose map
    flickers about the least segment length is lost and taken again every few frames, and
    each new track would start its probation anew. A new track along one of them (the
    :class:`StillMarks` rule) goes on with its probation instead, from its first sighting."""

    def __init__(self, near_mm: float):
        self.near_mm = near_mm
        self._held: list[_Unproven] = []

    def pause(self, u: _Unproven) -> None:
        if len(self._held) >= _MAX_PAUSED:
            del self._held[0]  # the oldest goes first
        self._held.append(u)

    def resume(self, seg: NeedleLine) -> _Unproven | None:
        """The paused probation ``seg`` runs along, taken out of the pause (its tip's
        two-frame count starts again); None when there is none."""
        for i, u in enumerate(self._held):
            if runs_along(seg, u.middle_mm, u.direction, self.near_mm):
                del self._held[i]
                u.tip_grown = False
                return u
        return None


_MAX_PAUSED = 32  # probations kept paused: a bound on memory, not a setting
