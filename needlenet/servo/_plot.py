"""Trajectory plots of closed-loop runs drawn with OpenCV (matplotlib is not a dependency)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

__all__ = ["plot_runs"]

_TRUE, _EST, _PROBE = (40, 150, 40), (40, 40, 220), (200, 110, 30)  # BGR
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _panel(img, x0, y0, w, h, t, series, title):
    cv2.rectangle(img, (x0, y0), (x0 + w, y0 + h), (0, 0, 0), 1)
    cv2.putText(img, title, (x0 + 4, y0 - 6), _FONT, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    vals = np.concatenate([np.asarray(y, float)[np.isfinite(y)] for y, _ in series] or [[0.0]])
    lo, hi = (float(vals.min()), float(vals.max())) if vals.size else (0.0, 1.0)
    if hi - lo < 1e-9:
        lo, hi = lo - 1.0, hi + 1.0
    pad = 0.05 * (hi - lo)
    lo, hi = lo - pad, hi + pad
    t = np.asarray(t, float)
    tx = x0 + (t - t.min()) / max(float(np.ptp(t)), 1e-9) * w
    for y, color in series:
        y = np.asarray(y, float)
        py = y0 + h - (y - lo) / (hi - lo) * h
        ok = np.isfinite(py)
        # draw each finite run as one polyline (gaps where the needle was not seen)
        breaks = np.flatnonzero(np.diff(ok.astype(int)) != 0) + 1
        for seg in np.split(np.arange(len(t)), breaks):
            if len(seg) and ok[seg[0]]:
                pts = np.stack([tx[seg], py[seg]], -1).round().astype(np.int32)
                cv2.polylines(img, [pts], False, color, 1, cv2.LINE_AA)
    for v, yy in ((hi - pad, y0 + 12), (lo + pad, y0 + h - 4)):
        cv2.putText(img, f"{v:.1f}", (x0 - 46, yy), _FONT, 0.35, (0, 0, 0), 1, cv2.LINE_AA)


def plot_runs(traces, path, title: str = "") -> Path:
    """One row of panels per run: X, Y, Z of the true tip (green), its estimate (red) and the
    probe (blue) over time; a PNG at ``path``."""
    traces = list(traces)
    if not traces:
        raise ValueError("nothing to plot")
    w, h, mx, my = 330, 150, 60, 40
    W = mx + 3 * (w + mx)
    H = 30 + len(traces) * (h + my + 10) + 20
    img = np.full((H, W, 3), 255, np.uint8)
    cv2.putText(img, title, (mx, 20), _FONT, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    for i, tr in enumerate(traces):
        y0 = 30 + my + i * (h + my + 10)
        raw = tr.raw
        if tr.scenario == "servo":
            label = f"{raw.get('gain')}-{raw.get('filter')}"
            axes = ("X (world, mm)", "Y (world, mm)", "Z (world, mm)")
        else:
            label = f"{raw.get('features')} {raw.get('run')}"
            axes = ("tip x (probe, mm)", "tip y (probe, mm)", "tip z (probe, mm)")
        for a in range(3):
            series = [(tr.p_true[:, a], _TRUE), (tr.p_hat[:, a], _EST)]
            if tr.scenario == "servo" and a < 2:
                series.append((tr.probe[:, a], _PROBE))
            if tr.scenario != "servo" and a < 2:
                series.append((tr.probe[:, a], _PROBE))  # probe position, world
            _panel(img, mx + a * (w + mx), y0, w, h, tr.t, series, f"{label}: {axes[a]}")
    cv2.putText(img, "green: true tip   red: estimate   blue: probe   x axis: time (s)",
                (mx, H - 8), _FONT, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    path = Path(path)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"cannot write {path}")
    return path
