"""Where a 2-D frame holds an image: black capture margins and the outside of a sector are not.

Black is what a margin or the outside of a sector holds: exactly 0 in an image that was
written as it was formed, a few grey levels after lossy compression (a frame-grabbed video,
a JPEG screen capture rings around the sector's edge). A box of 1 mm that is at least four
fifths exact zeros is blank; so is a box of 2 mm that is at least four fifths at or under
``BLACK_GREY`` (8-bit; the larger box keeps dark speckle at the border, whose clusters are a
speckle cell across, from passing for a compressed margin). :func:`zero_margins`, applied by
every tracker to every 2-D frame, sets the margin to 0, so that everything read from the
frame afterwards (the learned model's input, the line contrast, the tissue's grey level) sees
the margin it would see uncompressed."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numba
import numpy as np

from ..features import Frame

__all__ = ["imaged_region", "inner_region", "zero_margins", "BLACK_GREY", "MARGIN_ALONG_MM"]

BLACK_GREY = 12  # 8-bit grey levels: JPEG ringing beside a black margin (quality 40: <= 10)
MARGIN_ALONG_MM = 5.0  # a margin runs along the border; a vessel at the border touches it less


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


def _counted(n: int) -> bool:
    """Whether a box of ``n`` pixels is tested by its count in integers (a third of the
    time): with n no multiple of 5 no box is exactly a fifth, so "count < n / 5" is the
    mean's "<= 0.2" whatever its rounding (and a 16-bit count holds n)."""
    return bool(n % 5) and n < 65536


def _blank(im: np.ndarray, level: float, k: tuple[int, int]) -> np.ndarray:
    """Pixels whose box ``k`` is at most a fifth above ``level``."""
    n = k[0] * k[1]
    if _counted(n):
        count = cv2.boxFilter((im > level).view(np.uint8), cv2.CV_16U, k, normalize=False)
        return count < (n + 4) // 5
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
    edges = {t: _border_blank(im, *t) for t in _boxes(frame)}
    tests = [t for t, e in edges.items() if any(side.any() for side in e)]
    valid = np.ones(im.shape, bool)  # no margin: every blank area lies inside the image
    # blank areas run along the border for at most the blank border pixels' length in all:
    # under MARGIN_ALONG_MM none is margin, and the whole frame need not be read
    dz, dx = frame.grid.spacing_mm
    sides = [np.logical_or.reduce([e[i] for e in edges.values()]) for i in range(4)]
    along = sum(float(np.count_nonzero(side)) * step
                for side, step in zip(sides, (dx, dx, dz, dz), strict=True))
    if tests and along >= MARGIN_ALONG_MM - 1e-9:
        blank = np.zeros(im.shape, bool)
        for level, k in tests:
            blank |= _blank(im, level, k)
        if blank.any():
            n, labels = cv2.connectedComponents(blank.astype(np.uint8), connectivity=4)
            imaged = np.ones(n, bool)
            imaged[_margins(labels, frame.grid.spacing_mm)] = False
            valid = imaged[labels]
    frame.extras["imaged_region"] = valid
    return valid


def inner_region(frame: Frame, edge_mm: float) -> np.ndarray:
    """The imaged region (:func:`imaged_region`) less ``edge_mm`` along the edges of margins
    and sector masks, where a map marks the mask's step (the frame's own border is no such
    edge)."""
    valid = imaged_region(frame)
    if valid.all():
        return valid
    dz, dx = frame.grid.spacing_mm
    kz = max(int(round(edge_mm / dz)), 1)
    kx = max(int(round(edge_mm / dx)), 1)
    padded = np.pad(valid, ((kz, kz), (kx, kx)), constant_values=True).astype(np.uint8)
    eroded = cv2.erode(padded, np.ones((2 * kz + 1, 2 * kx + 1), np.uint8))
    return eroded[kz:-kz, kx:-kx] > 0


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


def _border_blank(im: np.ndarray, level: float, k: tuple[int, int]) -> tuple[np.ndarray, ...]:
    """The blank pixels (by the test of (``level``, box ``k`` = (width, height) pixels)) of
    the frame's first row, last row, first column and last column, reading only the strips
    along the border that the boxes cover (the same values as :func:`_blank` of the frame)."""
    kx, kz = min(k[0], im.shape[1]), min(k[1], im.shape[0])
    n = k[0] * k[1]
    if _counted(n):  # _blank's count, on the border rows only
        least = (n + 4) // 5
        # each strip turned so that its first row is the border, copied to one layout (one
        # compiled version per pixel type)
        return tuple(_edge_count(np.ascontiguousarray(strip), float(level), a, b) < least
                     for strip, a, b in ((im[:kz], k[0], k[1]), (im[-kz:][::-1], k[0], k[1]),
                                         (im[:, :kx].T, k[1], k[0]),
                                         (im[:, -kx:][:, ::-1].T, k[1], k[0])))
    return (_blank(im[:kz], level, k)[0], _blank(im[-kz:], level, k)[-1],
            _blank(im[:, :kx], level, k)[:, 0], _blank(im[:, -kx:], level, k)[:, -1])


@numba.njit(cache=True, nogil=True)
def _reflect(p, n):  # pragma: no cover - compiled
    """OpenCV's BORDER_REFLECT_101 index of ``p`` on an axis of ``n`` samples."""
    if n == 1:
        return 0
    while p < 0 or p >= n:
        p = -p if p < 0 else 2 * n - 2 - p
    return p


@numba.njit(cache=True, nogil=True)
def _edge_count(strip, level, kw, kh):  # pragma: no cover - compiled
    """For each pixel of ``strip``'s first row, how many pixels of its ``kw`` x ``kh`` box
    (centred, reflected at the strip's ends as OpenCV's box filter reflects) lie above
    ``level``: ``cv2.boxFilter`` of ``strip > level`` (unnormalised) on that row."""
    h, w = strip.shape
    col = np.zeros(w, np.int64)
    for r in range(-(kh // 2), kh // 2 + 1):
        row = _reflect(r, h)
        for c in range(w):
            if strip[row, c] > level:
                col[c] += 1
    half = kw // 2
    out = np.empty(w, np.int64)
    total = 0
    for c in range(-half, half + 1):
        total += col[_reflect(c, w)]
    out[0] = total
    for x in range(1, w):  # the box slid on by one column
        total += col[_reflect(x + half, w)] - col[_reflect(x - 1 - half, w)]
        out[x] = total
    return out
