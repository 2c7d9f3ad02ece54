"""Which way does the network's body face, on the data's own windows? (not a timed test)

On `windows` validation windows drawn at random, the network is given what the sampler gives a
walking episode (the window's first 2 frames, its last-frame pelvis x, z) and its prediction is
compared with the data's window:
- how far off its direction of travel the walking body faces (`metrics.heading_off_travel`),
  with the facing taken from the hips (as every table does) and from the shoulders;
- the distance between the two hips, which a rigid pelvis keeps (the data's is constant) and
  which no bone-length figure sees: a hip folded in under the pelvis keeps its bone's length;
- how far the last frame's facing (from the hips) is from the data's, over all windows and over
  those whose body turns by 30° or more, with how far the data and the network turn there
  (and, for a model trained with a facing goal, the same given the data's facing).
A network whose hips fold in has a facing that the hips no longer tell; one whose shoulders are
also off its travel walks sideways.

    python benchmarks/network_facing.py ckpt=PATH [split=val] [windows=200] [steps=10]
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from hand_goal import quartiles, yaw_apart

from motiongen.cli import parse_key_values, tool_main
from motiongen.data.windows import WindowDataset
from motiongen.errors import ConfigError
from motiongen.eval.evaluate_config import dataset_config
from motiongen.geometry import facing_yaw
from motiongen.importers.sources import open_dataset
from motiongen.loading.build import last_facing, load_model, sample_windows
from motiongen.metrics import heading_off_travel_angles
from motiongen.skeleton import LEFT_HIP, LEFT_SHOULDER, RIGHT_HIP, RIGHT_SHOULDER

TURNING_DEG = 30                     # a window whose body turns this much from its first frame to its last
SPEC = {"ckpt": (str, None), "split": (str, "val"), "windows": (int, 200), "steps": (int, 10)}


def files_and_keys(argv: list[str], spec: dict, usage: str, doc: str) -> tuple[list[str], dict]:
    """The files (arguments without `=`) and the key=value options of a benchmark that reads
    `sample` outputs; a bad key or value, or a file that is not there, raises ConfigError."""
    paths = [a for a in argv if "=" not in a and not a.startswith("-")]
    opts = parse_key_values([a for a in argv if a not in paths], spec, usage=usage, doc=doc)
    for path in paths:
        if not Path(path).is_file():
            raise ConfigError(f"{path}: no such file")
    return paths, opts


def model_and_data(ckpt: str):
    """(the loaded checkpoint, the dataset it was trained on)."""
    loaded = load_model(ckpt)
    return loaded, open_dataset(dataset_config(None, loaded.config), verbose=False)


def random_windows(loaded, ds, split: str, n: int) -> dict:
    """A batch of up to n windows of `split` (fixed draw)."""
    windows = WindowDataset(ds, split, loaded.window, loaded.stats)
    idx = sorted(np.random.default_rng(0).choice(len(windows), min(n, len(windows)), replace=False))
    items = [windows[int(i)] for i in idx]
    return {k: torch.stack([it[k] for it in items]) for k in items[0]}


def predict_on_windows(loaded, ds, split: str, n: int, steps: int,
                       facing: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """The data's joints and the network's on up to n windows of `split`, each (B, L, J, 3) in
    metres, and their frame rate. The network is given what the sampler gives a walking episode:
    the window's first 2 frames and its last-frame pelvis x, z (DDIM-`steps`, fixed noise);
    with `facing`, also the data's last-frame facing (a model trained with `mask.p_facing`)."""
    batch = random_windows(loaded, ds, split, n)
    x0 = batch["motion"]                                                                       # (B, L, D)
    goal = last_facing(x0, loaded.layout, loaded.stats) if facing else None                   # (B, 2)
    x = sample_windows(loaded.model, loaded.diffusion, batch, loaded.config, loaded.device,
                       torch.Generator().manual_seed(0), steps, goal)
    data, net = (loaded.layout.decode(loaded.stats.denormalize(m))[0].numpy().astype(np.float64) for m in (x0, x))
    return data, net, loaded.model_fps


def off_travel(joints: np.ndarray, fps: float, pair: tuple[int, int]) -> np.ndarray:
    """Facing-off-travel angles (degrees) of windows joints (N, L, J, 3), the facing taken from
    the joint pair (left, right) put where the hips are (`heading_off_travel_angles` reads the hips)."""
    j = joints.copy()
    j[..., [LEFT_HIP, RIGHT_HIP], :] = joints[..., list(pair), :]
    return np.concatenate([heading_off_travel_angles(w, fps) for w in j])


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, required=("ckpt",), usage=__doc__.splitlines()[-2].strip())
    loaded, ds = model_and_data(opts["ckpt"])
    data, net, fps = predict_on_windows(loaded, ds, opts["split"], opts["windows"], opts["steps"])
    print(f"{opts['ckpt']}: {len(data)} {opts['split']} windows, first 2 frames and last-frame pelvis x, z given, "
          f"DDIM-{opts['steps']}")
    rows = {"the data": data, "the network": net}
    for name, j in rows.items():                                                               # (B, L, J, 3)
        width = np.linalg.norm(j[..., LEFT_HIP, :] - j[..., RIGHT_HIP, :], axis=-1)           # (B, L)
        hips, shoulders = off_travel(j, fps, (LEFT_HIP, RIGHT_HIP)), off_travel(j, fps, (LEFT_SHOULDER, RIGHT_SHOULDER))
        print(f"  {name}: walking, faces {quartiles(hips, '°')} off its direction of travel by the hips, "
              f"{quartiles(shoulders, '°')} by the shoulders")
        print(f"  {name}: hips {quartiles(100 * width[:, 2:].ravel(), ' cm')} apart on the free frames "
              f"(spread within a window {100 * width[:, 2:].std(1).mean():.2f} cm)")
    last_frame_facing(data, net, "")
    if loaded.mask.p_facing > 0:
        _, given, _ = predict_on_windows(loaded, ds, opts["split"], opts["windows"], opts["steps"], facing=True)
        last_frame_facing(data, given, ", given the data's as a facing goal")


def last_frame_facing(data: np.ndarray, net: np.ndarray, given: str) -> None:
    """Print how far the network's last-frame facing (hips) is from the data's, over all windows
    (N, L, J, 3) and over those whose body turns by 30° or more from its first frame."""
    yaw = facing_yaw(np.stack([data[:, -1], net[:, -1]]))                                     # (2, B)
    off = yaw_apart(yaw[1], yaw[0])
    turn = yaw_apart(yaw[0], facing_yaw(data[:, 0]))                                           # (B,)
    turning = turn >= TURNING_DEG
    if not turning.any():
        print(f"  the last frame's facing (hips) is {quartiles(off, '°')} off the data's{given}; no window turns by "
              f"{TURNING_DEG}° or more")
        return
    net_turn = yaw_apart(yaw[1], facing_yaw(net[:, 0]))                                        # (B,)
    print(f"  the last frame's facing (hips) is {quartiles(off, '°')} off the data's{given}; "
          f"{quartiles(off[turning], '°')} on the {int(turning.sum())} windows turning by {TURNING_DEG}° or more, "
          f"where the data turns by {quartiles(turn[turning], '°')} and the network by {quartiles(net_turn[turning], '°')}")


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
