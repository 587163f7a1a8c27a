"""Marks a scanner draws in gray over a live recording (a biopsy guide, a focus marker,
calipers, text) found by their stillness and filled in from the echo around them.

Coloured marks are told by their colour (:mod:`._colour_marks`); a mark drawn in gray is, in
one frame, a line as bright as a needle's echo that enters through the edge of the view, and
every tracker takes a dotted biopsy guide for a needle. Over time the two differ: in a live
recording (a probe held by hand, tissue that breathes and pulses, the receiver's noise) no
echo keeps its exact gray level frame after frame, while what the scanner draws over the image
is pixel-identical in every frame.

So, over the recording's first :data:`FRAMES` frames, a pixel that keeps one gray level
strictly between black and white in all of them is a drawn mark, when the recording is live:
when such pixels make up at most :data:`LIVE_SHARE` of the imaged mid-gray pixels. A flat
still area (one gray level over :data:`FLAT_PX` x :data:`FLAT_PX` pixels, wider than a drawn
line or letter: a screen capture's gray panel around the image), with its border, is neither
a mark nor imaged, so a capture that was not cropped is judged by its image alone. Black (0)
is left out (a capture margin, an anechoic lumen) and so is white (255): saturation clips a
needle's echo to a constant too, so a mark drawn in pure white is not told from a saturated
shaft and stays. A recording in which more pixels keep their level is not live (a simulation
of still tissue keeps 12-60% of its pixels from frame to frame, a codec may copy still blocks
as they were), and nothing is filled there. Nor in a recording compressed frame by frame
(JPEG, most MP4): the codec moves a mark's pixels by a few levels from frame to frame, as it
does the echo's, and no pixel keeps its level. A mark is drawn in one colour: of each still
piece, at least :data:`CORE_PX` pixels and half of them keep one level (scattered echo pixels
that a simulation without noise leaves still are of many levels). The marks and their
one-pixel anti-aliased rim are filled in every frame by OpenCV's fast-marching inpainting, as
coloured marks are.
"""

from __future__ import annotations

import numpy as np

from ._colour_marks import INPAINT_RADIUS_PX
from ._lazy import FrameStack, is_frame_stack

__all__ = ["FRAMES", "LIVE_SHARE", "fill_still_marks", "still_marks"]

FRAMES = 8  # frames a pixel must keep its level: 2^-7 of chance for a pixel of two levels
LIVE_SHARE = 0.02  # of the imaged mid-gray pixels: a guide and text cover a few per mille
FLAT_PX = 7  # a still area this wide in one gray level is a panel, not a drawn line
CORE_PX = 3  # pixels of one level that make a drawn piece (a dash, a stroke)


def still_marks(images) -> np.ndarray | None:
    """Boolean mask (H, W) of the gray marks drawn over a live recording of 2D uint8 frames
    ``images`` (an array or a :class:`FrameStack`; the first :data:`FRAMES` frames are read),
    or None when there are none: fewer frames than that, frames of another type, no still
    pixel, or a recording that is not live (see the module's doc)."""
    if images.ndim != 3 or images.dtype != np.uint8 or len(images) < FRAMES:
        return None
    import cv2

    first = np.asarray(images[0])
    mid = (first > 0) & (first < 255)
    still = mid.copy()
    for k in range(1, FRAMES):
        still &= np.asarray(images[k]) == first
    # flat areas: one still level over 7 x 7 pixels (wider than any drawn line or letter),
    # grown back to their extent and one pixel beyond
    box = np.ones((FLAT_PX, FLAT_PX), np.uint8)
    flat = cv2.erode(still.view(np.uint8), box) & \
        (cv2.dilate(first, box) == cv2.erode(first, box)).view(np.uint8)
    flat = cv2.dilate(flat, np.ones((FLAT_PX + 2, FLAT_PX + 2), np.uint8)).astype(bool)
    still &= ~flat
    n = int(np.count_nonzero(still))
    if n == 0 or n > LIVE_SHARE * np.count_nonzero(mid & ~flat):
        return None
    return _drawn(still, first)


def _drawn(still: np.ndarray, first: np.ndarray) -> np.ndarray | None:
    """The parts of ``still`` drawn in one colour: connected pieces (8-neighbours) of which at
    least :data:`CORE_PX` pixels, and at least half, keep the piece's most common level (a
    mark's opaque core; its anti-aliased rim blends with the echo). Echo that a simulation
    without noise leaves still (an interface unchanged from slice to slice) keeps scattered
    pixels of many levels."""
    import cv2

    n, labels = cv2.connectedComponents(still.view(np.uint8), connectivity=8)
    lab = labels[still]
    counts = np.bincount(lab * 256 + first[still], minlength=n * 256).reshape(n, 256)
    size = counts.sum(axis=1)
    mode = counts.max(axis=1)
    keep = (mode >= CORE_PX) & (2 * mode >= size)
    keep[0] = False
    out = keep[labels] & still
    return out if out.any() else None


def fill_still_marks(images, meta: dict) -> np.ndarray | FrameStack:
    """``images`` with :func:`still_marks` filled in every frame (lazily for a
    :class:`FrameStack`); ``images`` itself when there are none. A note for the user is added
    to ``meta["warnings"]``: the pixels changed, and why."""
    import cv2

    mark = still_marks(images)
    if mark is None:
        return images
    mask = cv2.dilate(mark.view(np.uint8), np.ones((3, 3), np.uint8))

    def fill(frame: np.ndarray) -> np.ndarray:
        return cv2.inpaint(np.ascontiguousarray(frame), mask, INPAINT_RADIUS_PX,
                           cv2.INPAINT_TELEA)

    n = int(np.count_nonzero(mark))
    meta.setdefault("warnings", []).append(
        f"{n} pixels keep one gray level through the first {FRAMES} frames while the echo "
        "around them changes: marks drawn over the image (a biopsy guide, text), filled in "
        "from the echo around them in every frame")
    meta["still_marks_px"] = n
    if is_frame_stack(images):
        return FrameStack(lambda i: fill(images.frame(i)), len(images), images.shape[1:],
                          images.dtype, source=images.source)
    return np.stack([fill(f) for f in images])
