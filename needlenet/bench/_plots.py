"""Plots of the benchmark suites (matplotlib, Agg backend): error CDFs, error over frames,
the failure-rate heatmap, latency bars and servo trajectories.

Each ``plot_<suite>(result, traces, out_dir)`` writes PNG files into ``out_dir`` and returns
``[(caption, file name), ...]`` for the report. Classical features are drawn in blue, learned
ones in orange, throughout.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

COLOURS = {"classical": "#1f77b4", "learned": "#ff7f0e", "ideal": "#2ca02c"}


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, out_dir: Path, name: str) -> str:
    fig.tight_layout()
    fig.savefig(out_dir / name, dpi=110)
    _plt().close(fig)
    return name


def _cdf(ax, values, label, colour, style="-"):
    v = np.sort(np.asarray(values, float)[np.isfinite(values)])
    if v.size == 0:
        return
    ax.step(v, np.arange(1, v.size + 1) / v.size, where="post", label=label, color=colour,
            linestyle=style)


def plot_inplane(result: dict, traces: dict, out_dir: Path) -> list[tuple[str, str]]:
    plt = _plt()
    out = []
    norm = traces.get("norm_e_mm", {})
    if norm:
        fig, ax = plt.subplots(figsize=(6.4, 4.2))
        methods = sorted({m for m, _ in norm})
        styles = ["-", "--", ":", "-."]
        for i, m in enumerate(methods):
            for kind in ("classical", "learned"):
                if (m, kind) in norm:
                    _cdf(ax, norm[m, kind], f"{m} {kind}", COLOURS[kind],
                         styles[i % len(styles)])
        ax.axhline(0.95, color="0.6", lw=0.8)
        ax.set_xlabel("tip error ‖e‖ (mm)")
        ax.set_ylabel("fraction of frames")
        ax.set_xlim(left=0)
        hi = max(np.nanpercentile(v, 99) for v in norm.values() if np.size(v))
        ax.set_xlim(0, max(1.0, 1.1 * hi))
        ax.set_title("In-plane (Mathiassen protocol): CDF of the tip error")
        ax.legend(fontsize=7, ncol=2)
        out.append(("In-plane tip error CDF, classical vs learned features",
                    _save(fig, out_dir, "inplane_error_cdf.png")))
    ex = traces.get("example", {})
    if ex:
        fig, ax = plt.subplots(figsize=(6.4, 3.4))
        for (m, kind), (_, _, err) in sorted(ex.items()):
            ax.plot(np.asarray(err, float), label=f"{m} {kind}", color=COLOURS[kind])
        ax.set_xlabel("frame")
        ax.set_ylabel("‖e‖ (mm)")
        ax.set_title("In-plane tip error over the frames of the first sequence")
        ax.legend(fontsize=8)
        out.append(("In-plane tip error over frames (first sequence)",
                    _save(fig, out_dir, "inplane_error_frames.png")))
    return out


def plot_axial(result: dict, traces: dict, out_dir: Path) -> list[tuple[str, str]]:
    plt = _plt()
    out = []
    rows = result["rows"]
    if rows:
        fig, ax = plt.subplots(figsize=(6.4, 3.6))
        labels = sorted({(r["D_mm"], r["method"]) for r in rows})
        x = np.arange(len(labels))
        for j, kind in enumerate(("classical", "learned")):
            vals = [next((r["tip_prediction_error_mm"] for r in rows if r["features"] == kind
                          and (r["D_mm"], r["method"]) == lab), np.nan) for lab in labels]
            ax.bar(x + (j - 0.5) * 0.38, vals, 0.38, label=kind, color=COLOURS[kind])
        ax.set_xticks(x, [f"D={d:.0f}\n{m}" for d, m in labels], fontsize=8)
        ax.set_ylabel("tip prediction error (mm)")
        ax.set_title("Axial (Carriere protocol): tip prediction error")
        ax.legend()
        out.append(("Axial tip prediction error", _save(fig, out_dir, "axial_tip_error.png")))
    te = traces.get("tracking_error_mm", {})
    if te:
        fig, ax = plt.subplots(figsize=(6.4, 3.4))
        for (D, filt, kind), err in sorted(te.items()):
            if filt != "paper":
                continue
            ax.plot(np.arange(len(err)) * 0.5, err, label=f"D={D:.0f} {kind}",
                    color=COLOURS[kind], alpha=1.0 if D == 60 else 0.6)
        ax.set_xlabel("insertion depth of the slice (mm)")
        ax.set_ylabel("cross-section error (mm)")
        ax.set_title("Axial tracking error over the slices")
        ax.legend(fontsize=8)
        out.append(("Axial tracking error over the slices",
                    _save(fig, out_dir, "axial_error_frames.png")))
    return out


def plot_volume(result: dict, traces: dict, out_dir: Path) -> list[tuple[str, str]]:
    plt = _plt()
    out = []
    t3 = [r for r in result["rows"] if r.get("table") == 3]
    if t3:
        crs = sorted({r["cr"] for r in t3})
        keys = sorted({(r["features"], r["threshold"] or 0) for r in t3})
        grid = np.full((len(keys), len(crs)), np.nan)
        for r in t3:
            i = keys.index((r["features"], r["threshold"] or 0))
            if r["failure_rate"] is not None:
                grid[i, crs.index(r["cr"])] = 100 * r["failure_rate"]
        fig, ax = plt.subplots(figsize=(5.6, 0.5 * len(keys) + 1.6))
        im = ax.imshow(grid, cmap="RdYlGn_r", vmin=0, vmax=100, aspect="auto")
        for i in range(grid.shape[0]):
            for j in range(grid.shape[1]):
                if np.isfinite(grid[i, j]):
                    ax.text(j, i, f"{grid[i, j]:.0f}%", ha="center", va="center", fontsize=8)
        ax.set_xticks(range(len(crs)), [f"CR {c}" for c in crs])
        ax.set_yticks(range(len(keys)),
                      [f"threshold {t}" if k == "classical" else "learned likelihood"
                       for k, t in keys])
        ax.set_title("ROI-RK failure rate (Zhao Table 3 layout)")
        fig.colorbar(im, ax=ax, label="failure rate (%)")
        out.append(("Volume: failure rate over CR and threshold",
                    _save(fig, out_dir, "volume_failure_heatmap.png")))
    tips = traces.get("tip_error_mm", {})
    if tips:
        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        styles = {"ransac": ":", "roi-rk": "-", "chatelain": "--"}
        for (alpha, m, kind), err in sorted(tips.items()):
            if alpha != 0.0:
                continue
            _cdf(ax, err, f"{m} {kind}", COLOURS[kind], styles.get(m, "-"))
        ax.axvline(3.0, color="0.6", lw=0.8)
        ax.set_xlabel("tip error (mm); failure above 3 mm")
        ax.set_ylabel("fraction of volumes")
        ax.set_xlim(0, 10)
        ax.set_title("Volume (CR 4.7, alpha 0): CDF of the tip error")
        ax.legend(fontsize=8)
        out.append(("Volume tip error CDF", _save(fig, out_dir, "volume_error_cdf.png")))
    return out


def plot_latency(result: dict, traces: dict, out_dir: Path) -> list[tuple[str, str]]:
    plt = _plt()
    rows = result["rows"]
    if not rows:
        return []
    labels = sorted({(r["tracker"], r["method"]) for r in rows})
    fig, ax = plt.subplots(figsize=(7.0, 0.32 * len(labels) + 1.5))
    y = np.arange(len(labels))
    for j, kind in enumerate(("classical", "learned")):
        med = [next((r["latency_median_ms"] for r in rows if r["features"] == kind
                     and (r["tracker"], r["method"]) == lab), np.nan) for lab in labels]
        p99 = [next((r["latency_p99_ms"] for r in rows if r["features"] == kind
                     and (r["tracker"], r["method"]) == lab), np.nan) for lab in labels]
        ax.barh(y + (j - 0.5) * 0.38, med, 0.38, color=COLOURS[kind], label=f"{kind} median")
        ax.plot(p99, y + (j - 0.5) * 0.38, "k|", ms=8)
    ax.set_yticks(y, [f"{t}/{m}" for t, m in labels], fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("ms per frame (bar: median, tick: p99)")
    ax.set_title("Tracker latency per frame")
    ax.legend(fontsize=8)
    return [("Latency per frame", _save(fig, out_dir, "latency.png"))]


def plot_servo(result: dict, traces: dict, out_dir: Path) -> list[tuple[str, str]]:
    """Ye's loop: true tip, estimate and probe along X (insertion) and Y; Chatelain's: the tip
    in the probe frame (true and estimated), which the servoing drives to X = Z = 0."""
    plt = _plt()
    out = []
    for key, tr in sorted(traces.get("runs", {}).items()):
        t = np.asarray(tr["t"], float)
        chatelain = str(key[0]).startswith("chatelain")
        comps = (0, 2) if chatelain else (0, 1)
        names = ("X (mm)", "Z (mm)") if chatelain else ("x (mm)", "y (mm)")
        fig, axes = plt.subplots(2, 1, figsize=(6.4, 5.0), sharex=True)
        p_true, p_hat = np.asarray(tr["p_true"], float), np.asarray(tr["p_hat"], float)
        for ax, c, name in zip(axes, comps, names, strict=True):
            if chatelain:
                ax.plot(t, p_true[:, c], color="k", lw=1.2, label="true tip")
                ax.plot(t, p_hat[:, c], color=COLOURS["learned"], lw=1, label="estimated tip")
                ax.set_ylabel("tip in probe frame, " + name)
            else:  # Ye: over 80 s the paths overlap; show them relative to the true tip
                probe = np.asarray(tr["probe"], float)
                ax.axhline(0.0, color="k", lw=1.2, label="true tip")
                ax.plot(t, p_hat[:, c] - p_true[:, c], color=COLOURS["learned"], lw=0.8,
                        label="estimate - tip")
                ax.plot(t, probe[:, c] - p_true[:, c], color=COLOURS["classical"], lw=0.8,
                        label="probe - tip")
                ax.set_ylabel(name.replace("(mm)", "relative to the tip (mm)"))
        axes[0].legend(fontsize=8)
        axes[-1].set_xlabel("time (s)")
        label = " ".join(str(k) for k in key)
        axes[0].set_title(f"Servo: {label}")
        name = "servo_" + "_".join(str(k) for k in key).replace(" ", "_").replace("/", "-")
        out.append((f"Servo trajectories ({label})", _save(fig, out_dir, name + ".png")))
    return out


PLOTS = {"inplane": plot_inplane, "axial": plot_axial, "volume": plot_volume,
         "latency": plot_latency, "servo": plot_servo}
