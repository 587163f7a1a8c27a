"""The classical evidence of the default in-plane tracker (``line``): a line-contrast map in
speckle standard deviations, invariant to gain and dynamic range."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["line_contrast"]


def line_contrast(image: np.ndarray, window_px: int) -> np.ndarray:
    """The classical line evidence: how far a pixel (smoothed over one pixel) stands above the
    tissue beside it, in units of the image's speckle spread (1.4826 times the median absolute
    deviation of its non-zero pixels: the speckle SD of a log-compressed image, whatever the
    gain and dynamic range), clipped at 0; black margins give 0 and are no tissue.

    The tissue is the darkest of three ``window_px`` boxes centred a box's width above, left
    and right of the pixel: below a needle lie its reverberations and shadow, and along it
    the needle itself, so one of the three is tissue at any needle angle (Mathiassen's shaft
    contrast takes the band above the needle for the same reason)."""
    im = np.asarray(image, np.float32)
    k = max(int(window_px) | 1, 3)
    inside = im[im > 0]
    if inside.size < 2:
        return np.zeros_like(im)
    valid = cv2.blur((im > 0).astype(np.float32), (k, k))
    # the mean of the imaged pixels of each box; a box mostly in a margin is no tissue
    mean = np.where(valid > 0.5, cv2.blur(im, (k, k)) / np.maximum(valid, 1e-6), np.inf)
    mean = np.pad(mean, k, mode="edge")
    h, w = im.shape
    above = mean[0:h, k:k + w]
    left = mean[k:k + h, 0:w]
    right = mean[k:k + h, 2 * k:2 * k + w]
    tissue = np.minimum(np.minimum(above, left), right)
    sd = 1.4826 * float(np.median(np.abs(inside - np.median(inside))))
    z = (cv2.GaussianBlur(im, (3, 3), 0) - tissue) / max(sd, 1e-6)
    return np.where((im > 0) & np.isfinite(z), np.maximum(z, 0.0), 0.0).astype(np.float32)
