"""A scanner's image post-processing, drawn per training world.

Scanners do not show the beamformed, log-compressed envelope as it is: they smooth the speckle
(speckle reduction: edge-preserving filters, non-local means), sharpen edges, and recordings
are often stored with lossy compression. Each changes the texture a network reads (a speckle
cell grows under smoothing while a needle's bright edge stays sharp), so a network trained on
unprocessed frames only reads processed recordings as a texture it has never seen.

:func:`draw_postprocessing` draws one chain for a world (a scanner's preset stays the same
for a recording): speckle reduction in 70% of the chains (bilateral, median, non-local means
or a Gaussian, 0.2-0.8 mm), edge enhancement in 40% (unsharp masking), JPEG in 30% (quality
30-90); :func:`postprocess` applies it to a frame at its own pixel spacing. Filter sizes are in
millimetres, so a chain does to a fine and a coarse frame what it would do to the same tissue
(non-local means keeps OpenCV's windows of 7 and 21 pixels, and a median at most 7 pixels, as
scanners' filters have fixed kernels on their own grids).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["draw_postprocessing", "postprocess", "postprocessed"]


def _odd_px(mm: float, spacing_mm: float, lo: int = 3) -> int:
    n = max(int(round(mm / spacing_mm)), lo)
    return n + 1 - n % 2


def draw_postprocessing(rng: np.random.Generator) -> list[tuple[str, dict]]:
    """One world's chain: a list of (operation, parameters), applied in order."""
    chain: list[tuple[str, dict]] = []
    if rng.random() < 0.7:
        kind = str(rng.choice(["bilateral", "median", "nlm", "gaussian"]))
        size = float(rng.uniform(0.2, 0.8))  # mm: the filter's reach
        if kind == "bilateral":
            chain.append((kind, {"size_mm": size, "sigma_color": float(rng.uniform(15, 60))}))
        elif kind == "nlm":
            chain.append((kind, {"h": float(rng.uniform(8, 30))}))
        else:
            chain.append((kind, {"size_mm": size}))
    if rng.random() < 0.4:
        chain.append(("sharpen", {"sigma_mm": float(rng.uniform(0.15, 0.6)),
                                  "amount": float(rng.uniform(0.3, 1.5))}))
    if rng.random() < 0.3:
        chain.append(("jpeg", {"quality": int(rng.integers(30, 91))}))
    return chain


def postprocess(image: np.ndarray, spacing_mm: float, chain) -> np.ndarray:
    """``image`` (2D uint8, pixels ``spacing_mm`` apart, the smaller of the two axes') through
    ``chain``; pixels outside the imaged region (0) stay 0."""
    im = np.ascontiguousarray(image, np.uint8)
    for op, p in chain:
        if op == "bilateral":
            d = _odd_px(p["size_mm"], spacing_mm)
            out = cv2.bilateralFilter(im, d, p["sigma_color"], d / 2.0)
        elif op == "median":
            out = cv2.medianBlur(im, min(_odd_px(p["size_mm"], spacing_mm), 7))
        elif op == "nlm":
            out = cv2.fastNlMeansDenoising(im, None, h=p["h"], templateWindowSize=7,
                                           searchWindowSize=21)
        elif op == "gaussian":
            out = cv2.GaussianBlur(im, (0, 0), max(p["size_mm"] / 2.0 / spacing_mm, 0.3))
        elif op == "sharpen":
            f = im.astype(np.float32)
            blur = cv2.GaussianBlur(f, (0, 0), max(p["sigma_mm"] / spacing_mm, 0.3))
            out = np.clip(np.rint(f + p["amount"] * (f - blur)), 0, 255).astype(np.uint8)
        elif op == "jpeg":
            ok, buf = cv2.imencode(".jpg", im, [cv2.IMWRITE_JPEG_QUALITY, int(p["quality"])])
            out = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE) if ok else im
        else:
            raise ValueError(f"unknown post-processing operation {op!r}")
        im = np.where(image > 0, out, 0).astype(np.uint8)
    return im


def postprocessed(images: np.ndarray, spacing_mm, chain) -> np.ndarray:
    """Every frame of a 2D sequence's ``images`` (n, H, W) through ``chain``."""
    s = float(min(spacing_mm[:2]))
    return np.stack([postprocess(im, s, chain) for im in images])
