"""Small hand-made datasets with known answers for tests."""

from __future__ import annotations

import numpy as np

from motiongen.data.format import DatasetWriter
from motiongen.data.occupancy import OccupancyGrid
from motiongen.geometry import transform_points, local_to_world
from motiongen.skeleton import BODY

# A rest pose facing +z (left hip at +x), y-up, metres: (22, 3).
REST = np.array([
    [0, .95, 0], [.09, .88, 0], [-.09, .88, 0], [0, 1.05, 0], [.1, .5, 0], [-.1, .5, 0], [0, 1.18, 0],
    [.1, .08, 0], [-.1, .08, 0], [0, 1.24, 0], [.1, .02, .12], [-.1, .02, .12], [0, 1.45, 0],
    [.08, 1.38, 0], [-.08, 1.38, 0], [0, 1.6, .02], [.18, 1.38, 0], [-.18, 1.38, 0], [.45, 1.38, 0],
    [-.45, 1.38, 0], [.7, 1.38, 0], [-.7, 1.38, 0]], np.float32)


def walking_sequence(T: int, start_xz, yaw0: float, turn_rate: float, speed: float) -> np.ndarray:
    """(T, 22, 3): the rest pose carried along a curved path at `speed` m/s (30 fps)."""
    yaw = yaw0 + turn_rate * np.arange(T) / 30.0
    pos = np.zeros((T, 2))
    pos[0] = start_xz
    for t in range(1, T):
        pos[t] = pos[t - 1] + speed / 30.0 * np.array([np.sin(yaw[t]), np.cos(yaw[t])])
    return np.stack([transform_points(local_to_world(yaw[t], pos[t]), REST) for t in range(T)]).astype(np.float32)


def make_dataset(root, scenes=(1, 71, 91), seqs_per_scene=2, T=120, obstacle=True):
    """A dataset with one 4 x 2 x 4 m scene per id (a 0.4 m box at (1, *, 1) when `obstacle`)."""
    w = DatasetWriter(root, BODY, ["walk", "sit"], 30.0)
    rng = np.random.default_rng(0)
    for sid in scenes:
        occ = np.zeros((200, 100, 200), bool)               # 2 cm, origin (-2, 0, -2)
        if obstacle:
            occ[140:160, 0:40, 140:160] = True              # x, z in [0.8, 1.2), y in [0, 0.8)
        w.add_scene(sid, grid=OccupancyGrid.from_dense(occ, [-2.0, 0.0, -2.0], 0.02))
        for k in range(seqs_per_scene):
            j = walking_sequence(T, rng.uniform(-1, 0, 2), rng.uniform(-np.pi, np.pi), rng.uniform(-0.5, 0.5), 1.0)
            acts = np.zeros((T, 2), bool)
            acts[:, 0] = True
            w.add_sequence(f"s{sid}_{k}", sid, j, acts, np.zeros((T, 22), bool))
    return w.finish(splits={"train": [1], "val": [71], "test": [91]}, source="test")
