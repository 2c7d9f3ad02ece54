"""Do the toes clear the floor when they move? (not a timed test) The foot-skating figure
counts a toe below 5 cm moving faster than 0.5 m/s; a foot planted and sliding and a foot
swinging too low both count. For `sample` outputs (motion.npz; grouped by checkpoint) this
prints, for the network's own joints (`joints_raw`) and the output (`joints`), the skating
figure and the height of the toes on every transition where a toe moves faster than 0.5 m/s
(the higher of its two frames; quartiles, metres), and the same for the data's sequences of
`split` that the first file's checkpoint was trained on. A body that swings its feet as the data does clears 7-14 cm; one
that shuffles stays under 5 cm, and its skating counts its swings.

    python benchmarks/toe_clearance.py RUN/motion.npz [RUN2/motion.npz ...] [split=val]
"""

from __future__ import annotations

import sys

import numpy as np

from motiongen.eval.evaluate_config import dataset_config
from motiongen.importers.sources import open_dataset
from motiongen.loading.build import load_model
from motiongen.metrics import TOE_JOINTS, foot_skating_frames

FAST = 0.5     # m/s, the skating figure's speed threshold


def fast_toe_heights(joints: np.ndarray, fps: float) -> np.ndarray:
    """Heights (m) of the toes of joints (T, J, 3) on the transitions where they move faster
    than FAST horizontally: the higher of the transition's two frames, one value per toe and
    transition."""
    toes = joints[:, list(TOE_JOINTS)]                                           # (T, 2, 3)
    speed = np.linalg.norm(np.diff(toes[..., [0, 2]], axis=0), axis=-1) * fps    # (T-1, 2)
    height = np.maximum(toes[:-1, :, 1], toes[1:, :, 1])                         # (T-1, 2)
    return height[speed > FAST]


def row(name: str, motions: list[np.ndarray], fps: float) -> str:
    skate = np.concatenate([foot_skating_frames(j, fps) for j in motions]).mean()
    q = np.percentile(np.concatenate([fast_toe_heights(j, fps) for j in motions]), [25, 50, 75])
    return f"  {name:28s} skating {skate:.3f}, toe height when moving {q[1]:.3f} m ({q[0]:.3f} - {q[2]:.3f})"


def main(argv: list[str]) -> None:
    split = next((a.split("=", 1)[1] for a in argv if a.startswith("split=")), "val")
    paths = [a for a in argv if not a.startswith("split=")]
    if not paths:
        sys.exit(__doc__.splitlines()[-1].strip())
    runs: dict[str, list] = {}                 # checkpoint -> [(fps, npz), ...], in the order given
    for path in paths:
        d = np.load(path)
        runs.setdefault(str(d["ckpt"]), []).append((float(d["fps"]), d))
    for ckpt, outs in runs.items():
        fps = outs[0][0]
        print(f"{ckpt} ({len(outs)} outputs: {', '.join(str(d['scene']) for _, d in outs)}):")
        print(row("network", [j.astype(np.float64) for _, d in outs for j in d["joints_raw"]], fps))
        print(row("output", [j.astype(np.float64) for _, d in outs for j in d["joints"]], fps))
    loaded = load_model(str(np.load(paths[0])["ckpt"]))
    ds = open_dataset(dataset_config(None, loaded.config), verbose=False)
    print(f"the data ({split}, {ds.fps:g} fps):")
    print(row(f"{split} sequences", [np.asarray(j, np.float64) for _, j in ds.iter_sequences(split)], ds.fps))


if __name__ == "__main__":
    main(sys.argv[1:])
