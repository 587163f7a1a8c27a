"""Geometry of the `line` tracker's segments against the frame: whether a segment runs on a
line, which of its ends is the entry, where the imaged region is (capture margins and sector
masks are not), and how far a point lies from that region's edge.

Black is what a margin or the outside of a sector holds: exactly 0 in an image that was
written as it was formed, a few grey levels after lossy compression (a frame-grabbed video,
a JPEG screen capture rings around the sector's edge). An 8-bit pixel at or under
``BLACK_GREY`` counts as black; :func:`zero_margins` sets the margin of such a frame to 0, so
that everything read from the frame afterwards (the learned model's input, the line contrast,
the tissue's grey level) sees the margin it would see uncompressed."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from ..backends import NeedleLine
from ..features import Frame

__all__ = ["on_line", "entry_to_tip", "sample_grid", "imaged_region", "zero_margins",
           "distance_to_edge", "AROUND", "BLACK_GREY"]

BLACK_GREY = 12  # 8-bit grey levels: JPEG ringing beside a black margin (quality 40: <= 10)


def on_line(seg: NeedleLine, point: np.ndarray, direction: np.ndarray, window_deg: float,
             window_mm: float) -> bool:
    """Whether ``seg`` runs within ``window_deg`` of the line (``point``, ``direction``) with
    its midpoint within ``window_mm`` of it."""
    cos = abs(float(seg.direction @ direction))
    n = np.array([-direction[1], direction[0]])
    mid = 0.5 * (seg.start_mm + seg.end_mm)
    return cos >= np.cos(np.deg2rad(window_deg)) and abs(float((mid - point) @ n)) <= window_mm


def entry_to_tip(seg: NeedleLine, frame: Frame, min_angle_deg: float,
                  valid: np.ndarray) -> NeedleLine:
    """``seg`` from its entry end to its tip end: the deeper end is the tip of a segment that
    descends by ``min_angle_deg`` or more; else the entry is the end nearer the edge of the
    imaged region."""
    d = seg.direction
    if abs(d[1]) >= np.sin(np.deg2rad(min_angle_deg)):
        return seg if d[1] > 0 else seg.reversed()
    a = distance_to_edge(valid, frame, seg.start_mm, -d)
    b = distance_to_edge(valid, frame, seg.end_mm, d)
    return seg if a <= b else seg.reversed()


def sample_grid(values: np.ndarray, grid, pts: np.ndarray) -> np.ndarray:
    """Bilinear samples of a map on ``grid`` at points (N, 2) in mm; 0 outside."""
    idx = grid.points_to_index(pts)  # (N, 2) as (row, col)
    out = cv2.remap(values, idx[:, 1].astype(np.float32).reshape(1, -1),
                    idx[:, 0].astype(np.float32).reshape(1, -1), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    return out.ravel()


def _lit(im: np.ndarray) -> np.ndarray:
    """Pixels above black (see the module's doc)."""
    return im > (BLACK_GREY if im.dtype == np.uint8 else 0)


def imaged_region(frame: Frame) -> np.ndarray:
    """Where the frame holds an image: not black capture margin or outside a sector. A pixel
    is blank when at most a fifth of the pixels within 1 mm are above black (dark speckle has
    isolated black pixels; a margin is black throughout), and a blank area is margin only
    where it reaches the frame's border: a black vessel or cyst inside the image is imaged
    tissue. Read once per frame."""
    if "imaged_region" in frame.extras:
        return frame.extras["imaged_region"]
    im = np.asarray(frame.image)
    dz, dx = frame.grid.spacing_mm
    k = (max(int(round(1.0 / dx)) | 1, 3), max(int(round(1.0 / dz)) | 1, 3))
    if not _blank_on_border(im, k):  # no margin: every blank area lies inside the image
        valid = np.ones(im.shape, bool)
    else:
        valid = cv2.blur(_lit(im).astype(np.float32), k) > 0.2
        if not valid.all():
            n, labels = cv2.connectedComponents((~valid).astype(np.uint8), connectivity=4)
            border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0],
                                               labels[:, -1]]))
            valid = ~np.isin(labels, border[border > 0])
    frame.extras["imaged_region"] = valid
    return valid


def zero_margins(frame: Frame) -> Frame:
    """The 2-D ``frame`` with its margin (outside :func:`imaged_region`) set to 0 where a
    lossy compression left it a few grey levels above; the frame itself when its margin is 0
    already (or it has none). The copy keeps the frame's time, index and what was read of it."""
    if frame.grid.ndim != 2:
        return frame
    valid = imaged_region(frame)
    if valid.all():
        return frame
    im = np.asarray(frame.image)
    outside = ~valid
    if not np.any(im[outside]):
        return frame
    clean = im.copy()
    clean[outside] = 0
    return replace(frame, image=clean, extras={"imaged_region": valid})


def _blank_on_border(im: np.ndarray, k: tuple[int, int]) -> bool:
    """Whether a pixel on the frame's border is blank by :func:`imaged_region`'s test (the
    box of ``k`` = (width, height) pixels around it at most a fifth above black), reading
    only the strips along the border that those boxes cover."""
    kx, kz = min(k[0], im.shape[1]), min(k[1], im.shape[0])
    strips = ((im[:kz], 0, None), (im[-kz:], -1, None), (im[:, :kx], None, 0),
              (im[:, -kx:], None, -1))
    for strip, row, col in strips:
        b = cv2.blur(_lit(strip).astype(np.float32), k)
        edge = b[row] if row is not None else b[:, col]
        if np.any(edge <= 0.2):
            return True
    return False


AROUND = np.stack([np.cos(np.linspace(0, 2 * np.pi, 24, endpoint=False)),
                    np.sin(np.linspace(0, 2 * np.pi, 24, endpoint=False))], -1)


def distance_to_edge(valid: np.ndarray, frame: Frame, start: np.ndarray,
                      direction: np.ndarray, step_mm: float = 0.2,
                      max_mm: float = 200.0) -> float:
    """How far (mm) from ``start`` the imaged region ends along ``direction`` (2,), or along
    the nearest of several directions (D, 2)."""
    dirs = np.asarray(direction, float).reshape(-1, 2)
    s = np.arange(0.0, max_mm, step_mm)
    pts = start[None, None] + s[None, :, None] * dirs[:, None, :]  # (D, S, 2)
    idx = np.rint(frame.grid.points_to_index(pts.reshape(-1, 2))).astype(int)
    h, w = valid.shape
    inside = (idx[:, 0] >= 0) & (idx[:, 0] < h) & (idx[:, 1] >= 0) & (idx[:, 1] < w)
    ok = np.zeros(len(idx), bool)
    ok[inside] = valid[idx[inside, 0], idx[inside, 1]]
    out = np.flatnonzero(~ok.reshape(len(dirs), len(s)).all(axis=0))
    return float(s[out[0]]) if out.size else float(max_mm)
