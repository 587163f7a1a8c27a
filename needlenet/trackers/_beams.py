"""The direction of the ultrasound beams through a point of a 2-D frame, from the shape of the
imaged region.

A linear array's beams run straight down, a phased or convex array's fan out from an apex
(the virtual apex of a convex array). The imaged region shows which: its left and right edges
are the outermost beams (of its largest connected part: the image, not a grey-scale bar or
text in the margin). Two straight side edges that converge meet at the apex; two parallel
ones (a linear array, or one steered to a slant) give the beams' direction; a frame with no
side edge in view (a linear array's image filling the frame) or only one, upright, has beams
along the depth axis (so, wrongly, has a crop from inside a sector: crop a sector with its
black sides). Where one slanted side edge is in view, or the edges are not straight, the
beams are not known.

A needle's shaft echoes back to the probe where the beam meets it across (specular
reflection); a line that runs along the beams is a reverberation tail ("comet tail") under
a bright reflector, or a needle that the beams graze and that shows little shaft.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..backends import NeedleLine
from ..features import Frame
from ._margins import imaged_region

__all__ = ["BeamGeometry", "along_beams", "beam_geometry"]

_MIN_ROWS = 12  # rows of a side edge needed to fit it
_STRAIGHT_PX = 1.5  # rows this near (pixels) an edge's fitted line lie on it
_PARALLEL_DEG = 1.0  # side edges within this of each other are parallel beams


@dataclass(frozen=True)
class BeamGeometry:
    """``apex_mm``: the (x, z) point the beams fan out from, or None for parallel beams along
    ``direction`` (unit (x, z), pointing deeper)."""

    apex_mm: np.ndarray | None = None
    direction: np.ndarray | None = None

    def at(self, point_mm: np.ndarray) -> np.ndarray:
        """The unit beam direction (pointing deeper) through ``point_mm``."""
        if self.apex_mm is None:
            return self.direction
        d = np.asarray(point_mm, float) - self.apex_mm
        n = float(np.hypot(*d))
        return d / n if n > 0 else np.array([0.0, 1.0])

    def angle_deg(self, point_mm: np.ndarray, direction: np.ndarray) -> float:
        """The angle (0-90 degrees) between a line along ``direction`` through ``point_mm``
        and the beam there."""
        d = np.asarray(direction, float)
        c = abs(float(d @ self.at(point_mm))) / max(float(np.hypot(*d)), 1e-12)
        return float(np.degrees(np.arccos(min(c, 1.0))))


def beam_geometry(frame: Frame) -> BeamGeometry | None:
    """The frame's beams from its imaged region (see the module's doc); None where they are
    not known. Read once per frame (kept in ``frame.extras``)."""
    if "beam_geometry" not in frame.extras:
        frame.extras["beam_geometry"] = _from_region(imaged_region(frame), frame.grid)
    return frame.extras["beam_geometry"]


def along_beams(frame: Frame, seg: NeedleLine, min_angle_deg: float, below_mm: float) -> str:
    """Why a segment shorter than ``below_mm`` that runs within ``min_angle_deg`` of the
    frame's beams is no needle's shaft ('' for any other segment, or where the beams are not
    known); the frame's beams are read only when a short segment asks."""
    if seg.length_mm >= below_mm:
        return ""
    geometry = beam_geometry(frame)
    if geometry is None:
        return ""
    angle = geometry.angle_deg(0.5 * (seg.start_mm + seg.end_mm), seg.direction)
    if angle < min_angle_deg:
        return (f"the {seg.length_mm:.0f} mm line runs {angle:.0f} degrees from the beams: a "
                "reverberation tail, not a needle's shaft")
    return ""


def _side_edges(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows with imaged pixels, and each one's first and last imaged column."""
    rows = np.flatnonzero(valid.any(axis=1))
    sub = valid[rows]
    first = np.argmax(sub, axis=1)
    last = valid.shape[1] - 1 - np.argmax(sub[:, ::-1], axis=1)
    return rows, first, last


def _fit_edge(rows: np.ndarray, cols: np.ndarray, top: float, span: float
              ) -> tuple[float, float] | None:
    """(column at row 0, columns per row) of a straight edge through (rows, cols), or None
    when too few rows hold it or it is not straight (a ragged mask). The line is fitted to
    the rows between 10% and 60% of the imaged depth below ``top`` (``span`` rows), where a
    sector's side runs straight between its top and bottom arcs, then again to every row
    within ``_STRAIGHT_PX`` of it: the side wherever it is the edge, the arcs left out."""
    upper = (rows >= top + 0.1 * span) & (rows <= top + 0.6 * span)
    if upper.sum() < _MIN_ROWS:
        return None
    r, c = rows.astype(float), cols.astype(float)
    slope, icpt = np.polyfit(r[upper], c[upper], 1)
    on = np.abs(c - (icpt + slope * r)) <= _STRAIGHT_PX
    if on.sum() < max(_MIN_ROWS, 0.5 * upper.sum()):
        return None  # the edge is not straight where a side would be
    slope, icpt = np.polyfit(r[on], c[on], 1)
    return float(icpt), float(slope)


def _largest_part(valid: np.ndarray) -> np.ndarray:
    """The largest connected part of the imaged region: the image, without a grey-scale bar,
    a logo or text left in the margin beside it."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(valid.astype(np.uint8),
                                                           connectivity=8)
    if n <= 2:
        return valid
    return labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))


def _from_region(valid: np.ndarray, grid) -> BeamGeometry | None:
    w = valid.shape[1]
    rows, first, last = _side_edges(_largest_part(valid))
    if rows.size == 0:
        return None
    span = float(rows[-1] - rows[0])
    on_left = first > 0  # the edge is the region's, not the frame's
    on_right = last < w - 1
    if not on_left.any() and not on_right.any():
        return BeamGeometry(direction=np.array([0.0, 1.0]))  # no side edge: a linear image
    left = _fit_edge(rows[on_left], first[on_left], rows[0], span)
    right = _fit_edge(rows[on_right], last[on_right], rows[0], span)
    dz, dx = grid.spacing_mm
    one = left if not on_right.any() else right if not on_left.any() else None
    if one is not None and abs(np.degrees(np.arctan(one[1] * dx / dz))) <= _PARALLEL_DEG:
        # one straight upright edge, the image running on out of the frame on the other
        # side: a linear image (a sector's side is never upright)
        return BeamGeometry(direction=np.array([0.0, 1.0]))
    if left is None or right is None:
        return None
    oz, ox = grid.origin_mm
    # each edge as x = a + b z in mm
    (al, bl), (ar, br) = ((ox + dx * (c0 - s * oz / dz), s * dx / dz) for c0, s in (left, right))
    if abs(np.degrees(np.arctan(bl) - np.arctan(br))) <= _PARALLEL_DEG:
        d = np.array([0.5 * (bl + br), 1.0])
        return BeamGeometry(direction=d / np.hypot(*d))
    z = (ar - al) / (bl - br)
    if z >= oz + dz * rows[0] + 0.2 * dz * span:
        return None  # the edges meet inside the image or below it: no fan of beams
    return BeamGeometry(apex_mm=np.array([al + bl * z, z]))
