"""Per-window occupancy lookup for training items (CPU, one window at a time)."""

from __future__ import annotations

import numpy as np

from motiongen.data.format import MotionDataset
from motiongen.geometry import transform_points


def window_occupancy(ds: MotionDataset, scene: int, goal_frame: int, T: np.ndarray, goal_local: np.ndarray,
                     grid_points: np.ndarray, cfg) -> np.ndarray:
    """Occupancy (P,) bool at `grid_points` (P, 3) placed at the goal pelvis (x, z) of a window
    whose local -> world transform is T (4, 4). Height is measured from the floor, not the pelvis."""
    pts = grid_points.copy()
    pts[:, 0] += goal_local[0]
    pts[:, 2] += goal_local[2]
    world = transform_points(T, pts)                                              # (P, 3)
    return ds.grid(scene).occupied(world, outside=cfg.outside_occupied)
