"""How a generated body stands and walks, episode by episode (not a timed test): from `sample`'s
motion.npz, per episode the network's own bone lengths over the output body's (mean over bones:
1 when the network keeps the body's size), the output's pelvis and head heights and its knee
angle (mean of both knees, 180° straight); then medians over the whole motion. With `split=`
the same medians for the dataset's own walking frames of that split, to read them against.

    python benchmarks/posture.py motion=[out/motion.npz,...] [split=val] [episodes=true]
"""

from __future__ import annotations

import numpy as np

from motiongen.cli import parse_key_values, tool_main
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.metrics import bone_lengths, knee_angles
from motiongen.skeleton import BODY_PARENTS, HEAD, PELVIS

SPEC = {"motion": (list, []), "split": (str, None), "episodes": (bool, True)}


def motion_posture(path: str, episodes: bool) -> None:
    z = np.load(path)
    net, out = (z[k][0, :, :22].astype(np.float64) for k in ("joints_raw", "joints"))          # (T, 22, 3)
    scale = (bone_lengths(net, BODY_PARENTS) / bone_lengths(out, BODY_PARENTS)).mean(1)      # (T,)
    knee, pelvis, head = knee_angles(out), out[:, PELVIS, 1], out[:, HEAD, 1]
    print(f"{path}: knee median {np.median(knee):.0f}°, pelvis {np.median(pelvis):.2f} m, head {np.median(head):.2f} m, "
          f"network bone scale median {np.median(scale):.2f} (lowest episode "
          f"{min(scale[a:b].mean() for a, b in spans(z, len(out))):.2f})")
    if episodes:
        for name, x, f in (("network bone scale", scale, "{:.2f}"), ("pelvis y [m]", pelvis, "{:.2f}"),
                           ("head y [m]", head, "{:.2f}"), ("knee [°]", knee, "{:.0f}")):
            print(f"  {name:19s}" + " ".join(f.format(x[a:b].mean()) for a, b in spans(z, len(out))))


def spans(z, T: int) -> list[tuple[int, int]]:
    starts = [int(s) for s in z["episode_starts"]] + [T]
    return [(a, b) for a, b in zip(starts[:-1], starts[1:]) if b > a]


def data_posture(split: str) -> None:
    ds = open_dataset(DataConfig(), verbose=False)
    walk = list(ds.action_names).index("walk")
    knee, pelvis, head = [], [], []
    for s in ds.sequences:
        if s.scene not in ds.splits.get(split, []):
            continue
        j = np.asarray(ds.joints[s.start:s.end], np.float64)[:, :22]
        on = np.asarray(ds.actions[s.start:s.end], bool)[:, walk]
        knee.append(knee_angles(j[on])), pelvis.append(j[on, PELVIS, 1]), head.append(j[on, HEAD, 1])
    k, p, h = (np.concatenate(x) for x in (knee, pelvis, head))
    print(f"data, {split} split, walking frames: knee median {np.median(k):.0f}° (10th-90th percentile "
          f"{np.percentile(k, 10):.0f}-{np.percentile(k, 90):.0f}°), pelvis {np.median(p):.2f} m, head {np.median(h):.2f} m")


def run(argv: list[str]) -> None:
    o = parse_key_values(argv, SPEC, usage=__doc__.splitlines()[-2].strip())
    for path in o["motion"]:
        motion_posture(path, o["episodes"])
    if o["split"]:
        data_posture(o["split"])


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
