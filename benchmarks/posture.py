"""How a generated body stands and walks, episode by episode (not a timed test): from `sample`'s
motion.npz, per episode the network's own bone lengths over the output body's (mean over bones:
1 when the network keeps the body's size), the output's pelvis and head heights and its knee
angle (mean of both knees, 180° straight); then medians over the whole motion, and each knee's
angle while walking by its leg's phase (stance: the ankle slower than 0.3 m/s, swing: faster
than 1 m/s, with the pelvis above 0.5 m/s), for the output and the network's own joints. With
`split=` the same medians for the dataset's own walking frames of that split, to read them
against: a body whose median knee is more bent than the data's may crouch (both phases bent)
or swing its legs higher (only the swing bent).

    python benchmarks/posture.py motion=[out/motion.npz,...] [split=val] [episodes=true]
"""

from __future__ import annotations

import numpy as np

from motiongen.cli import parse_key_values, tool_main
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.metrics import LEGS, bone_lengths, knee_angles, leg_knee_angles, walking_frames
from motiongen.skeleton import BODY_PARENTS, HEAD, PELVIS

SPEC = {"motion": (list, []), "split": (str, None), "episodes": (bool, True)}
STANCE_MPS, SWING_MPS, WALK_MPS = 0.3, 1.0, 0.5


def phase_knees(joints: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Each knee's angle (degrees) over the walking frames of joints (T, 22, 3) at fps, split by
    its leg's phase: (stance angles, swing angles), both legs pooled."""
    walking = walking_frames(joints, fps, WALK_MPS)                                          # (T,)
    stance, swing = [], []
    angles = leg_knee_angles(joints)                                                          # (T, 2)
    for leg, (_, _, ankle) in enumerate(LEGS):
        a = np.linalg.norm(np.gradient(joints[:, ankle], axis=0), axis=-1) * fps             # (T,) m/s
        stance.append(angles[walking & (a < STANCE_MPS), leg]), swing.append(angles[walking & (a > SWING_MPS), leg])
    return np.concatenate(stance), np.concatenate(swing)


def phase_line(name: str, stance: np.ndarray, swing: np.ndarray) -> str:
    return (f"  {name}: knee while walking, stance {np.median(stance):.0f}°, swing {np.median(swing):.0f}° "
            f"(swing's 10th percentile {np.percentile(swing, 10):.0f}°; {len(stance)} / {len(swing)} leg-frames)")


def motion_posture(path: str, episodes: bool) -> None:
    z = np.load(path)
    net, out = (z[k][0, :, :22].astype(np.float64) for k in ("joints_raw", "joints"))          # (T, 22, 3)
    scale = (bone_lengths(net, BODY_PARENTS) / bone_lengths(out, BODY_PARENTS)).mean(1)      # (T,)
    knee, pelvis, head = knee_angles(out), out[:, PELVIS, 1], out[:, HEAD, 1]
    print(f"{path}: knee median {np.median(knee):.0f}°, pelvis {np.median(pelvis):.2f} m, head {np.median(head):.2f} m, "
          f"network bone scale median {np.median(scale):.2f} (lowest episode "
          f"{min(scale[a:b].mean() for a, b in spans(z, len(out))):.2f})")
    fps = float(z["fps"])
    print(phase_line("output ", *phase_knees(out, fps)))
    print(phase_line("network", *phase_knees(net, fps)))
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
    knee, pelvis, head, stance, swing = [], [], [], [], []
    for s in ds.sequences:
        if s.scene not in ds.splits.get(split, []):
            continue
        j = np.asarray(ds.joints[s.start:s.end], np.float64)[:, :22]
        on = np.asarray(ds.actions[s.start:s.end], bool)[:, walk]
        knee.append(knee_angles(j[on])), pelvis.append(j[on, PELVIS, 1]), head.append(j[on, HEAD, 1])
        st, sw = phase_knees(j, ds.fps)
        stance.append(st), swing.append(sw)
    k, p, h = (np.concatenate(x) for x in (knee, pelvis, head))
    print(f"data, {split} split, walking frames: knee median {np.median(k):.0f}° (10th-90th percentile "
          f"{np.percentile(k, 10):.0f}-{np.percentile(k, 90):.0f}°), pelvis {np.median(p):.2f} m, head {np.median(h):.2f} m")
    print(phase_line("data", np.concatenate(stance), np.concatenate(swing)))


def run(argv: list[str]) -> None:
    o = parse_key_values(argv, SPEC, usage=__doc__.splitlines()[-2].strip())
    for path in o["motion"]:
        motion_posture(path, o["episodes"])
    if o["split"]:
        data_posture(o["split"])


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
