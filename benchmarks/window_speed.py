"""Does the walk surge once per window? (not a timed test)

The data's pelvis walks at a steady speed across a window. If the network slows down towards
the end of each window it draws, the loop's next window starts from those slow frames, and the
output walks in surges, one per episode: power at the episode rate (0.7 Hz for the demo) that
the data does not have, which PSKL counts on the trunk. This prints
- for a checkpoint, on `windows` of the data's `split` windows (first 2 frames and the last
  frame's pelvis x, z given, DDIM-`steps`: what the loop gives a walking episode), the pelvis's
  speed along the floor at each frame of the window, mean over the windows whose data pelvis
  travels at least 1.2 m, the data's beside the network's, and the network's mean speed over
  the window's last 4 frame steps as a share of the data's there;
- for `sample` outputs (motion.npz), the pelvis's speed along the floor by model frame since
  the episode's start, mean over the frames where the body walks (its speed averaged over
  ±0.67 s above 0.3 m/s), for the output (`joints`) and the network's own joints
  (`joints_raw`), and the slowest phase's speed as a share of the fastest's.

    python benchmarks/window_speed.py [ckpt=PATH] [RUN/motion.npz ...] [split=val] [windows=400] [steps=10]
"""

from __future__ import annotations

import numpy as np

from network_facing import files_and_keys, model_and_data, predict_on_windows

from motiongen.cli import tool_main
from motiongen.errors import ConfigError
from motiongen.skeleton import PELVIS

SPEC = {"ckpt": (str, None, "a checkpoint: its speed on the data's windows"), "split": (str, "val", "the data's split"),
        "windows": (int, 400, "of the data's windows"), "steps": (int, 10, "DDIM steps")}
USAGE = __doc__.strip().splitlines()[-1].strip()
TRAVEL = 1.2          # m the data's pelvis goes over a window that walks at full speed
WALKING = 0.3         # m/s: a frame walks when the pelvis's speed averaged over ±0.67 s is above this
END = 4               # a window's last frames whose speed is compared


def floor_speed(joints: np.ndarray, fps: float) -> np.ndarray:
    """(..., T, J, 3) joints -> (..., T-1) the pelvis's speed along the floor (m/s)."""
    return np.linalg.norm(np.diff(joints[..., PELVIS, :][..., [0, 2]], axis=-2), axis=-1) * fps


def speed_by_window_frame(data: np.ndarray, net: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Mean pelvis speed at each frame step of the windows (B, L, J, 3) whose data pelvis travels
    at least TRAVEL: (data (L-1,), network (L-1,), how many windows)."""
    travel = np.linalg.norm(data[:, -1, PELVIS, [0, 2]] - data[:, 0, PELVIS, [0, 2]], axis=-1)     # (B,)
    sel = travel >= TRAVEL
    if not sel.any():
        return np.full(data.shape[1] - 1, np.nan), np.full(data.shape[1] - 1, np.nan), 0
    return floor_speed(data[sel], fps).mean(0), floor_speed(net[sel], fps).mean(0), int(sel.sum())


def speed_by_phase(joints: np.ndarray, starts: np.ndarray, fps: float, per_model_frame: int) -> np.ndarray:
    """Mean pelvis speed over the walking frames of motions (S, T, J, 3) by model frame since the
    episode's start (episodes start at output frames `starts`), over the episodes of the most
    common length (the loop's; the warm-up episode is shorter)."""
    starts = np.asarray(starts, np.int64)
    lengths = np.diff(np.append(starts, joints.shape[-3]))                                      # (E,) output frames
    common = int(np.bincount(lengths).argmax())
    n = common // per_model_frame
    if n < 2 or (lengths == common).sum() < 2:
        raise ConfigError("window_speed: the motion needs two episodes of one length or more")
    total, count = np.zeros(n), np.zeros(n)
    half = int(round(0.67 * fps))
    for v in floor_speed(joints, fps):                                                          # (T-1,) each
        walking = np.convolve(v, np.ones(2 * half + 1) / (2 * half + 1), mode="same") > WALKING
        episode = np.searchsorted(starts, np.arange(len(v)), side="right") - 1
        phase = (np.arange(len(v)) - starts[np.maximum(episode, 0)]) // per_model_frame
        keep = walking & (episode >= 0) & (lengths[np.maximum(episode, 0)] == common) & (phase < n)
        np.add.at(total, phase[keep], v[keep])
        np.add.at(count, phase[keep], 1)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def _row(name: str, values: np.ndarray) -> str:
    return f"  {name:10s}" + " ".join(f"{x:5.2f}" for x in values)


def on_windows(ckpt: str, split: str, n: int, steps: int) -> None:
    loaded, ds = model_and_data(ckpt)
    data, net, fps = predict_on_windows(loaded, ds, split, n, steps)
    d, m, count = speed_by_window_frame(data, net, fps)
    print(f"{ckpt}: pelvis speed [m/s] at each frame step of {count} {split} windows whose data pelvis goes "
          f">= {TRAVEL} m ({fps:g} fps)")
    print(_row("data", d))
    print(_row("network", m))
    print(f"  the network's last {END} frame steps: {m[-END:].mean():.2f} m/s, {m[-END:].mean() / d[-END:].mean():.0%} "
          f"of the data's; over the window {m.mean():.2f} against {d.mean():.2f}")


def on_output(path: str) -> None:
    out = np.load(path)
    fps, model_fps = float(out["fps"]), float(out["model_fps"])
    step = max(1, int(round(fps / model_fps)))
    print(f"{path}: pelvis speed [m/s] by model frame since the episode's start, over the walking frames")
    for key, name in (("joints", "output"), ("joints_raw", "network")):
        v = speed_by_phase(out[key], out["episode_starts"], fps, step)
        print(_row(name, v) + f"   slowest/fastest {np.nanmin(v) / np.nanmax(v):.2f}")


def run(argv: list[str]) -> None:
    paths, opts = files_and_keys(argv, SPEC, usage=USAGE, doc=__doc__)
    if not paths and not opts["ckpt"]:
        raise ConfigError(f"nothing to measure: give ckpt=PATH or motion.npz files (usage: {USAGE})")
    if opts["ckpt"]:
        on_windows(opts["ckpt"], opts["split"], opts["windows"], opts["steps"])
    for path in paths:
        on_output(path)


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
