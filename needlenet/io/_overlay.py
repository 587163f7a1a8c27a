"""Overlay animations of tracking results: estimate in red (in 2D with the region its
covariance gives the tip at 95%), ground truth in green."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from ..backends import chi2_gate

__all__ = ["overlay_frames", "tip_region_mm", "write_overlay"]

_RED, _GREEN, _YELLOW, _WHITE = (40, 40, 255), (60, 220, 60), (0, 220, 255), (255, 255, 255)


def _px(grid, pts_xz, scale):
    idx = grid.points_to_index(np.asarray(pts_xz, float))
    return tuple(int(round(v * scale + scale / 2)) for v in idx[::-1])


def tip_region_mm(tip_mm, covariance, n: int = 64) -> np.ndarray | None:
    """``n`` points (x, z) mm on the boundary of the 2D region that holds the tip with 95%
    probability under a Gaussian with ``covariance`` (mm^2) about ``tip_mm``: the ellipse
    of Mahalanobis distance sqrt(chi2_2(0.95)); None for a covariance that is not one (not
    2 x 2, not finite, or with a negative variance)."""
    C = None if covariance is None else np.asarray(covariance, float)
    if C is None or C.shape != (2, 2) or not np.all(np.isfinite(C)):
        return None
    var, axes = np.linalg.eigh(0.5 * (C + C.T))
    if var.min() < -1e-12 * max(var.max(), 1e-300):
        return None
    phi = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    unit = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    radii = chi2_gate(2, 0.95) * np.sqrt(np.maximum(var, 0.0))
    return np.asarray(tip_mm, float) + (unit * radii) @ axes.T


def _frame_2d(seq, i, est, scale):
    g = seq.grid()
    img = cv2.cvtColor(np.ascontiguousarray(seq.images[i]), cv2.COLOR_GRAY2BGR)
    img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
    if seq.tip_mm is not None and seq.visible is not None and seq.visible[i] and np.all(
            np.isfinite(seq.tip_mm[i])):
        cv2.circle(img, _px(g, seq.tip_mm[i], scale), max(3, 2 * scale), _GREEN, 1, cv2.LINE_AA)
    if est is not None and est.tip_mm is not None:
        tip = np.asarray(est.tip_mm, float)
        c = _px(g, tip, scale)
        cv2.drawMarker(img, c, _RED, cv2.MARKER_CROSS, max(8, 4 * scale), 1, cv2.LINE_AA)
        region = tip_region_mm(tip, est.covariance)
        if region is not None:
            idx = np.clip(g.points_to_index(region) * scale + scale / 2, -2**20, 2**20)
            cv2.polylines(img, [np.round(idx[:, ::-1]).astype(np.int32)], True, _RED, 1,
                          cv2.LINE_AA)  # (row, col) -> OpenCV's (x, y)
        if est.direction is not None and seq.modality == "inplane":
            back = tip - 15.0 * np.asarray(est.direction, float)
            cv2.line(img, _px(g, back, scale), c, _RED, 1, cv2.LINE_AA)
    return img


def _frame_3d(seq, i, est):
    vol = seq.images[i]
    g = seq.grid()
    views = [vol.max(axis=1), vol.max(axis=2)]  # (z, x) and (z, y) projections
    axes = [(2, 0), (1, 0)]
    panels = []
    for v, (ca, ra) in zip(views, axes, strict=True):
        p = cv2.cvtColor(np.ascontiguousarray(v), cv2.COLOR_GRAY2BGR)
        p = cv2.resize(p, None, fx=2, fy=2, interpolation=cv2.INTER_LINEAR)
        for pt, col in ((None if seq.tip_mm is None else seq.tip_mm[i], _GREEN),
                        (None if est is None else est.tip_mm, _RED)):
            if pt is None or not np.all(np.isfinite(pt)):
                continue
            idx = g.points_to_index(np.asarray(pt, float))
            cv2.circle(p, (int(idx[ca] * 2 + 1), int(idx[ra] * 2 + 1)), 6, col, 1, cv2.LINE_AA)
        panels.append(p)
    return np.hstack(panels)


def overlay_frames(seq, estimates, max_size: int = 320, step: int = 1) -> list[np.ndarray]:
    """BGR images of every ``step``-th frame (0, step, 2 step, ...) with the estimate (red)
    and the ground truth (green); only those frames are read."""
    out = []
    big = max(seq.images.shape[1:3])
    scale = max(1, int(max_size // big))
    shrink = max_size / big if seq.ndim == 2 and big > max_size else 1.0
    for i in range(0, seq.n_frames, max(1, int(step))):
        est = estimates[i] if estimates is not None else None
        img = _frame_3d(seq, i, est) if seq.ndim == 3 else _frame_2d(seq, i, est, scale)
        if shrink < 1.0:  # drawn at full size, then averaged down (a smaller file)
            img = cv2.resize(img, None, fx=shrink, fy=shrink, interpolation=cv2.INTER_AREA)
        status = est.status.value if est is not None else ""
        cv2.putText(img, f"{i:4d} {status}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, _YELLOW, 1,
                    cv2.LINE_AA)
        out.append(img)
    return out


def write_overlay(path: str | Path, seq, estimates, fps: float | None = None,
                  max_frames: int = 300, max_size: int = 320) -> Path:
    """Write the overlay as an animated GIF (Pillow) or MP4/AVI (OpenCV), by extension;
    2D frames larger than ``max_size`` pixels are scaled down to it."""
    path = Path(path)
    step = max(1, int(np.ceil(seq.n_frames / max_frames)))
    frames = overlay_frames(seq, estimates, max_size=max_size, step=step)
    if fps is None:
        dt = np.median(np.diff(seq.timestamps_s)) if seq.n_frames > 1 else 0.05
        fps = float(np.clip(1.0 / max(dt * step, 1e-3), 1.0, 30.0))
    ext = path.suffix.lower()
    if ext not in (".gif", ".mp4", ".avi"):
        raise ValueError(f"overlay {path}: use .gif, .mp4 or .avi")
    # written whole or not at all: a temporary file beside it (same suffix, which OpenCV
    # reads the container from), renamed over the target at the end
    parent = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem[:64]}.", suffix=ext, dir=parent)
    os.close(fd)
    try:
        if ext == ".gif":
            from PIL import Image

            ims = [Image.fromarray(cv2.cvtColor(f, cv2.COLOR_BGR2RGB)) for f in frames]
            ims[0].save(tmp, format="GIF", save_all=True, append_images=ims[1:],
                        duration=int(1000 / fps), loop=0, optimize=False)
        else:
            h, w = frames[0].shape[:2]
            fourcc = cv2.VideoWriter_fourcc(*("mp4v" if ext == ".mp4" else "MJPG"))
            wr = cv2.VideoWriter(tmp, fourcc, fps, (w, h))
            if not wr.isOpened():
                raise OSError(f"overlay {path}: OpenCV cannot write {ext} here")
            for f in frames:
                wr.write(f)
            wr.release()
        os.chmod(tmp, 0o644)  # mkstemp makes it private
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path
