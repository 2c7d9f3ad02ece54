"""Walkable floor maps and collision-free paths on them: one implementation that the synthetic
data generator and the sampler's goal routing both use.

* `WalkableMap` (walkable.py): free floor cells with a body-radius clearance; built from an
  occupancy grid (`walkable_map`) or from axis-aligned boxes (`walkable_from_boxes`).
* `plan_path` (planner.py): shortest 8-connected cell path (Dijkstra on a sparse grid graph,
  scipy), shortened by line of sight; `round_corners` turns corners into arcs.
"""

from motiongen.routing.planner import plan_path, round_corners, shortcut
from motiongen.routing.walkable import WalkableMap, walkable_from_boxes, walkable_map

__all__ = ["WalkableMap", "plan_path", "round_corners", "shortcut", "walkable_from_boxes", "walkable_map"]
