"""Does the network follow a hand goal? (not a timed test) On the validation windows that end
in a pick-up, the reaching wrist's own last-frame position is given as the goal (with the
window's first 2 frames and its last-frame pelvis x, z, as the sampler gives them), and the
network's wrist at that frame is compared with it: the median miss with and without the hand
goal, in the same run with the same noise. A network that follows the goal misses by little
more than it misses the pelvis goal; one that ignores it misses by about as much as without.
Also where the goal lies in the body's own frame at the window's first and last frames, how
far the body turns over the window, and how far off its direction of travel the walking body
faces (the split's sequences at the model's rate): what `hand_goal_episodes.py` prints for the
sampler's episodes, here for the data's.

    python benchmarks/hand_goal.py ckpt=PATH [split=val] [windows=120] [steps=10]
"""

from __future__ import annotations

import numpy as np
import torch

from motiongen.cli import parse_key_values, tool_main
from motiongen.data.windows import WindowDataset
from motiongen.diffusion import sample
from motiongen.diffusion.masks import MaskConfig, known_mask, replace_mask
from motiongen.eval.evaluate_config import dataset_config
from motiongen.geometry import canonical_frame, facing_yaw, invert_rigid, transform_points
from motiongen.importers.sources import open_dataset
from motiongen.loading.build import acting_hands, load_model
from motiongen.metrics import heading_off_travel_angles
from motiongen.models import Condition
from motiongen.skeleton import HAND_JOINTS

SPEC = {"ckpt": (str, None), "split": (str, "val"), "windows": (int, 120), "steps": (int, 10)}
HAND_ACTION = "pick up"


def pick_up_windows(loaded, ds, split: str, n: int) -> dict:
    """A batch of up to n windows of `split` whose last frame is labelled a pick-up (fixed draw)."""
    windows = WindowDataset(ds, split, loaded.window, loaded.stats)
    a = loaded.action_names.index(HAND_ACTION)
    idx = [i for i in range(len(windows)) if ds.actions[windows.window_frames(i)[-1], a] > 0]
    idx = sorted(np.random.default_rng(0).choice(idx, min(n, len(idx)), replace=False))
    items = [windows[int(i)] for i in idx]
    return {k: torch.stack([it[k] for it in items]) for k in items[0]}


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, required=("ckpt",), usage=__doc__.splitlines()[-2].strip())
    loaded = load_model(opts["ckpt"])
    ds = open_dataset(dataset_config(None, loaded.config), verbose=False)
    batch = pick_up_windows(loaded, ds, opts["split"], opts["windows"])
    _, wrist = acting_hands(MaskConfig(p_hand_action=1.0, hand_joints=HAND_JOINTS), batch, loaded.layout, loaded.stats,
                            loaded.action_names)                                               # (B,) the reaching wrist
    x0 = batch["motion"]                                                                       # (B, L, D)
    B, L, D = x0.shape
    cond = Condition(scene=batch.get("scene"), actions=batch["actions"])
    truth, _ = loaded.layout.decode(loaded.stats.denormalize(x0))                              # (B, L, J, 3)
    rows = torch.arange(B)
    print(f"{opts['ckpt']}: {B} {opts['split']} windows ending in a pick-up, DDIM-{opts['steps']}; "
          f"the reaching wrist moves {(truth[rows, -1, wrist] - truth[rows, 0, wrist]).norm(dim=-1).median():.3f} m "
          f"over a window (median)")
    for hand in (False, True):
        mask = known_mask(B, L, loaded.joint_set.num_joints, 2, True, False, hand, wrist, channels=D)
        x = sample(loaded.diffusion, loaded.model, x0.shape, cond, known=x0, known_mask=mask, sampler="ddim",
                   steps=opts["steps"], generator=torch.Generator().manual_seed(0),
                   replace_mask=replace_mask(mask, loaded.predict_goal))
        pred, _ = loaded.layout.decode(loaded.stats.denormalize(x))
        miss = (pred[rows, -1, wrist] - truth[rows, -1, wrist]).norm(dim=-1)
        pelvis = (pred[:, -1, 0, [0, 2]] - truth[:, -1, 0, [0, 2]]).norm(dim=-1)
        print(f"  hand goal {'given' if hand else 'not given':9s}: wrist misses it by {miss.median():.3f} m "
              f"(median), the pelvis goal (x, z) by {pelvis.median():.3f} m")
    print_goal_geometry("the data", truth.numpy(), wrist.numpy(), truth[rows, -1, wrist].numpy())
    stride = loaded.window.stride
    off = [heading_off_travel_angles(np.asarray(j, np.float64)[::stride], ds.fps / stride)
           for _, j in ds.iter_sequences(opts["split"])]
    print(f"  the data, walking, faces {quartiles(np.concatenate(off), '°')} off its direction of travel")


def print_goal_geometry(what: str, joints: np.ndarray, wrist: np.ndarray, goal: np.ndarray) -> None:
    """Where the hand goals lie from the body: joints (N, L, J, 3) world, wrist (N,) the reaching
    wrist, goal (N, 3) world. Forward, and sideways towards the reaching hand's own side
    (negative: across the body), at the window's first and last frames; the body's turn."""
    side = np.where(wrist == HAND_JOINTS[0], 1.0, -1.0)                                  # left wrist: +left
    for name, f in (("first", 0), ("last", -1)):
        to_body = invert_rigid(canonical_frame(joints[:, f]))                             # (N, 4, 4) world -> body
        off = transform_points(to_body, goal[:, None])[:, 0]                              # (N, 3) left, y, forward
        print(f"  {what}, goal from the body at the window's {name} frame: forward "
              f"{quartiles(off[:, 2])}, towards the hand's side {quartiles(off[:, 0] * side)}")
    yaw = facing_yaw(joints[:, [0, -1]])                                                  # (N, 2)
    print(f"  {what}, the body turns over the window by {quartiles(yaw_apart(yaw[:, 1], yaw[:, 0]), '°')}")


def yaw_apart(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Degrees in [0, 180] between yaws a and b (radians, any shape), across the ±π wrap."""
    return np.degrees(np.abs(np.angle(np.exp(1j * (a - b)))))


def quartiles(v: np.ndarray, unit: str = " m") -> str:
    q = np.percentile(v, [25, 50, 75])
    return f"{q[1]:.2f}{unit} ({q[0]:.2f} – {q[2]:.2f})"


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
