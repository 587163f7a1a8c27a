"""A needle's first mark: shorter than a needle segment, but growing where it enters.

A needle coming into the view shows first as a short mark at the edge, a few millimetres
long, which a search for needle segments of ``min_length_mm`` does not take: a short
needle-like mark is as often a piece of tissue. What tells them apart is insertion: the
needle's mark grows while it stays where it was, its tip end moving on. A tissue mark stands
still and keeps its length (its ends jitter by the map's noise, some tenths of a millimetre),
and one moved by the probe moves as a whole.

:class:`GrowingMark` keeps the first sighting of a short mark that enters through the edge of
the view and tells, on each later frame, how much longer the same mark is (a mark that passes
within ``near_mm`` of the first sighting's middle; not its direction: a mark a few
millimetres long at the edge of a sector is a blob whose line's direction is a guess); the
`line` tracker takes it for a needle once it has grown by ``growth_mm``.

The same holds for a new track on a line a little longer than a needle segment's least: it
stays only if it grows within ``prove_within_s``. :class:`StillMarks` keeps those that did
not, so that the tracker takes a line there again only once it reaches further than they had.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backends import NeedleLine

__all__ = ["GrowingMarkParams", "GrowingMark", "StillMarks", "line_middle", "runs_along"]


@dataclass(frozen=True)
class GrowingMarkParams:
    """``min_length_mm``: the shortest mark remembered (2 mm: some twenty pixels of a fine
    grid, a few speckle cells). ``growth_mm``: how much longer than at its first sighting the
    mark must be to be taken for a needle (1 mm: three times the jitter of a map's end on a
    still mark). ``near_mm``: a later mark that passes this close to the first sighting's
    middle is the same mark (the `line` tracker's ``track_window_mm``: a needle's echo band
    with the point spread of a phased array a few centimetres deep).
    ``forget_after_frames``: frames without the mark after which its sighting is dropped.
    ``prove_within_s``: a new track on a short line that has not grown by ``growth_mm`` in
    this time is a still line (0.5 s: a needle coming in at 2 mm/s, a slow hand, has advanced
    a millimetre by then)."""

    min_length_mm: float = 2.0
    growth_mm: float = 1.0
    near_mm: float = 2.0
    forget_after_frames: int = 5
    prove_within_s: float = 0.5

    def __post_init__(self) -> None:
        for name in ("min_length_mm", "growth_mm", "near_mm"):
            if not 0.0 < getattr(self, name) <= 100.0:
                raise ValueError(f"{name} must lie in (0, 100] mm, got {getattr(self, name)}")
        if not 0.0 < self.prove_within_s <= 60.0:
            raise ValueError(f"prove_within_s must lie in (0, 60] s, got {self.prove_within_s}")
        if self.forget_after_frames < 1:
            raise ValueError(f"forget_after_frames must be >= 1, got "
                             f"{self.forget_after_frames}")


class GrowingMark:
    """The first sighting of a short entering mark, and its growth since (see the module's
    doc)."""

    def __init__(self, params: GrowingMarkParams | None = None):
        self.params = GrowingMarkParams() if params is None else params
        self.clear()

    def clear(self) -> None:
        self._middle: np.ndarray | None = None
        self._length = 0.0
        self._unseen = 0

    def missed(self) -> None:
        """A frame without a short entering mark."""
        self._unseen += 1
        if self._unseen >= self.params.forget_after_frames:
            self.clear()

    def growth_mm(self, seg: NeedleLine) -> float:
        """How much longer ``seg`` is than at its first sighting (0 on the first sighting,
        which it becomes when it is not the mark seen before)."""
        self._unseen = 0
        if self._middle is not None and _passes_near(seg, self._middle, self.params.near_mm):
            return float(seg.length_mm - self._length)
        self._middle = line_middle(seg)
        self._length = float(seg.length_mm)
        return 0.0


def line_middle(seg: NeedleLine) -> np.ndarray:
    """The middle (x, z) mm of ``seg``."""
    return 0.5 * (np.asarray(seg.start_mm, float) + np.asarray(seg.end_mm, float))


def _passes_near(seg: NeedleLine, point: np.ndarray, near_mm: float) -> bool:
    """Whether the segment ``seg`` passes within ``near_mm`` of ``point``."""
    t = np.clip((point - seg.start_mm) @ seg.direction, 0.0, seg.length_mm)
    return float(np.linalg.norm(seg.start_mm + t * seg.direction - point)) <= near_mm


_MAX_MARKS = 32  # still marks remembered: a bound on memory, not a setting
# a line within this of a still mark's direction is that mark seen again (the direction of a
# few millimetres of map jitters by some degrees; a line crossing the mark is another line)
_SAME_LINE_DEG = 20.0


class StillMarks:
    """Short lines that were tracked as new needles but never grew: tissue. A line along one
    of them (through its middle, within ``near_mm``, and within ``_SAME_LINE_DEG`` of its
    direction) is taken for a needle only once its far end or its measured tip lies
    ``growth_mm`` beyond the furthest the mark's reached (see
    :meth:`~._inplane_line_confirmed.ConfirmedTrack._proven`)."""

    def __init__(self, params: GrowingMarkParams | None = None):
        self.params = GrowingMarkParams() if params is None else params
        self._marks: list[tuple[np.ndarray, ...]] = []  # (middle, direction, far end, far tip)

    def add(self, seg: NeedleLine, far_end_mm: np.ndarray, far_tip_mm: np.ndarray) -> None:
        """``seg``, oriented entry to tip, whose far end and measured tip reached
        ``far_end_mm`` and ``far_tip_mm`` at the furthest."""
        if len(self._marks) >= _MAX_MARKS:
            del self._marks[0]  # the oldest goes first
        self._marks.append((line_middle(seg), np.asarray(seg.direction, float).copy(),
                            np.asarray(far_end_mm, float).copy(),
                            np.asarray(far_tip_mm, float).copy()))

    def advance_mm(self, seg: NeedleLine, tip_mm: np.ndarray) -> float | None:
        """How far the far end of ``seg`` (oriented entry to tip), or ``tip_mm`` measured on
        it, lies beyond the furthest of the still mark it runs along, along ``seg``; None when
        it runs along none."""
        for middle, direction, far_end, far_tip in self._marks:
            if runs_along(seg, middle, direction, self.params.near_mm):
                return max(float((np.asarray(seg.end_mm, float) - far_end) @ seg.direction),
                           float((np.asarray(tip_mm, float) - far_tip) @ seg.direction))
        return None


def runs_along(seg: NeedleLine, middle: np.ndarray, direction: np.ndarray,
               near_mm: float) -> bool:
    """Whether ``seg`` is the line through ``middle`` along ``direction`` seen again: it
    passes within ``near_mm`` of the middle, within ``_SAME_LINE_DEG`` of the direction."""
    return abs(float(np.asarray(direction, float) @ seg.direction)) >= \
        np.cos(np.deg2rad(_SAME_LINE_DEG)) and _passes_near(seg, middle, near_mm)
