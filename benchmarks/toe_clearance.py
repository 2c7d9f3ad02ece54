"""Do the toes clear the floor when they move? (not a timed test) The foot-skating figure
counts a toe below 5 cm moving faster than 0.5 m/s; a foot planted and sliding and a foot
swinging too low both count. For `sample` outputs (motion.npz; grouped by checkpoint) this
prints, for the network's own joints (`joints_raw`) and the output (`joints`), the skating
figure and the height of the toes on every transition where a toe moves faster than 0.5 m/s
(the higher of its two frames; quartiles, metres), also by the pelvis's speed (over 1 s), and
the same for the data's sequences of `split` that the first file's checkpoint was trained on;
the network's and the data's also at the model's rate (every n-th frame), which is where the
data's windows below are measured: at 30 fps the resampled frames count more of a glide's
slow start and stop as moving.
A body that swings its feet as the data does clears 7-14 cm; one that shuffles stays under
5 cm, and its skating counts its swings. With `windows=N`, each checkpoint is also given N of
the data's own windows of `split` (the first 2 frames and the last frame's pelvis x, z, as
`network_facing.py` does; DDIM-10) and its toes are measured there beside the data's, with how
far its pelvis and its toes travel against the data's (a body that steps moves its feet as far
as its pelvis); the same travel is printed for the sampler's walking episodes.

    python benchmarks/toe_clearance.py RUN/motion.npz [RUN2/motion.npz ...] [split=val] [windows=0]
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d

from network_facing import files_and_keys, model_and_data, predict_on_windows

from motiongen.cli import tool_main
from motiongen.errors import ConfigError
from motiongen.metrics import TOE_JOINTS, foot_skating_frames
from motiongen.skeleton import PELVIS

FAST = 0.5                                   # m/s, the skating figure's speed threshold
SPEED_BINS = ((0.3, 0.6), (0.6, 0.9), (0.9, 1.2), (1.2, 3.0))   # m/s, the pelvis over 1 s
GOAL_BINS = ((0.3, 0.6), (0.6, 0.9), (0.9, 1.2), (1.2, 1.5), (1.5, 3.0))   # m over a window
SPEC = {"split": (str, "val", "the data's split"), "windows": (int, 0, "of the data's windows per checkpoint; 0 = none")}
USAGE = __doc__.strip().splitlines()[-1].strip()


def fast_toe_heights(joints: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Heights (m) of the toes of joints (T, J, 3) on the transitions where they move faster
    than FAST horizontally (the higher of the transition's two frames, one value per toe and
    transition), and the pelvis's horizontal speed (m/s, averaged over 1 s) at each."""
    toes = joints[:, list(TOE_JOINTS)]                                           # (T, 2, 3)
    speed = np.linalg.norm(np.diff(toes[..., [0, 2]], axis=0), axis=-1) * fps    # (T-1, 2)
    height = np.maximum(toes[:-1, :, 1], toes[1:, :, 1])                         # (T-1, 2)
    pelvis = np.linalg.norm(np.diff(joints[:, PELVIS, [0, 2]], axis=0), axis=-1) * fps
    pelvis = uniform_filter1d(pelvis, max(1, round(fps)), mode="nearest")       # (T-1,)
    fast = speed > FAST
    return height[fast], np.repeat(pelvis[:, None], 2, 1)[fast]


def row(name: str, motions: list[np.ndarray], fps: float) -> str:
    skate = np.concatenate([foot_skating_frames(j, fps) for j in motions]).mean()
    h, v = (np.concatenate(x) for x in zip(*[fast_toe_heights(j, fps) for j in motions]))
    q = np.percentile(h, [25, 50, 75])
    bins = ", ".join(f"{lo:g}-{hi:g}: {np.median(h[(v >= lo) & (v < hi)]):.3f}" for lo, hi in SPEED_BINS
                     if ((v >= lo) & (v < hi)).any())
    return (f"  {name:22s} skating {skate:.3f}, toe height when moving {q[1]:.3f} m ({q[0]:.3f} - {q[2]:.3f}); "
            f"by the pelvis's speed [m/s]: {bins}")


def travel(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Windows (N, T, J, 3) -> how far (m, over the floor) the pelvis and, on average, the two
    toes move from the first frame to the last, each (N,). A body that steps moves its feet
    as far as its pelvis; one whose feet stay behind does not."""
    pelvis = np.linalg.norm(joints[:, -1, PELVIS, [0, 2]] - joints[:, 0, PELVIS, [0, 2]], axis=-1)
    toes = joints[:, :, list(TOE_JOINTS)][..., [0, 2]]                                        # (N, T, 2, 2)
    return pelvis, np.linalg.norm(toes[:, -1] - toes[:, 0], axis=-1).mean(-1)


def on_data_windows(loaded, ds, name: str, split: str, n: int) -> None:
    """The network given n of the data's own windows, beside the data, at the model's rate."""
    data, net, fps = predict_on_windows(loaded, ds, split, n, steps=10)
    print(f"{name} on {len(data)} of the data's {split} windows ({fps:g} fps, the free frames):")
    for label, j in (("the data", data), ("the network", net)):
        print(row(label, list(j[:, 2:]), fps))
    # Frame 1 (the last given) to the end; binned by how far the data's pelvis goes, which is
    # where the network's goal is.
    (dp, dt), (np_, nt) = travel(data[:, 1:]), travel(net[:, 1:])
    print("  travel from the last given frame to the end [m], by the data's pelvis travel:")
    for lo, hi in GOAL_BINS:
        w = (dp >= lo) & (dp < hi)
        if w.any():
            print(f"    {lo:g}-{hi:g} m ({w.sum()} windows): the data's pelvis {dp[w].mean():.2f}, toes "
                  f"{dt[w].mean():.2f}; the network's pelvis {np_[w].mean():.2f}, toes {nt[w].mean():.2f}")


def episode_travel(outs: list) -> str:
    """The network's pelvis and toe travel per walking episode of `sample` outputs (episode
    start to the next, `joints_raw`; walking: the pelvis moves over 0.8 m)."""
    p, t = [], []
    for _, d in outs:
        starts = list(d["episode_starts"]) + [d["joints_raw"].shape[1] - 1]
        for j in d["joints_raw"].astype(np.float64):
            for a, b in zip(starts[:-1], starts[1:]):
                pe, to = travel(j[None, a:b + 1])
                p.append(pe[0])
                t.append(to[0])
    p, t = np.array(p), np.array(t)
    w = p > 0.8
    return (f"  network, {w.sum()} walking episodes of {len(p)}: pelvis {p[w].mean():.2f} m, toes {t[w].mean():.2f} m"
            if w.any() else f"  network: no walking episode of {len(p)}")


def main(argv: list[str]) -> None:
    paths, opts = files_and_keys(argv, SPEC, USAGE, __doc__)
    split, windows = opts["split"], opts["windows"]
    if not paths:
        raise ConfigError(f"no motion.npz given (usage: {USAGE})")
    runs: dict[str, list] = {}                 # checkpoint -> [(fps, npz), ...], in the order given
    for path in paths:
        d = np.load(path)
        runs.setdefault(str(d["ckpt"]), []).append((float(d["fps"]), d))
    for ckpt, outs in runs.items():
        fps = outs[0][0]
        print(f"{ckpt} ({len(outs)} outputs: {', '.join(str(d['scene']) for _, d in outs)}):")
        print(row("network", [j.astype(np.float64) for _, d in outs for j in d["joints_raw"]], fps))
        print(row("output", [j.astype(np.float64) for _, d in outs for j in d["joints"]], fps))
        # The output's rate is a cubic resampling of the model's frames (every n-th frame is one):
        # the data's windows are measured at the model's rate, so the loop is too.
        n = round(fps / float(outs[0][1]["model_fps"]))
        print(row(f"network, {fps / n:g} fps", [j[::n].astype(np.float64) for _, d in outs for j in d["joints_raw"]],
                  fps / n))
        print(episode_travel(outs))
    loaded, ds = model_and_data(next(iter(runs)))
    seqs = [np.asarray(j, np.float64) for _, j in ds.iter_sequences(split)]
    n = loaded.window.stride
    print(f"the data ({split}, {ds.fps:g} fps):")
    print(row(f"{split} sequences", seqs, ds.fps))
    print(row(f"{split}, {ds.fps / n:g} fps", [j[::n] for j in seqs], ds.fps / n))
    for i, ckpt in enumerate(runs if windows > 0 else ()):
        on_data_windows(*((loaded, ds) if i == 0 else model_and_data(ckpt)), ckpt, split, windows)


if __name__ == "__main__":
    tool_main(main)()                     # a bad key or a missing file: one line, exit 2
