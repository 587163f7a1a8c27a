"""Coloured marks drawn over a gray B-mode image (a scanner's biopsy guide, calipers, a cursor,
text) filled in from the echo around them before the frame is read as gray.

A B-mode image is gray: its pixels have equal red, green and blue (a lossy codec moves them by a
few levels). A scanner draws its marks in saturated colour (green, yellow, cyan), and converted
to gray they are lines as bright as a needle's echo: a drawn guide line from the probe face is a
needle to any tracker. A pixel whose channels differ by at least ``CHROMA_MIN`` levels and by at
least ``SATURATION_MIN`` of its brightest channel is such a mark; the marks and the one-pixel
blend of their anti-aliased edges are filled in from the gray around them (OpenCV's
fast-marching inpainting). A frame with more than ``MAX_SHARE`` of its pixels coloured is left
as it is: that is a tinted display map or a colour Doppler box, not a drawn mark, and its gray
(luma) carries the echo.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CHROMA_MIN", "MAX_SHARE", "SATURATION_MIN", "fill_colour_marks"]

CHROMA_MIN = 40  # gray levels between a pixel's largest and smallest channel
SATURATION_MIN = 0.5  # that difference over the largest channel (a tint stays below it)
MAX_SHARE = 0.10  # of a frame's pixels: more is a tinted map or a Doppler box
INPAINT_RADIUS_PX = 3


def colour_marks(rgb: np.ndarray) -> np.ndarray:
    """Boolean mask (H, W) of the saturated coloured pixels of a uint8 frame (H, W, >= 3)."""
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    # elementwise over the three planes: numpy's reduction over a last axis of three is
    # twenty times slower on a frame
    hi = np.maximum(np.maximum(r, g), b).astype(np.int16)
    chroma = hi - np.minimum(np.minimum(r, g), b)
    return (chroma >= CHROMA_MIN) & (chroma >= SATURATION_MIN * hi)


def fill_colour_marks(gray: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """``gray`` (H, W uint8, the luma of ``rgb``) with ``rgb``'s coloured marks filled in from
    the gray around them; ``gray`` itself when the frame has none or is tinted as a whole."""
    import cv2

    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] < 3:
        return gray
    mark = colour_marks(rgb)
    n = int(np.count_nonzero(mark))
    if n == 0 or n > MAX_SHARE * mark.size:
        return gray
    mask = cv2.dilate(mark.view(np.uint8), np.ones((3, 3), np.uint8))
    return cv2.inpaint(np.ascontiguousarray(gray), mask, INPAINT_RADIUS_PX, cv2.INPAINT_TELEA)
