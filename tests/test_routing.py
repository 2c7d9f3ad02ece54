"""The one planner (motiongen.routing) that the synthetic generator and the sampler share."""

import numpy as np

from motiongen.routing import WalkableMap, plan_path, round_corners, walkable_from_boxes
from motiongen.routing.planner import grid_graph
from scipy.sparse.csgraph import dijkstra


def _map(free: np.ndarray, cell: float = 0.1) -> WalkableMap:
    return WalkableMap(free, free.copy(), np.zeros(2), cell)


def test_grid_graph_lengths_are_octile_distances():
    free = np.ones((7, 5), bool)
    d = dijkstra(grid_graph(free), indices=0)                 # from cell (0, 0)
    i, k = np.unravel_index(np.arange(35), free.shape)
    octile = np.maximum(i, k) + (np.sqrt(2) - 1) * np.minimum(i, k)
    np.testing.assert_allclose(d, octile)


def test_diagonal_between_blocked_corners_only_with_squeeze():
    # Two free cells that touch only at a corner, their two common neighbours blocked.
    free = np.array([[1, 0], [0, 1]], bool)
    assert not np.isfinite(dijkstra(grid_graph(free), indices=0)[3])
    np.testing.assert_allclose(dijkstra(grid_graph(free, squeeze=True), indices=0)[3], np.sqrt(2))


def test_plan_path_goes_round_a_wall_by_the_shortest_way():
    free = np.ones((40, 40), bool)                            # 4 x 4 m at 10 cm
    free[:30, 20] = False                                     # a wall from x = 0 to 3 m at z = 2.0-2.1
    fmap = _map(free)
    start, goal = np.array([1.05, 1.05]), np.array([1.05, 3.05])
    path = plan_path(fmap, start, goal)
    np.testing.assert_allclose(path[[0, -1]], [start, goal])
    dense = np.concatenate([np.linspace(a, b, 50) for a, b in zip(path[:-1], path[1:])])
    assert fmap.is_free(dense).all()
    # Round the wall's free end at x >= 3.0: at least the two straight lines via its corner.
    corner = np.array([3.0, 2.05])
    lower = np.linalg.norm(corner - start) + np.linalg.norm(goal - corner)
    length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    assert lower - 1e-9 <= length <= lower + 0.3
    assert plan_path(_map(np.where(np.arange(40)[None, :] == 20, False, free)), start, goal) is None


def test_boxes_map_keeps_the_largest_region_and_round_corners_keeps_ends():
    # A box splitting a 4 x 2 m room into a 1 m and a 2.5 m part: only the larger stays free.
    boxes = np.array([[[-1.0, 0.0, -1.0], [-0.5, 1.0, 1.0]]])
    fmap = walkable_from_boxes(boxes, (4.0, 2.0), 0.05, 0.0)
    assert fmap.is_free([1.0, 0.0]) and not fmap.is_free([-1.5, 0.0]) and not fmap.is_free([-0.75, 0.0])
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    r = round_corners(pts)
    np.testing.assert_allclose(r[[0, -1]], pts[[0, -1]])
    assert len(r) > 3 and np.linalg.norm(r - [1.0, 0.0], axis=1).min() > 0.05   # the corner is cut
