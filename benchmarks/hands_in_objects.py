"""Hands in objects: the share of pick-up frames with a wrist joint inside a placed object (not a
timed test). The evaluation's own figures cannot see it: its hand-object distance is unsigned and
its contact rate subtracts the same skin offset the hand reach adds.

    python benchmarks/hands_in_objects.py ckpt=PATH [split=val] [k=2] [pairs=5] [steps=10]

Runs the `evaluate` protocol's dynamic setting (seed 0, DDIM) on every scene of `split` and prints,
for the output motions and the network's own joints: pick-up frames, those with either wrist
joint inside an object's occupied voxels, and the nearest wrist's distance to the object's voxel
centres (median, 10th percentile), beside the report's hand-object distance and contact rate.
"""

from __future__ import annotations

import warnings

import numpy as np

import motiongen.eval.protocol as protocol
from motiongen.cli import parse_key_values, tool_main
from motiongen.eval.pairs import ProtocolConfig
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.loading.build import load_model
from motiongen.sampling import SamplerSettings
from motiongen.skeleton import HAND_JOINTS

SPEC = {"ckpt": (str, None), "split": (str, "val"), "k": (int, 2), "pairs": (int, 5), "steps": (int, 10)}


def wrists_in_objects(joints: np.ndarray, objects) -> tuple[np.ndarray, np.ndarray]:
    """joints (F, J, 3), objects [(OccupancyGrid, pose (4, 4))] -> (F,) either wrist inside an
    object, (F,) the nearest wrist's distance (m) to an object voxel centre."""
    w = joints[:, list(HAND_JOINTS)]                                                   # (F, 2, 3)
    inside, near = np.zeros(len(w), bool), np.full(len(w), np.inf)
    for grid, pose in objects:
        pose = np.asarray(pose, np.float64)
        local = (w.reshape(-1, 3) - pose[:3, 3]) @ pose[:3, :3]                        # R^T (p - t): (2F, 3)
        inside |= grid.occupied(local, outside=False).reshape(len(w), -1).any(1)
        centres = grid.origin + (np.argwhere(np.asarray(grid.dense())) + 0.5) * grid.voxel_size   # (N, 3)
        d = np.linalg.norm(local[:, None] - centres[None], axis=-1).min(1)             # (2F,)
        near = np.minimum(near, d.reshape(len(w), -1).min(1))
    return inside, near


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, required=("ckpt",), usage=__doc__.splitlines()[3].strip())
    captured = []
    generate = protocol.generate

    def keep(*a, **kw):                        # the protocol keeps scores, not motions: keep them here
        motion = generate(*a, **kw)
        captured.append((motion, kw.get("objects") or []))
        return motion

    protocol.generate = keep
    loaded = load_model(opts["ckpt"])
    ds = open_dataset(DataConfig(), verbose=False)
    scenes = [s for s in ds.splits[opts["split"]] if s in ds.scenes]
    warnings.simplefilter("ignore")
    ev = protocol.evaluate(loaded, ds, scenes, ProtocolConfig(k=opts["k"], pairs=opts["pairs"]), ["dynamic"],
                           SamplerSettings("ddim", opts["steps"]), progress=False)
    for label, field in (("output", "joints"), ("network's own joints", "joints_raw")):
        inside, near = [], []
        for motion, objects in captured:
            pick = motion.action_names.index("pick up")
            for s in range(motion.joints.shape[0]):
                frames = np.flatnonzero(motion.actions[s] == pick)
                if len(frames) and objects:
                    i, n = wrists_in_objects(getattr(motion, field)[s][frames].astype(np.float64), objects)
                    inside.append(i), near.append(n)
        i, n = np.concatenate(inside), np.concatenate(near)
        print(f"{label}: {len(i)} pick-up frames, a wrist inside an object in {i.sum()} ({100 * i.mean():.1f} %); "
              f"nearest wrist to an object voxel centre: median {np.median(n):.3f} m, 10th pct {np.percentile(n, 10):.3f} m")
    row = ev.model.get("dynamic", {})
    print(f"report: hand-object distance {row.get('object_dist_m'):.3f} m, contact rate {row.get('contact_rate'):.3f} "
          f"({opts['split']} scenes {scenes[0]}-{scenes[-1]}, k={opts['k']}, {opts['pairs']} pairs per scene)")


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
