"""Figures of an evaluation run: sampled tracks over each scene's map, metric bars model vs reference.

Every function draws onto its own `Figure` (no pyplot state) and writes a PNG to the given
path (the caller's temp name; report.py renames it into place)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from motiongen.skeleton import PELVIS

_COLOURS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2"]


def _figure(w: float, h: float, dpi: int):
    # Imported here, when a figure is drawn: matplotlib is heavy (~0.5 s, paid by evaluation runs
    # that write no plots too if it sat at the top), and choosing its backend on import would
    # change it for every program importing motiongen.
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # heavy, as above
    from matplotlib.figure import Figure  # heavy, as above

    fig = Figure(figsize=(w, h), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def _map(ax, fmap) -> None:
    # Top-down occupancy as the planner sees it: obstacles dark, body-radius margin light grey.
    (x0, z0), (x1, z1) = fmap.bounds
    img = np.where(fmap.open, 1.0, 0.25)
    img = np.where(fmap.open & ~fmap.free, 0.85, img)
    ax.imshow(img.T, origin="lower", extent=(x0, x1, z0, z1), cmap="gray", vmin=0, vmax=1, interpolation="nearest")


def plot_scene_pairs(path, fmap, results, title: str = "", dpi: int = 90) -> Path:
    """One panel per pair of one scene: the map, the A* path and its subgoals, start (circle),
    goal (star; a square marks an interaction goal), the object (triangle, dynamic) and the k
    sampled pelvis tracks (each cut at its finish). results: [PairResult] of one scene."""
    n = max(1, len(results))
    fig = _figure(3.2 * n, 3.6, dpi)
    for i, r in enumerate(results):
        ax = fig.add_subplot(1, n, i + 1)
        _map(ax, fmap)
        route = r.pair.route
        ax.plot(route.path[:, 0], route.path[:, 1], "--", color="#555555", lw=1.0)
        ax.plot(route.subgoals[:, 0], route.subgoals[:, 1], "o", color="#555555", ms=2)
        for s, js in enumerate(r.kept):
            pel = js[:, PELVIS]
            ax.plot(pel[:, 0], pel[:, 2], "-", color=_COLOURS[s % len(_COLOURS)], lw=1.1, alpha=0.85)
        ax.plot(*r.pair.start, "o", color="k", ms=5)
        g = r.pair.goal
        ax.plot(*g.xz, "s" if g.interacts else "*", color="#ffbf00", ms=9 if g.interacts else 13, mec="k", mew=0.7)
        if r.pair.object_pose is not None:
            ax.plot(r.pair.object_pose[0, 3], r.pair.object_pose[2, 3], "^", color="#00c0ff", ms=8, mec="k", mew=0.7)
        d = np.mean([m["goal_dist_m"] for m in r.per_sample])
        ax.set_title(f"pair {r.pair.index}" + (f" ({g.action})" if g.action else "") + f"\ngoal {d:.2f} m, "
                     f"done {r.completed:.0%}", fontsize=8)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
    return _save(fig, path, title)


def _save(fig, path, title: str) -> Path:
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, format="png")
    return path


def plot_metric_bars(path, rows: dict[str, dict], metrics, title: str = "", dpi: int = 90) -> Path:
    """One small bar chart per metric, a bar per row (model, reference); n/a rows leave a gap.
    metrics: [(key, label, unit, arrow)]."""
    keys = [m for m in metrics if any(_num(r.get(m[0])) is not None for r in rows.values())]
    cols = 5
    nrow = max(1, -(-len(keys) // cols))
    fig = _figure(2.6 * cols, 2.2 * nrow, dpi)
    names = list(rows)
    for i, (key, label, unit, arrow) in enumerate(keys):
        ax = fig.add_subplot(nrow, cols, i + 1)
        vals = [_num(rows[n].get(key)) for n in names]
        ax.bar(range(len(names)), [v if v is not None else 0 for v in vals],
               color=[_COLOURS[j % len(_COLOURS)] for j in range(len(names))])
        for j, v in enumerate(vals):
            ax.annotate("n/a" if v is None else f"{v:.3g}", (j, v or 0), ha="center", va="bottom", fontsize=7)
        ax.set_xticks(range(len(names)), names, fontsize=7)
        ax.set_title(f"{label} {arrow}" + (f" [{unit}]" if unit else ""), fontsize=8)
        ax.tick_params(axis="y", labelsize=6)
    return _save(fig, path, title)


def _num(v):
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if np.isfinite(f) else None


__all__ = ["plot_scene_pairs", "plot_metric_bars"]
