"""Does the network follow a facing goal? (not a timed test) On validation windows whose body
turns by at least `min_turn` degrees, the network is given the window's first 2 frames and its
last-frame pelvis x, z (as the sampler gives them) and, in a second run with the same noise,
also the last-frame hips' x, z (`mask.p_facing`): the facing at the last frame is compared with
the data's. A network that follows the goal ends within a few degrees of it; one that ignores
it about as far off as without.

    python benchmarks/facing_goal.py ckpt=PATH [split=val] [windows=200] [steps=10] [min_turn=30]
"""

from __future__ import annotations

import numpy as np
import torch

from motiongen.cli import parse_key_values, tool_main
from motiongen.data.windows import WindowDataset
from motiongen.diffusion import sample
from motiongen.diffusion.masks import known_mask, replace_mask
from motiongen.eval.evaluate_config import dataset_config
from motiongen.geometry import facing_yaw
from motiongen.importers.sources import open_dataset
from motiongen.loading.build import load_model
from motiongen.models import Condition

SPEC = {"ckpt": (str, None), "split": (str, "val"), "windows": (int, 200), "steps": (int, 10),
        "min_turn": (float, 30.0)}


def _turn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|b - a| in degrees, wrapped to [0, 180]."""
    return np.degrees(np.abs(np.angle(np.exp(1j * (b - a)))))


def turning_windows(loaded, ds, split: str, n: int, min_turn: float) -> dict:
    """A batch of up to n windows of `split` whose body turns by at least min_turn degrees
    between the first and last frames (a fixed draw)."""
    windows = WindowDataset(ds, split, loaded.window, loaded.stats)
    idx = []
    for i in range(len(windows)):
        j = ds.joints[windows.window_frames(i)[[0, -1]]].astype(np.float64)                 # (2, J, 3)
        yaw = facing_yaw(j)
        if _turn(yaw[0], yaw[1]) >= min_turn:
            idx.append(i)
    idx = sorted(np.random.default_rng(0).choice(idx, min(n, len(idx)), replace=False))
    items = [windows[int(i)] for i in idx]
    return {k: torch.stack([it[k] for it in items]) for k in items[0]}


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, required=("ckpt",), usage=__doc__.splitlines()[-2].strip())
    loaded = load_model(opts["ckpt"])
    ds = open_dataset(dataset_config(None, loaded.config), verbose=False)
    batch = turning_windows(loaded, ds, opts["split"], opts["windows"], opts["min_turn"])
    x0 = batch["motion"]                                                                       # (B, L, D)
    B, L, D = x0.shape
    cond = Condition(scene=batch.get("scene"), actions=batch["actions"])
    truth, _ = loaded.layout.decode(loaded.stats.denormalize(x0))                              # (B, L, J, 3)
    truth = truth.numpy()
    want = facing_yaw(truth[:, -1])                                                            # (B,)
    print(f"{opts['ckpt']}: {B} {opts['split']} windows turning by ≥ {opts['min_turn']:g}° "
          f"(median {np.median(_turn(facing_yaw(truth[:, 0]), want)):.0f}°), DDIM-{opts['steps']}; "
          f"trained with mask.p_facing={loaded.mask.p_facing:g}")
    for facing in (False, True):
        mask = known_mask(B, L, loaded.joint_set.num_joints, 2, True, False, channels=D, facing=facing)
        x = sample(loaded.diffusion, loaded.model, x0.shape, cond, known=x0, known_mask=mask, sampler="ddim",
                   steps=opts["steps"], generator=torch.Generator().manual_seed(0),
                   replace_mask=replace_mask(mask, loaded.predict_goal))
        pred, _ = loaded.layout.decode(loaded.stats.denormalize(x))
        err = _turn(facing_yaw(pred.numpy()[:, -1]), want)
        q = np.percentile(err, [25, 50, 75])
        print(f"  facing goal {'given' if facing else 'not given':9s}: the last frame faces {q[1]:.1f}° off the "
              f"data's (quartiles {q[0]:.1f}, {q[2]:.1f})")


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
