"""Penetration statistics of per-vertex contact labels, as in TRUMANS supp. Fig. A3: per frame
the maximum, mean and median penetration depth over the vertices that penetrate (0 when none
does); the share of frames below depth thresholds (a table and the figure's left panel) and
frames by depth range (the right panel)."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

STATS = ("max", "mean", "median")
THRESHOLDS_CM = (0.5, 1.0, 2.0, 3.0, 5.0, 10.0)
BINS_CM = (0.0, 0.5, 1.0, 2.0, 5.0, 10.0, np.inf)


def penetration_table(pen: np.ndarray, penetrating: np.ndarray | None = None) -> dict:
    """Summary of per-frame depths pen (N, 3) metres (columns max, mean, median):
    {"frames", "frames_penetrating", "share_below": {stat: {"<t cm": share}}, "mean_cm": {stat: ...},
    "median_cm": {...}, "p95_cm": {...}}. Shares are of all frames."""
    pen = np.asarray(pen, np.float64)
    N = len(pen)
    out = {"frames": int(N), "frames_penetrating": int((pen[:, 0] > 0).sum()) if N else 0,
           "share_below": {}, "mean_cm": {}, "median_cm": {}, "p95_cm": {}}
    if penetrating is not None:
        out["mean_penetrating_vertices"] = float(np.mean(penetrating)) if N else 0.0
    for i, s in enumerate(STATS):
        cm = pen[:, i] * 100
        out["share_below"][s] = {f"<{t:g} cm": float((cm < t).mean()) if N else 1.0 for t in THRESHOLDS_CM}
        out["mean_cm"][s] = float(cm.mean()) if N else 0.0
        out["median_cm"][s] = float(np.median(cm)) if N else 0.0
        out["p95_cm"][s] = float(np.percentile(cm, 95)) if N else 0.0
    return out


def write_table(path: str | Path, table: dict) -> Path:
    """CSV: one row per statistic, the share of frames below each threshold, then mean/median/p95."""
    path = Path(path)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["statistic"] + [f"share <{t:g} cm" for t in THRESHOLDS_CM] + ["mean cm", "median cm", "p95 cm"])
        for s in STATS:
            w.writerow([s] + [f"{table['share_below'][s][f'<{t:g} cm']:.4f}" for t in THRESHOLDS_CM]
                       + [f"{table[k][s]:.3f}" for k in ("mean_cm", "median_cm", "p95_cm")])
    os.replace(tmp, path)
    return path


def plot_penetration(path: str | Path, pen: np.ndarray, title: str = "", dpi: int = 100) -> Path:
    """Fig. A3: left, share of frames whose max / mean / median penetration is below x cm;
    right, frames by penetration range."""
    # Imported here, when the figure is drawn: matplotlib is heavy (~0.5 s), the table needs only
    # numpy, and choosing its backend on import would change it for every program importing motiongen.
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # heavy, as above
    from matplotlib.figure import Figure  # heavy, as above

    cm = np.asarray(pen, np.float64) * 100                                          # (N, 3)
    N = max(len(cm), 1)
    fig = Figure(figsize=(10, 3.8), dpi=dpi)
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2)
    xs = np.linspace(0, max(10.0, float(np.percentile(cm[:, 0], 99)) if len(cm) else 10.0), 200)
    for i, s in enumerate(STATS):
        left.plot(xs, [(cm[:, i] < x).sum() / N for x in xs], label=s)
    left.set_xlabel("penetration depth threshold (cm)")
    left.set_ylabel("share of frames below")
    left.set_ylim(0, 1.02)
    left.grid(alpha=0.3)
    left.legend()
    labels = [f"{a:g}-{b:g}" if np.isfinite(b) else f">={a:g}" for a, b in zip(BINS_CM[:-1], BINS_CM[1:])]
    x = np.arange(len(labels))
    for i, s in enumerate(STATS):
        counts = np.histogram(cm[:, i], bins=np.asarray(BINS_CM))[0]
        right.bar(x + (i - 1) * 0.27, counts / N, width=0.27, label=s)
    right.set_xticks(x, labels)
    right.set_xlabel("penetration depth (cm)")
    right.set_ylabel("share of frames")
    right.legend()
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.png")
    fig.savefig(tmp)
    os.replace(tmp, path)
    return path
