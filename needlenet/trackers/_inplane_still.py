"""Needle-like lines that stood still beside the needle: tissue, not a needle.

One needle is tracked. While it advances, any other line in the same frame that would pass
for a needle (a straight echo entering through the edge of the view and ending inside it)
cannot be that needle: it is a tissue structure, a fascia, a vessel wall, a tendon, which
on a frame without the needle nothing tells from a faint needle. The `line` tracker looks for
such lines on the frames on which it searches the whole frame, with the tracked needle's
own echo band set aside, and refuses them later: when the needle leaves the plane, a line it
had been seen beside is not taken for it.

A line is recorded only once it has been seen twice at the same place while the tracked tip
moved ``advance_mm`` in between: the needle advanced and the line stood still. A probe moved
by hand moves both (neither is recorded), and a track that sits on a still tissue line itself
does not advance, so a needle beside it is never taken for tissue. Lines within ``band_mm`` of
the tracked line are its own echo and reverberations, not rivals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backends import LineSearchParams, NeedleLine, WorkingMap, find_needle_line
from ._inplane_geometry import on_line

__all__ = ["StillLineParams", "StillLines"]

_MAX_SEEN = 64  # sightings kept until seen again: a bound on memory, not a setting


@dataclass(frozen=True)
class StillLineParams:
    """``advance_mm``: how far the tracked tip must have moved between two sightings of a line
    at the same place for the line to be taken for tissue (3 mm: ten times the tip
    measurement's noise, three times the jitter of a map's end). ``band_mm``: half-width of
    the tracked needle's own echo, with its reverberation tail, set aside in that search (5
    mm: four reverberation lines a 14 G lumen apart, and the search's 2 mm band).
    ``window_deg``/``window_mm``: a later line within these of a still line is that line.
    ``level_ratio``: lines are looked for at this fraction of the level that marks a needle
    (Canny's hysteresis: a line just under the level beside the needle, in its clutter, may
    stand just over it once the needle has gone)."""

    advance_mm: float = 3.0
    band_mm: float = 5.0
    window_deg: float = 4.0
    window_mm: float = 2.0
    level_ratio: float = 0.5

    def __post_init__(self) -> None:
        if not 0.0 < self.level_ratio <= 1.0:
            raise ValueError(f"level_ratio must lie in (0, 1], got {self.level_ratio}")
        for name in ("advance_mm", "band_mm", "window_deg", "window_mm"):
            if not 0.0 < getattr(self, name) <= 100.0:
                raise ValueError(f"{name} must lie in (0, 100], got {getattr(self, name)}")


class StillLines:
    """The still lines seen beside the tracked needle (see the module's doc)."""

    def __init__(self, params: StillLineParams | None = None):
        self.params = StillLineParams() if params is None else params
        self.lines: list[tuple[np.ndarray, np.ndarray]] = []  # (point, unit direction)
        self._seen: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (+ tip then)

    def holds(self, seg: NeedleLine) -> bool:
        """Whether ``seg`` lies on a line seen standing still beside the needle."""
        return self._on(seg, self.lines) is not None

    def _on(self, seg: NeedleLine, lines) -> int | None:
        p = self.params
        for k, (point, d, *_) in enumerate(lines):
            if on_line(seg, point, d, p.window_deg, p.window_mm):
                return k
        return None

    def observe(self, wm: WorkingMap, level: float, search: LineSearchParams,
                needle_point: np.ndarray, needle_dir: np.ndarray, tip_mm: np.ndarray,
                looks) -> None:
        """Search ``wm`` once more with the tracked needle's band (around the line through
        ``needle_point`` along ``needle_dir``) set aside, at ``level_ratio`` of ``level``;
        a line found whose look passes ``looks`` (a function of a segment and the level: ''
        for a needle's, else why not), wherever it lies (beside the needle it may show only
        the part out of its band), is noted with the tracked tip ``tip_mm``, and recorded
        when it is found again there after the tip has moved ``advance_mm``."""
        p = self.params
        h, w = wm.values.shape
        n = np.array([-needle_dir[1], needle_dir[0]])
        x = wm.x0 + wm.step * np.arange(w)
        z = wm.z0 + wm.step * np.arange(h)
        off = (x[None, :] - needle_point[0]) * n[0] + (z[:, None] - needle_point[1]) * n[1]
        rest = WorkingMap(np.where(np.abs(off) > p.band_mm, wm.values, 0.0).astype(np.float32),
                          wm.x0, wm.z0, wm.step)
        low = p.level_ratio * level
        seg = find_needle_line(rest, low, search, is_valid=lambda s: looks(s, low))
        if not seg or self.holds(seg):
            return
        k = self._on(seg, self._seen)
        if k is None:
            if len(self._seen) >= _MAX_SEEN:
                del self._seen[0]  # the oldest sighting goes first
            self._seen.append((0.5 * (seg.start_mm + seg.end_mm), seg.direction.copy(),
                               np.array(tip_mm, float)))
        elif np.linalg.norm(np.asarray(tip_mm) - self._seen[k][2]) >= p.advance_mm:
            point, d, _ = self._seen.pop(k)
            self.lines.append((point, d))
