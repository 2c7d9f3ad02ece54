"""Static figures of generated motion: top-down trajectories against goals and the planned path."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from motiongen.export.video_frame import SAMPLE_COLOURS
from motiongen.skeleton import PELVIS


def plot_trajectories(path: str | Path, joints: np.ndarray, walkable=None, path_xz: np.ndarray | None = None,
                      subgoals: np.ndarray | None = None, goals: np.ndarray | None = None,
                      arrival_frames: np.ndarray | None = None, title: str = "", dpi: int = 110) -> Path:
    """Top-down PNG (seen from +y: x right, z down) of pelvis trajectories (S, T, J, 3) with the
    walkable map (obstacles dark, body-radius margin light), planned path, subgoals, goals
    (numbered) and where each sample arrived (arrival_frames (S, G), -1 = never)."""
    # Imported here, when a figure is drawn: matplotlib is heavy, and choosing its backend on
    # import would change it for every program that imports motiongen.
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # heavy, as above
    from matplotlib.figure import Figure  # heavy, as above

    path = Path(path)
    joints = np.asarray(joints)
    if joints.ndim == 3:
        joints = joints[None]
    S = joints.shape[0]
    fig = Figure(figsize=(6.4, 6.4), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(111)
    if walkable is not None:
        (x0, z0), (x1, z1) = walkable.bounds
        img = np.where(walkable.open, 1.0, 0.25)
        img = np.where(walkable.open & ~walkable.free, 0.85, img)
        ax.imshow(img.T, origin="lower", extent=(x0, x1, z0, z1), cmap="gray", vmin=0, vmax=1, interpolation="nearest")
    if path_xz is not None and len(path_xz):
        ax.plot(path_xz[:, 0], path_xz[:, 1], "--", color="#555555", lw=1.2, label="planned path")
    if subgoals is not None and len(subgoals):
        ax.plot(subgoals[:, 0], subgoals[:, 1], "o", color="#555555", ms=2.5, label="subgoals")
    for s in range(S):
        pel = joints[s, :, PELVIS]
        ax.plot(pel[:, 0], pel[:, 2], "-", color=SAMPLE_COLOURS[s % 8], lw=1.5, alpha=0.85,
                label=f"sample {s}" if S <= 8 else None)
        ax.plot(pel[0, 0], pel[0, 2], "o", color=SAMPLE_COLOURS[s % 8], ms=5)
        if arrival_frames is not None:
            f = np.asarray(arrival_frames[s])
            f = f[f >= 0]
            ax.plot(pel[f, 0], pel[f, 2], "x", color=SAMPLE_COLOURS[s % 8], ms=7)
    if goals is not None and len(goals):
        ax.plot(goals[:, 0], goals[:, 1], "*", color="#ffbf00", ms=16, mec="k", mew=0.7, label="goals")
        for i, g in enumerate(goals):
            ax.annotate(str(i + 1), g, textcoords="offset points", xytext=(7, 7), fontsize=9)
    ax.set_aspect("equal")
    if walkable is None:
        pts = [joints[:, :, PELVIS][..., [0, 2]].reshape(-1, 2)]
        if goals is not None and len(goals):
            pts.append(np.asarray(goals))
        pts = np.concatenate(pts)
        lo, hi = pts.min(0) - 0.5, pts.max(0) + 0.5
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
    ax.invert_yaxis()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.legend(loc="best", fontsize=7)
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path
