"""TensorBoard figures: sampled windows vs ground truth (top-down paths with goals, skeleton strip)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from motiongen.skeleton import BODY_PARENTS  # noqa: E402
from motiongen.loading.build import sample_windows  # noqa: E402


def _bones(ax, pose: np.ndarray, color, dx: float = 0.0) -> None:
    """Draw one pose (J, 3) side-on (x, y), shifted by dx."""
    for j, p in enumerate(BODY_PARENTS[: pose.shape[0]]):
        if p >= 0:
            ax.plot([pose[j, 0] + dx, pose[p, 0] + dx], [pose[j, 1], pose[p, 1]], color=color, lw=1)


def window_figure(gt: np.ndarray, gen: np.ndarray, goals: np.ndarray) -> plt.Figure:
    """gt, gen: (N, L, J, 3) local joints in metres; goals: (N, 3)."""
    N = gt.shape[0]
    fig, axes = plt.subplots(2, N, figsize=(3.2 * N, 6), squeeze=False)
    for i in range(N):
        ax = axes[0, i]
        ax.plot(gt[i, :, 0, 0], gt[i, :, 0, 2], "-o", ms=2, color="tab:gray", label="ground truth")
        ax.plot(gen[i, :, 0, 0], gen[i, :, 0, 2], "-o", ms=2, color="tab:blue", label="sample")
        ax.plot(goals[i, 0], goals[i, 2], "r*", ms=10, label="goal")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"window {i}: pelvis x–z")
        if i == 0:
            ax.legend(fontsize=7)
        ax = axes[1, i]
        L = gt.shape[1]
        for k, f in enumerate(np.linspace(0, L - 1, 4).astype(int)):
            _bones(ax, gt[i, f] - gt[i, f, 0] * [1, 0, 1], "tab:gray", dx=k * 0.9)
            _bones(ax, gen[i, f] - gen[i, f, 0] * [1, 0, 1], "tab:blue", dx=k * 0.9)
        ax.set_aspect("equal")
        ax.set_title("skeleton strip (gray: GT)")
    fig.tight_layout()
    return fig


@torch.no_grad()
def log_sample_figure(writer, model, diffusion, dataset, cfg, device, step: int, n: int = 4) -> None:
    idx = np.linspace(0, len(dataset) - 1, n).astype(int)
    batch = torch.utils.data.default_collate([dataset[int(i)] for i in idx])
    gen = torch.Generator(device=device).manual_seed(0)
    x = sample_windows(model, diffusion, batch, cfg, device, gen)                 # (n, L, D) normalised
    stats, layout = dataset.stats, dataset.layout
    to_np = lambda a: layout.decode(stats.denormalize(a.float().cpu()).numpy())[0]  # (n, L, J, 3)  # noqa: E731
    fig = window_figure(to_np(batch["motion"]), to_np(x), batch["goal"].numpy())
    writer.add_figure("samples/windows", fig, step)
    plt.close(fig)
