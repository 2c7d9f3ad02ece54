"""Routes: A* around obstacles, never through blocked floor; subgoal spacing; goal parsing."""

import json

import numpy as np
import pytest

from motiongen.scene.occupancy import OccupancyGrid
from motiongen.errors import ConfigError, DataError
from motiongen.routing import plan_path, walkable_map
from motiongen.sampling.goal_input import load_goals_file, parse_goals
from motiongen.sampling.goals import Goal, check_actions, place_subgoals, plan_route


def _room(wall=True):
    """4 x 2 x 4 m at 2 cm, origin (-2, 0, -2): a 0.4 m box at x, z in [0.8, 1.2) and (with
    `wall`) a wall across z in [-0.1, 0.1) from x = -2 to 1 (a gap at x > 1)."""
    occ = np.zeros((200, 100, 200), bool)
    occ[140:160, 0:40, 140:160] = True
    if wall:
        occ[:150, 0:90, 95:105] = True
    return OccupancyGrid.from_dense(occ, [-2.0, 0.0, -2.0], 0.02)


def _dense_points(path, step=0.005):
    pts = [path[0]]
    for a, b in zip(path[:-1], path[1:]):
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)
        pts.append(a + np.linspace(0, 1, n)[:, None] * (b - a))
    return np.concatenate([p.reshape(-1, 2) for p in pts])


def test_planner_routes_around_wall_and_never_through_occupied_cells():
    fmap = walkable_map(_room(), body_radius=0.2)
    start, goal = np.array([-1.0, -1.0]), np.array([-1.0, 1.0])
    path = plan_path(fmap, start, goal, 0.05)
    assert path is not None
    np.testing.assert_allclose(path[0], start)
    np.testing.assert_allclose(path[-1], goal)
    pts = _dense_points(path)
    assert fmap.is_free(pts).all()                        # keeps the body radius
    assert fmap.is_free(pts, clearance=False).all()       # and so never crosses a blocked cell
    assert pts[:, 0].max() > 1.0                          # went round through the gap
    # Shortened by line of sight: far fewer vertices than cells, and near the optimum length.
    assert len(path) < 10
    length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    assert length < 2 * np.hypot(2.2, 1.0) + 0.5


def test_no_path_and_bad_goals_raise():
    occ = np.zeros((200, 100, 200), bool)
    occ[:, 0:90, 95:105] = True                           # a wall with no gap
    fmap = walkable_map(OccupancyGrid.from_dense(occ, [-2.0, 0.0, -2.0], 0.02), body_radius=0.2)
    with pytest.raises(ConfigError, match="no collision-free path"):
        plan_route([-1, -1], [Goal([-1, 1])], fmap)
    fmap = walkable_map(_room(wall=False), body_radius=0.2)
    with pytest.raises(ConfigError, match="inside an obstacle"):
        plan_route([-1, -1], [Goal([1.0, 1.0])], fmap)
    with pytest.raises(ConfigError, match="outside the scene bounds"):
        plan_route([-1, -1], [Goal([5.0, 0.0])], fmap)
    # An interaction goal on furniture routes to the nearest walkable point, then onto it.
    r = plan_route([-1, -1], [Goal([1.0, 1.0], "sit", 2.0)], fmap)
    np.testing.assert_allclose(r.subgoals[-1], [1.0, 1.0])
    assert fmap.is_free(_dense_points(r.legs[0][:-1])).all()


@pytest.mark.parametrize("spacing", [0.3, 0.6, 1.0])
def test_subgoal_spacing(spacing):
    path = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.7]])
    sg = place_subgoals(path, spacing)
    s = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    # Arc length of each subgoal along the path.
    arc = []
    for p in sg:
        for i in range(len(path) - 1):
            a, b = path[i], path[i + 1]
            t = np.dot(p - a, b - a) / np.dot(b - a, b - a)
            if -1e-9 <= t <= 1 + 1e-9 and np.linalg.norm(a + t * (b - a) - p) < 1e-9:
                arc.append(s[i] + t * np.linalg.norm(b - a))
                break
    gaps = np.diff(np.concatenate([[0], arc]))
    np.testing.assert_allclose(gaps[:-1], spacing, atol=1e-9)
    assert 0 < gaps[-1] <= spacing + 1e-9
    np.testing.assert_allclose(sg[-1], path[-1])


def test_route_legs_and_subgoals_end_at_goals():
    fmap = walkable_map(_room(), body_radius=0.2)
    goals = [Goal([-1, 1]), Goal([-1.5, 1.5])]
    r = plan_route([-1, -1], goals, fmap, spacing=0.6)
    for g, goal in enumerate(goals):
        np.testing.assert_allclose(r.leg_subgoals(g)[-1], goal.xz)
    assert r.path.shape[1] == 2 and len(r.subgoals) == len(r.subgoal_leg)
    straight = plan_route([-1, -1], goals, None, mode="straight", spacing=0.6)
    assert len(straight.legs[0]) == 2


def _straight_piece(leg: np.ndarray) -> tuple[float, np.ndarray]:
    """The length and unit direction of a leg's last piece (N, 2)."""
    d = leg[-1] - leg[-2]
    return float(np.linalg.norm(d)), d / np.linalg.norm(d)


def test_approach_walks_straight_at_the_object_for_its_last_metres():
    fmap = walkable_map(_room(wall=False), body_radius=0.2)
    cup = np.array([-1.0, 0.4])                            # the object, north of the goal
    goal = Goal([-1.0, 0.0], "pick up", 2.0, toward=cup)
    plain = plan_route([1.5, -1.5], [goal], fmap)
    r = plan_route([1.5, -1.5], [goal], fmap, approach=1.2)
    leg = r.legs[0]
    np.testing.assert_allclose(leg[-1], goal.xz)
    length, u = _straight_piece(leg)
    assert length == pytest.approx(1.2, abs=1e-9)
    np.testing.assert_allclose(u, (cup - goal.xz) / np.linalg.norm(cup - goal.xz), atol=1e-9)   # at the object
    assert fmap.is_free(_dense_points(leg)).all()
    assert not np.allclose(_straight_piece(plain.legs[0])[1], u, atol=0.05)                    # the shortest path came from the side
    np.testing.assert_allclose(r.subgoals[-1], goal.xz)
    # No object, no approach length, or a start nearer than the straight piece: the plain route.
    for g, a, start in ((Goal(goal.xz, "pick up", 2.0), 1.2, [1.5, -1.5]), (goal, 0.0, [1.5, -1.5]),
                        (goal, 1.2, [-0.75, -0.25])):
        np.testing.assert_allclose(plan_route(start, [g], fmap, approach=a).legs[0],
                                   plan_route(start, [Goal(g.xz, "pick up", 2.0)], fmap).legs[0])


def test_approach_falls_back_to_a_shorter_piece_where_the_floor_is_blocked():
    occ = np.zeros((200, 100, 200), bool)
    occ[0:100, 0:90, 62:68] = True                         # a wall across z in [-0.76, -0.64) for x < 0
    fmap = walkable_map(OccupancyGrid.from_dense(occ, [-2.0, 0.0, -2.0], 0.02), body_radius=0.2)
    goal = Goal([-1.0, 0.0], "pick up", 2.0, toward=[-1.0, 0.4])
    leg = plan_route([1.5, -1.5], [goal], fmap, approach=1.2).legs[0]
    length, u = _straight_piece(leg)
    assert length == pytest.approx(0.4, abs=1e-9)          # 1.2, 0.9 and 0.6 m cross the wall or its clearance
    np.testing.assert_allclose(u, [0.0, 1.0], atol=1e-9)
    assert fmap.is_free(_dense_points(leg)).all()
    occ[0:100, 0:90, 85:95] = True                         # and now right behind the goal too: no straight piece
    fmap = walkable_map(OccupancyGrid.from_dense(occ, [-2.0, 0.0, -2.0], 0.02), body_radius=0.2)
    np.testing.assert_allclose(plan_route([1.5, -1.5], [goal], fmap, approach=1.2).legs[0],
                               plan_route([1.5, -1.5], [Goal(goal.xz, "pick up", 2.0)], fmap).legs[0])


def test_parse_goals_and_files(tmp_path):
    g = parse_goals([[1, 2], [3, 4]], ["walk", "sit"])
    assert g[0].action is None and g[1].action == "sit" and g[1].duration == 3.0
    with pytest.raises(ConfigError, match="one per goal"):
        parse_goals([[1, 2]], ["sit", "sit"])
    with pytest.raises(ConfigError, match="unknown action 'dance'.*walk, sit"):
        check_actions([Goal([0, 0], "dance")], ["walk", "sit"])
    f = tmp_path / "g.json"
    f.write_text(json.dumps({"start": [0, 0], "goals": [[1, 2], {"xz": [3, 4], "action": "sit", "duration": 2}]}))
    goals, start = load_goals_file(f)
    assert start.tolist() == [0, 0] and goals[1].action == "sit" and goals[1].duration == 2
    c = tmp_path / "g.csv"
    c.write_text("x,z,action,duration\n1,2,,\n3,4,sit,1.5\n")
    goals, _ = load_goals_file(c)
    assert goals[0].action is None and goals[1].duration == 1.5
    bad = tmp_path / "bad.json"
    bad.write_text("[[1, 2], [3]]")
    with pytest.raises(DataError, match=r"goals\[1\]"):
        load_goals_file(bad)
