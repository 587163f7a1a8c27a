"""Geometry of the `line` tracker's segments against the frame: whether a segment runs on a
line, which of its ends is the entry, where the imaged region is (capture margins and sector
masks are not), and how far a point lies from that region's edge.

Black is what a margin or the outside of a sector holds: exactly 0 in an image that was
written as it was formed, a few grey levels after lossy compression (a frame-grabbed video,
a JPEG screen capture rings around the sector's edge). A box of 1 mm that is at least four
fifths exact zeros is blank; so is a box of 2 mm that is at least four fifths at or under
``BLACK_GREY`` (8-bit; the larger box keeps dark speckle at the border, whose clusters are a
speckle cell across, from passing for a compressed margin). :func:`zero_margins` sets the
margin of a frame to 0, so that everything read from it afterwards (the learned model's
input, the line contrast, the tissue's grey level) sees the margin it would see
uncompressed."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from ..backends import NeedleLine
from ..features import Frame

__all__ = ["on_line", "entry_to_tip", "sample_grid", "imaged_region", "zero_margins",
           "distance_to_edge", "AROUND", "BLACK_GREY"]

BLACK_GREY = 12  # 8-bit grey levels: JPEG ringing beside a black margin (quality 40: <= 10)
MARGIN_ALONG_MM = 5.0  # a margin runs along the border; a vessel at the border touches it less


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


def _boxes(frame: Frame) -> list[tuple[float, tuple[int, int]]]:
    """(black level, box (width, height) in pixels) of the two blank tests: exact zeros in
    1 mm, at or under ``BLACK_GREY`` in 2 mm (8-bit frames only)."""
    dz, dx = frame.grid.spacing_mm
    out = []
    for level, mm in ((0, 1.0), (BLACK_GREY, 2.0)):
        if level and np.asarray(frame.image).dtype != np.uint8:
            continue
        out.append((level, (max(int(round(mm / dx)) | 1, 3), max(int(round(mm / dz)) | 1, 3))))
    return out


def _blank(im: np.ndarray, level: float, k: tuple[int, int]) -> np.ndarray:
    """Pixels whose box ``k`` is at most a fifth above ``level``."""
    return cv2.blur((im > level).astype(np.float32), k) <= 0.2


def imaged_region(frame: Frame) -> np.ndarray:
    """Where the frame holds an image: not black capture margin or outside a sector. A pixel
    is blank when its box is black throughout but for a fifth (see the module's doc: dark
    speckle has isolated black pixels; a margin is black throughout), and a blank area is
    margin only where it runs along the frame's border for ``MARGIN_ALONG_MM`` or more: a
    black vessel or cyst inside the image, or one that just reaches the border, is imaged
    tissue. Read once per frame."""
    if "imaged_region" in frame.extras:
        return frame.extras["imaged_region"]
    im = np.asarray(frame.image)
    tests = [(level, k) for level, k in _boxes(frame) if _blank_on_border(im, level, k)]
    valid = np.ones(im.shape, bool)  # no margin: every blank area lies inside the image
    if tests:
        blank = np.zeros(im.shape, bool)
        for level, k in tests:
            blank |= _blank(im, level, k)
        if blank.any():
            n, labels = cv2.connectedComponents(blank.astype(np.uint8), connectivity=4)
            valid = ~np.isin(labels, _margins(labels, frame.grid.spacing_mm))
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


def _margins(labels: np.ndarray, spacing_mm) -> np.ndarray:
    """The labels of the blank areas that run along the frame's border for
    ``MARGIN_ALONG_MM`` or more: a capture margin or the outside of a sector does; a black
    vessel or shadow that reaches the border touches it over a few millimetres."""
    dz, dx = spacing_mm
    along = np.zeros(int(labels.max()) + 1)
    for edge, step in ((labels[0], dx), (labels[-1], dx), (labels[:, 0], dz),
                       (labels[:, -1], dz)):
        along += np.bincount(edge, minlength=along.size) * step
    along[0] = 0.0  # not blank
    return np.flatnonzero(along >= MARGIN_ALONG_MM)


def _blank_on_border(im: np.ndarray, level: float, k: tuple[int, int]) -> bool:
    """Whether a pixel on the frame's border is blank by the test of (``level``, box ``k`` =
    (width, height) pixels), reading only the strips along the border that the boxes cover."""
    kx, kz = min(k[0], im.shape[1]), min(k[1], im.shape[0])
    strips = ((im[:kz], 0, None), (im[-kz:], -1, None), (im[:, :kx], None, 0),
              (im[:, -kx:], None, -1))
    for strip, row, col in strips:
        b = _blank(strip, level, k)
        edge = b[row] if row is not None else b[:, col]
        if np.any(edge):
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
