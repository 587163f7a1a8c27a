"""Preview images: the first and last frames of a sequence with the ground truth drawn on."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ._sequence import Sequence

__all__ = ["preview_image", "save_preview"]

_GREEN, _RED, _BLUE, _WHITE = (60, 220, 60), (40, 40, 255), (255, 160, 40), (255, 255, 255)


def _to_px(seq_grid, pts_xz):
    """(x, z) mm -> (col, row) pixel coordinates for OpenCV."""
    idx = seq_grid.points_to_index(np.asarray(pts_xz, float))
    return idx[..., ::-1]


def _panel_2d(seq: Sequence, i: int, scale: int) -> np.ndarray:
    g = seq.grid()
    img = cv2.cvtColor(seq.images[i], cv2.COLOR_GRAY2BGR)
    img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    s = float(scale)
    if seq.centerline_mm is not None and seq.modality == "inplane":
        cl = seq.centerline_mm[i]
        near = np.abs(cl[:, 1]) <= 1.5
        if near.sum() >= 2:
            pts = (_to_px(g, cl[near][:, [0, 2]]) * s + s / 2).astype(np.int32)
            cv2.polylines(img, [pts.reshape(-1, 1, 2)], False, _GREEN, 1, cv2.LINE_AA)
    if seq.tip_mm is not None and np.all(np.isfinite(seq.tip_mm[i])):
        c = (_to_px(g, seq.tip_mm[i]) * s + s / 2).astype(int)
        col = _RED if seq.visible[i] else _BLUE
        cv2.circle(img, (int(c[0]), int(c[1])), max(4, 2 * scale), col, 1, cv2.LINE_AA)
    return img


def _panel_3d(seq: Sequence, i: int) -> np.ndarray:
    """Maximum intensity projections of a 6 mm slab around the tip along elevation, lateral
    and depth, with the labelled centreline and tip projected on each."""
    vol = seq.images[i]
    g = seq.grid()
    tip = seq.tip_mm[i] if seq.tip_mm is not None else g.index_to_points(
        (np.asarray(vol.shape) - 1) / 2.0)
    c = np.clip(np.rint(g.points_to_index(tip)).astype(int), 0, np.asarray(vol.shape) - 1)
    h = np.maximum(np.rint(3.0 / np.asarray(g.spacing_mm)).astype(int), 1)

    def slab(axis):
        lo, hi = max(c[axis] - h[axis], 0), c[axis] + h[axis] + 1
        return np.take(vol, np.arange(lo, min(hi, vol.shape[axis])), axis=axis).max(axis=axis)

    views = [slab(1), slab(2), slab(0)]  # (z,x), (z,y), (y,x)
    axes = [(2, 0), (1, 0), (2, 1)]  # (col axis, row axis) in array order
    panels = []
    cl_idx = g.points_to_index(seq.centerline_mm[i]) if seq.centerline_mm is not None else None
    tip_idx = g.points_to_index(tip)
    for v, (ca, ra) in zip(views, axes, strict=True):
        p = cv2.cvtColor(np.ascontiguousarray(v), cv2.COLOR_GRAY2BGR)
        p = cv2.resize(p, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
        if cl_idx is not None:
            pts = (np.stack([cl_idx[:, ca], cl_idx[:, ra]], -1) * 2 + 1).astype(np.int32)
            cv2.polylines(p, [pts.reshape(-1, 1, 2)], False, _GREEN, 1, cv2.LINE_AA)
        tp = (int(tip_idx[ca] * 2 + 1), int(tip_idx[ra] * 2 + 1))
        cv2.circle(p, tp, 6, _RED if seq.visible[i] else _BLUE, 1, cv2.LINE_AA)
        panels.append(p)
    h = max(p.shape[0] for p in panels)
    panels = [cv2.copyMakeBorder(p, 0, h - p.shape[0], 0, 4, cv2.BORDER_CONSTANT) for p in panels]
    return np.hstack(panels)


def preview_image(seq: Sequence) -> np.ndarray:
    """A BGR image: first and last frames side by side, ground truth drawn on them
    (green: centreline near the plane; red circle: tip, blue when not visible)."""
    frames = [0, seq.n_frames - 1]
    if seq.ndim == 3:
        rows = [_panel_3d(seq, i) for i in frames]
        w = max(r.shape[1] for r in rows)
        rows = [cv2.copyMakeBorder(r, 0, 4, 0, w - r.shape[1], cv2.BORDER_CONSTANT) for r in rows]
        out = np.vstack(rows)
    else:
        scale = max(1, int(round(256 / max(seq.images.shape[1:]))))
        panels = [_panel_2d(seq, i, scale) for i in frames]
        panels = [cv2.copyMakeBorder(p, 0, 0, 0, 6, cv2.BORDER_CONSTANT) for p in panels]
        out = np.hstack(panels)
    label = f"{seq.meta.get('scenario', seq.modality)}  frames {frames[0]} and {frames[1]}"
    out = cv2.copyMakeBorder(out, 22, 0, 0, 0, cv2.BORDER_CONSTANT)
    cv2.putText(out, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, _WHITE, 1, cv2.LINE_AA)
    return out


def save_preview(seq: Sequence, path, overwrite: bool = False) -> Path:
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"preview {path}: must end in .png")
    if path.exists() and not overwrite:
        raise FileExistsError(f"preview {path} exists; pass --overwrite to replace it")
    if not cv2.imwrite(str(path), preview_image(seq)):
        raise OSError(f"preview {path}: could not be written")
    return path
