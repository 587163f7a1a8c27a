"""Bilinear samples of an image at any number of points (OpenCV's remap)."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["remap_points"]

# OpenCV's remap takes maps under SHRT_MAX (32,767) pixels on a side: the points are laid
# out in rows of this many (a long line read at a fine step holds more samples than that)
_WIDTH = 16384


def remap_points(image: np.ndarray, cols, rows, border: int = cv2.BORDER_CONSTANT,
                 value: float = 0.0) -> np.ndarray:
    """Bilinear samples of ``image`` at fractional pixel positions ``cols`` and ``rows``
    (arrays of one shape, any size), of that shape; ``border`` and ``value`` as OpenCV's
    ``borderMode`` and ``borderValue`` outside the image. Each sample is OpenCV's own
    (remap reads each map pixel alone, so the layout changes no value)."""
    c = np.asarray(cols, np.float32)
    shape = c.shape
    c = c.ravel()
    r = np.asarray(rows, np.float32).ravel()
    n = c.size
    if n == 0:
        return np.zeros(shape, np.asarray(image).dtype)
    w = min(n, _WIDTH)
    h = -(-n // w)
    if h * w != n:
        c = np.concatenate([c, np.zeros(h * w - n, np.float32)])
        r = np.concatenate([r, np.zeros(h * w - n, np.float32)])
    out = cv2.remap(image, c.reshape(h, w), r.reshape(h, w), interpolation=cv2.INTER_LINEAR,
                    borderMode=border, borderValue=value)
    return out.reshape(-1)[:n].reshape(shape)
