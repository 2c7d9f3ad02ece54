"""Does the network start where its pinned frames end? (not a timed test)

Each window the sampler's loop draws starts with the last k frames of the one before, pinned
(k the checkpoint's `mask.max_transition`: 3 for the demo, 2 for the quality recipe); the
network draws the rest. This prints, for a checkpoint on `windows` of the data's own
`split` windows (first 2 frames and the last frame's pelvis x, z given, DDIM-`steps`):
- per joint, the step (cm, median) from the last pinned frame to the first drawn one, and
  from that to the next, the network's beside the data's, and how far the network's frames
  are from the data's there; and, on the windows that walk, how far the toes are from the
  pelvis along the floor over the window (the network's feet can stay behind its pelvis);
- how far the network's one-step estimate x̂0 is from the clean window (pelvis and left toe,
  median cm, at a few frames) at noise levels t, given the clean window's own noised version:
  a denoiser at t = 1 sees the answer; with the height of its toes where they move faster
  than 0.5 m/s (`toe_clearance.py`'s figure) beside the data's: a network whose estimate
  lifts the toes no higher at t = 1 than at t = 90 does not take the step from its input;
and for `sample` outputs (motion.npz), the network's skating (`joints_raw`) within 3 output
frames of an episode's start and elsewhere, and the same at the model's rate (within 1 frame);
and per joint its step at the model's rate into each episode's first frame (the loop's own
seam) beside its steps between the other model frames.

    python benchmarks/seams.py [ckpt=PATH] [RUN/motion.npz ...] [split=val] [windows=300] [steps=10]
"""

from __future__ import annotations

import numpy as np
import torch

from network_facing import files_and_keys, model_and_data, predict_on_windows, random_windows
from toe_clearance import fast_toe_heights

from motiongen.cli import tool_main
from motiongen.diffusion.masks import known_mask
from motiongen.errors import ConfigError
from motiongen.metrics import foot_skating_frames
from motiongen.models import Condition

JOINTS = ("pelvis", "left_knee", "left_foot", "right_foot", "head", "right_wrist")
NOISE = (0.01, 0.1, 0.5, 0.9)          # t as a fraction of the schedule's steps (at least 1)
FRAMES = (0, 1, 2, 3, 8, -1)
NEAR = 3                                # output frames either side of a seam
WALKING = 0.8                           # m the data's pelvis travels over a window that walks


def steps_at_seam(loaded, ds, split: str, n: int, steps: int) -> None:
    data, net, _ = predict_on_windows(loaded, ds, split, n, steps)                           # (B, L, J, 3)
    names = list(loaded.joint_set.names)
    print(f"  steps at the seam, {len(data)} {split} windows, median cm (frame 1 is the last pinned one):")
    for name in JOINTS:
        j = names.index(name)
        d, m = (np.linalg.norm(np.diff(w[:, :, j], axis=1), axis=-1) for w in (data, net))    # (B, L-1)
        off = np.linalg.norm(net[:, :, j] - data[:, :, j], axis=-1)                           # (B, L)
        print(f"    {name:12s} 1->2: network {cm(m[:, 1])}, data {cm(d[:, 1])}; 2->3: network {cm(m[:, 2])}, "
              f"data {cm(d[:, 2])}; network from the data at 2: {cm(off[:, 2])}, at 3: {cm(off[:, 3])}")
    feet_behind(data, net, names)


def feet_behind(data: np.ndarray, net: np.ndarray, names: list) -> None:
    """How far the toes' midpoint is from the pelvis along the floor over the windows (B, L, J, 3)
    whose data pelvis travels over WALKING m: where the network's feet stay behind its pelvis,
    the next window, given those frames, starts with them back under it."""
    toes = [names.index("left_foot"), names.index("right_foot")]
    walking = np.linalg.norm(data[:, -1, 0, [0, 2]] - data[:, 0, 0, [0, 2]], axis=-1) > WALKING
    L = data.shape[1]
    frames = sorted({1, L // 4, L // 2, 3 * L // 4, L - 1})
    print(f"  toes' midpoint from the pelvis along the floor, {walking.sum()} windows whose data pelvis travels "
          f"over {WALKING} m, median cm at frames {frames}:")
    for who, j in (("data", data), ("network", net)):
        mid = j[walking][:, :, toes].mean(2)                                                     # (W, L, 3)
        gap = np.linalg.norm(mid[..., [0, 2]] - j[walking][:, :, 0, [0, 2]], axis=-1)             # (W, L)
        print(f"    {who:8s} " + " ".join(cm(gap[:, f]) for f in frames))


def one_step_error(loaded, ds, split: str, n: int) -> None:
    batch = random_windows(loaded, ds, split, n)
    x0 = batch["motion"]                                                                      # (B, L, D)
    B, L, D = x0.shape
    mask = known_mask(B, L, loaded.joint_set.num_joints, 2, True, False, False, 0, channels=D)
    model, diffusion = loaded.model, loaded.diffusion
    enc = model.encode_condition(Condition(scene=batch.get("scene"), actions=batch["actions"]))
    clean = loaded.layout.decode(loaded.stats.denormalize(x0.double()))[0]                   # (B, L, J, 3)
    gen = torch.Generator().manual_seed(0)
    toe = list(loaded.joint_set.names).index("left_foot")
    fps = loaded.model_fps
    print(f"  one-step x̂0 from the clean window noised to t, median cm at frames {FRAMES} (pelvis; left toe); "
          f"moving toes' height, median cm (the data's {moving_toes(clean.numpy(), fps)}):")
    for level in NOISE:
        t = torch.full((B,), max(1, round(level * diffusion.num_timesteps)), dtype=torch.long)
        x_t = torch.where(mask, x0, diffusion.q_sample(x0, t, torch.randn(x0.shape, generator=gen)))
        with torch.no_grad():
            x0_hat = diffusion.predict_x0_eps(model(x_t, t, enc, known_mask=mask), x_t, t)[0]
        est = loaded.layout.decode(loaded.stats.denormalize(x0_hat.double()))[0]                 # (B, L, J, 3)
        err = (est - clean).norm(dim=-1).numpy()
        print(f"    t = {int(t[0]):4d}: {' '.join(cm(err[:, f, 0]) for f in FRAMES)}; "
              f"{' '.join(cm(err[:, f, toe]) for f in FRAMES)}; moving toes {moving_toes(est.numpy(), fps)}")


def moving_toes(windows: np.ndarray, fps: float) -> str:
    """The median height (cm) of the toes of windows (B, L, J, 3) on the transitions where they move
    faster than 0.5 m/s (`toe_clearance.fast_toe_heights`)."""
    return cm(np.concatenate([fast_toe_heights(w, fps)[0] for w in windows]))


def skating_near_seams(path: str) -> str:
    """The network's skating (`joints_raw`) within NEAR frames of an episode's start and
    elsewhere, at the output's rate and at the model's (every n-th output frame is a model frame)."""
    d = np.load(path)
    fps, starts = float(d["fps"]), np.asarray(d["episode_starts"])
    n = round(fps / float(d["model_fps"])) if "model_fps" in d.files else 1
    parts = []
    for step in dict.fromkeys((1, n)):
        sk = np.concatenate([foot_skating_frames(j[::step].astype(np.float64), fps / step) for j in d["joints_raw"]])
        T = len(sk) // d["joints_raw"].shape[0]
        seams = starts // step
        near = np.tile(np.min(np.abs(np.arange(T)[:, None] - seams[None]), 1) <= max(1, NEAR // step), d["joints_raw"].shape[0])
        parts.append(f"at {fps / step:g} fps {sk.mean():.3f}; near a seam ({near.mean():.0%} of frames) "
                     f"{sk[near].mean():.3f}, elsewhere {sk[~near].mean():.3f}")
    return f"  {path}: network skating " + "; ".join(parts) + "\n" + seam_steps(d, n)


def seam_steps(d, n: int) -> str:
    """Per joint, the network's step (cm, median) at the model's rate into each episode's first
    frame (the loop's seam: from the frame the episode was handed on to its first drawn one)
    and between the other consecutive model frames."""
    names = [str(x) for x in d["joint_names"]]
    model = d["joints_raw"][:, ::n].astype(np.float64)                                       # (S, T, J, 3)
    step = np.linalg.norm(np.diff(model, axis=1), axis=-1)                                    # (S, T-1, J)
    seams = np.unique(np.asarray(d["episode_starts"]) // n)
    seams = seams[(seams >= 1) & (seams < model.shape[1])] - 1                              # index of the step into it
    at = np.zeros(step.shape[1], bool)
    at[seams] = True
    rows = [f"{name} {cm(step[:, at, names.index(name)])} / {cm(step[:, ~at, names.index(name)])}"
            for name in JOINTS if name in names]
    return f"    step into an episode's first model frame / between other model frames, median cm: {', '.join(rows)}"


def cm(x: np.ndarray) -> str:
    return f"{100 * np.median(x):.1f}"


SPEC = {"ckpt": (str, None, "checkpoint to run on the data's windows"), "split": (str, "val", "the data's split"),
        "windows": (int, 300, "of the data's windows"), "steps": (int, 10, "DDIM steps")}
USAGE = __doc__.strip().splitlines()[-1].strip()


def main(argv: list[str]) -> None:
    paths, opts = files_and_keys(argv, SPEC, USAGE, __doc__)
    if opts["ckpt"] is None and not paths:
        raise ConfigError(f"nothing to measure: give ckpt=PATH or motion.npz files (usage: {USAGE})")
    if opts["ckpt"] is not None:
        loaded, ds = model_and_data(opts["ckpt"])
        print(f"{opts['ckpt']}:")
        steps_at_seam(loaded, ds, opts["split"], opts["windows"], opts["steps"])
        one_step_error(loaded, ds, opts["split"], opts["windows"])
    for path in paths:
        print(skating_near_seams(path))


if __name__ == "__main__":
    tool_main(main)()                     # a bad key or a missing file: one line, exit 2
