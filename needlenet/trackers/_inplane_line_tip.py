"""The `line` tracker's tip on one frame: the needle segment's far end, moved on along the
line's weaker continuation where the tip map confirms it (learned) or to where the run of
echo ends (classical), and back to where the needle's echo ends in the image. A mixin of
:class:`~._inplane_line.LineTracker`, whose state it uses (``params``, ``features`` and the
frame's memo ``_beyond``)."""

from __future__ import annotations

import numpy as np

from ..backends import NeedleLine, WorkingMap, extend_end
from ..features import Frame
from ._base import radius_variance, tip_spread_covariance
from ._inplane_echo_end import echo_end
from ._inplane_geometry import distance_to_edge, sample_grid
from ._inplane_line_echo import echo_beyond
from ._inplane_line_params import MAX_DISTANCE_MM

__all__ = ["LineTip", "band_variance", "tip_spread_covariance"]


def band_variance(wm: WorkingMap, seg: NeedleLine, level: float, half_mm: float) -> float:
    """The second moment (mm^2) of the offsets across ``seg``'s line of the map's samples at
    or above ``level`` within ``half_mm`` of it, between its ends: for a band of width w
    centred on the line, w^2 / 12, the variance of a point anywhere across it; 0 where no
    sample reaches the level."""
    d = seg.direction
    n = np.array([-d[1], d[0]])
    t = np.arange(0.0, seg.length_mm + 1e-9, wm.step)
    s = np.arange(-half_mm, half_mm + 1e-9, wm.step)
    on = wm.sample(seg.start_mm[None, None] + t[None, :, None] * d
                   + s[:, None, None] * n) >= level
    counts = on.sum(axis=1)  # samples at the level at each offset
    return float(counts @ s ** 2 / counts.sum()) if counts.any() else 0.0


class LineTip:
    """The tip of the `line` tracker's needle segment (see the module's doc)."""

    def _offset_mm(self) -> float:
        """Echo (wall facing the probe) to centre line, along the normal into the tissue."""
        if self.features.kind == "learned" and \
                getattr(self.features, "target_reference", "centerline") != "wall":
            return 0.0
        return self.params.needle_radius_mm

    def _centre_line_covariance(self, direction: np.ndarray) -> np.ndarray:
        """Where the needle's centre line lies across what the tracker reads, as a covariance
        (mm^2) across ``direction``. The echo of the wall facing the probe (classical features,
        and a learned map trained on that wall, as the shipped one) is moved to the centre line
        by the nominal radius; the needle's own radius r, spread evenly over
        ``gauge_radii_mm`` = (a, b), puts the centre line off by r less that radius: variance
        Var(r) = (b - a)^2 / 12. A map trained on the centre line marks it: no such term."""
        if self._offset_mm() == 0.0:
            return np.zeros((2, 2))
        normal = np.array([-direction[1], direction[0]])
        return radius_variance(self.params.gauge_radii_mm, "gauge_radii_mm") * \
            np.outer(normal, normal)

    def _band_covariance(self, wm: WorkingMap, seg: NeedleLine, level: float) -> np.ndarray:
        """Where the centre line lies across a map band wider than a needle's: the band's
        variance across the line (:func:`band_variance`, within the search's
        ``explained_mm``) beyond that of the band a needle of ``needle_radius_mm`` leaves at
        the level (the learned map's training target, a Gaussian of the distance to the wall
        with sigma the radius, is at half its height 2 sqrt(2 ln 2) radius wide), across
        ``seg``'s direction. A band as wide as a needle's adds nothing; one that takes in the
        blur of a deep phased-array echo or an interface beside the needle adds its width."""
        p = self.params
        width = 2.0 * np.sqrt(2.0 * np.log(2.0)) * max(p.needle_radius_mm, 0.3)
        extra = band_variance(wm, seg, level, p.search.explained_mm) - width ** 2 / 12.0
        n = np.array([-seg.direction[1], seg.direction[0]])
        return np.outer(n, n) * max(extra, 0.0)

    def _echo_beyond(self, frame: Frame, inner: np.ndarray, seg: NeedleLine
                     ) -> tuple[float, float]:
        """(how far the echo goes on past the end of ``seg``, oriented entry to tip; how far
        the edge of the view lies past that end), both mm, read once per segment and frame:
        the validity test and the tip both ask (the memo is emptied with each frame)."""
        key = (*seg.start_mm, *seg.end_mm)
        if key not in self._beyond:
            far = self._room_beyond(frame, inner, seg)
            self._beyond[key] = (echo_beyond(frame, seg, True, far, self.params.echo), far)
        return self._beyond[key]

    def _room_beyond(self, frame: Frame, inner: np.ndarray, seg: NeedleLine) -> float:
        """How far (mm) the edge of the view lies past the end of ``seg`` (oriented entry to
        tip), read once per segment and frame (the memo is emptied with each frame)."""
        key = ("room", *seg.start_mm, *seg.end_mm)
        if key not in self._beyond:
            self._beyond[key] = distance_to_edge(inner, frame, seg.end_mm, seg.direction,
                                                 max_mm=MAX_DISTANCE_MM)
        return self._beyond[key]

    def _reach_mm(self, seg: NeedleLine, wm: WorkingMap, frame: Frame,
                  inner: np.ndarray) -> tuple[float, bool]:
        """How far (mm) a needle's segment continues past its end, and whether a learned
        segment's continuation runs on to the edge of the view: on a learned map, on weaker
        evidence (down to ``learned_extend_level``, Canny's hysteresis; 0 where that
        continuation reaches the edge of the view, the tip may lie beyond it); with classical
        features, as far as its echo goes on (:func:`echo_beyond`)."""
        p = self.params
        if self.features.kind != "learned":
            return self._echo_beyond(frame, inner, seg)[0], False
        if p.learned_extend_level >= p.learned_level:
            return 0.0, False
        longer = extend_end(wm, seg, p.learned_extend_level, p.search)
        if longer is seg:
            return 0.0, False
        if distance_to_edge(inner, frame, longer.end_mm, longer.direction,
                            max_mm=p.edge_margin_mm + 1.0) <= p.edge_margin_mm:
            return 0.0, True
        return float(np.linalg.norm(longer.end_mm - seg.end_mm)), False

    def _tip(self, frame: Frame, seg: NeedleLine, tip_map, grid, reach_mm: float = 0.0
             ) -> tuple[np.ndarray, bool, bool, float]:
        """The tip (x, z) on the centre line, whether the tip map placed it, whether it was
        moved back to the end of the echo, and how far apart (mm, along the line) the places
        the frame offered for the tip lie: the segment's far end, moved to the tip map's
        maximum when the map is confident there, searched from ``tip_window_mm`` behind the
        end to its window ahead of the end's weaker continuation (``reach_mm`` long): weaker
        shaft evidence moves the tip only where the tip map confirms it; with classical
        features, to where the echo's run ends. A tip that lies past where the needle's echo
        ends in the image (:func:`echo_end`: a map, or the run of echo, follows the streak of
        unfocused imaging) is moved back there, and to the tip map's maximum within
        ``tip_window_mm`` of it. The places: the segment's end, its continuation's end, the
        tip map's choice, the echo's end and the tip."""
        p = self.params
        normal = np.array([-seg.direction[1], seg.direction[0]])
        if normal[1] < 0:
            normal = -normal  # into the tissue (away from the probe)
        end = seg.end_mm
        used = False
        if tip_map is not None:
            end, used = self._tip_map_max(tip_map, grid, end, seg.direction, reach_mm)
        else:  # the classical echo itself goes on this far (see _reach_mm)
            end = end + reach_mm * seg.direction
        places = [seg.length_mm, seg.length_mm + reach_mm,
                  float((end - seg.start_mm) @ seg.direction)]
        along = echo_end(frame, seg.start_mm, seg.direction, places[-1], p.echo_end)
        if along is not None:
            end, used = seg.start_mm + along * seg.direction, False
            if tip_map is not None:
                end, used = self._tip_map_max(tip_map, grid, end, seg.direction, 0.0, end)
            places += [along, float((end - seg.start_mm) @ seg.direction)]
        return (end + self._offset_mm() * normal, used, along is not None,
                max(places) - min(places))

    def _tip_map_max(self, tip_map, grid, end: np.ndarray, d: np.ndarray, reach_mm: float,
                     default: np.ndarray | None = None) -> tuple[np.ndarray, bool]:
        """The tip map's maximum on the line from ``tip_window_mm`` behind ``end`` to its
        window ahead of ``end`` moved on by ``reach_mm``, where it reaches ``tip_map_min``;
        else (``default``, or ``end``; False)."""
        p = self.params
        back, ahead = p.tip_window_mm
        s = np.arange(-back, reach_mm + ahead + 1e-9, p.search.work_spacing_mm / 2)
        pts = end[None] + s[:, None] * d[None]
        vals = sample_grid(np.asarray(tip_map, np.float32), grid, pts)
        k = int(np.argmax(vals))
        if vals[k] >= p.tip_map_min:
            return pts[k], True
        return (end if default is None else default), False
