"""Goals, routes and subgoals for autoregressive sampling.

Everything here works on the ground plane: points are (x, z) in world metres (y-up).

* `Goal`: a target point, optionally with an action to perform there for `duration` seconds.
* `plan_route`: start + goals -> per-goal legs (shortest collision-free paths on the scene's
  `motiongen.routing.WalkableMap`), the full path and subgoals every `spacing` m.
* `plan_scene_route`: the same from a scene (its walkable map built here) after checking the
  goals' actions against a checkpoint's vocabulary: what a caller does before `generate`.
* Goals from the command line and from JSON / CSV files: `motiongen.sampling.goal_input`.

Goals that carry an interaction (sit, lie down, ...) may lie on furniture: the route then
leads to the nearest walkable point ("approach") and its last, short piece goes straight onto
the goal, which the sampler pins as the pelvis target.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from motiongen.errors import ConfigError
from motiongen.routing import WalkableMap, plan_path, walkable_map

WALK_NAMES = ("walk", "none", "")


@dataclass
class Goal:
    """A goal point (x, z) and what to do on arrival.

    action: a name from the checkpoint's vocabulary, or None for plain locomotion;
    duration: seconds to perform `action` once there (0 = pass through).
    """

    xz: np.ndarray               # (2,) float64 world x, z
    action: str | None = None
    duration: float = 0.0
    # (2,) x, z of what the action is done to (the object a pick-up takes), or None: a route with
    # `approach` comes onto the goal walking straight at it (`plan_route`).
    toward: np.ndarray | None = None

    def __post_init__(self):
        self.xz = np.asarray(self.xz, np.float64).reshape(2)
        if self.toward is not None:
            self.toward = np.asarray(self.toward, np.float64).reshape(2)
        if self.action is not None and str(self.action).strip().lower() in WALK_NAMES:
            self.action = None
        self.duration = float(self.duration)

    @property
    def interacts(self) -> bool:
        return self.action is not None


# ---------------------------------------------------------------------------------------
# Subgoals and routes


def path_length(path: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(path, axis=0), axis=-1).sum()) if len(path) > 1 else 0.0


def place_subgoals(path: np.ndarray, spacing: float) -> np.ndarray:
    """Points (K, 2) every `spacing` metres of arc length along the polyline (N, 2), ending
    exactly at its last point (the last gap is in (0, spacing]). A path of zero length gives
    its end point alone."""
    if spacing <= 0:
        raise ConfigError(f"subgoal_spacing must be > 0, got {spacing}")
    path = np.asarray(path, np.float64)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=-1)                                     # (N-1,)
    total = float(seg.sum())
    if total < 1e-9:
        return path[-1:].copy()
    s = np.concatenate([[0.0], np.cumsum(seg)])                                              # (N,) arc length
    n = int(math.ceil(total / spacing - 1e-9))
    at = np.minimum(np.arange(1, n + 1) * spacing, total)
    at[-1] = total
    keep = np.concatenate([[True], np.diff(at) > 1e-9])
    at = at[keep]
    x = np.interp(at, s, path[:, 0])
    z = np.interp(at, s, path[:, 1])
    out = np.stack([x, z], -1)
    out[-1] = path[-1]
    return out


@dataclass
class Route:
    """A planned route through all goals.

    legs[g] is the polyline from the previous goal (or the start) to goal g; subgoals (K, 2)
    are spaced along the legs and subgoal_leg (K,) says which goal each leads to. The last
    subgoal of each leg is the goal itself.
    """

    start: np.ndarray            # (2,)
    goals: list[Goal]
    legs: list[np.ndarray]       # G arrays (N_g, 2)
    subgoals: np.ndarray         # (K, 2)
    subgoal_leg: np.ndarray      # (K,) int64
    mode: str = "astar"

    @property
    def path(self) -> np.ndarray:
        """(N, 2) the whole planned polyline."""
        parts = [self.legs[0]] + [leg[1:] for leg in self.legs[1:]]
        return np.concatenate(parts) if parts else self.start[None]

    def leg_subgoals(self, g: int) -> np.ndarray:
        return self.subgoals[self.subgoal_leg == g]


def _fmt(p) -> str:
    return f"({p[0]:.2f}, {p[1]:.2f})"


def check_point(fmap: WalkableMap | None, xz, what: str, interacts: bool = False,
                approach_radius: float = 1.0) -> np.ndarray:
    """Validate a start/goal point; return the walkable point the route should use for it.

    Plain goals must lie on free floor; interaction goals (sitting on a chair) may lie on
    furniture, and then route to the nearest free point within `approach_radius`.
    """
    xz = np.asarray(xz, np.float64)
    if not np.all(np.isfinite(xz)):
        raise ConfigError(f"{what} {_fmt(xz)} is not a finite point")
    if fmap is None:
        return xz
    if not fmap.in_bounds(xz):
        (x0, z0), (x1, z1) = fmap.bounds
        raise ConfigError(f"{what} {_fmt(xz)} lies outside the scene bounds "
                          f"x in [{x0:.2f}, {x1:.2f}], z in [{z0:.2f}, {z1:.2f}]")
    if fmap.is_free(xz):
        return xz
    if interacts:
        near = fmap.nearest_free(xz, approach_radius)
        if near is not None:
            return near
        raise ConfigError(f"{what} {_fmt(xz)} has no walkable floor within {approach_radius} m to approach it from")
    why = "inside an obstacle" if not fmap.is_free(xz, clearance=False) else \
        f"closer than body_radius={fmap.body_radius} m to an obstacle"
    raise ConfigError(f"{what} {_fmt(xz)} is {why}")


def plan_route(start, goals: Sequence[Goal], fmap: WalkableMap | None = None, mode: str = "astar",
               spacing: float = 0.6, plan_cell: float = 0.05, approach: float = 0.0) -> Route:
    """Route from `start` (2,) through `goals`: shortest collision-free legs on `fmap`
    (mode="astar": Dijkstra on the grid, the paths A* finds) or straight lines (mode="straight",
    or no map), with subgoals every `spacing` metres. approach > 0 (metres): a goal with a
    `toward` point is come onto walking straight at that point for its last `approach` metres
    (`approach_leg`), where the floor allows.
    Raises ConfigError for points outside the map, inside obstacles, or unreachable."""
    if mode not in ("astar", "straight"):
        raise ConfigError(f"path: expected 'astar' or 'straight', got {mode!r}")
    if not goals:
        raise ConfigError("no goals given (goals=[[x,z],...] or goals_file=PATH)")
    start = check_point(fmap, start, "start")
    legs, subgoals, owner = [], [], []
    cur = start
    for g, goal in enumerate(goals):
        what = f"goal {g + 1}"
        target = check_point(fmap, goal.xz, what, goal.interacts)
        leg = _leg(fmap, cur, goal, target, what, mode, plan_cell, approach)
        sg = place_subgoals(leg, spacing)
        legs.append(leg)
        subgoals.append(sg)
        owner.append(np.full(len(sg), g, np.int64))
        cur = goal.xz
    return Route(start, list(goals), legs, np.concatenate(subgoals), np.concatenate(owner), mode)


def _leg(fmap: WalkableMap | None, cur: np.ndarray, goal: Goal, target: np.ndarray, what: str, mode: str,
         plan_cell: float, approach: float) -> np.ndarray:
    """`plan_route`'s polyline (N, 2) from cur to `goal`, planned to `target` (its walkable
    point, `check_point`)."""
    if mode == "straight" or fmap is None:
        return np.stack([cur, goal.xz])
    if approach > 0 and goal.toward is not None and np.allclose(target, goal.xz):
        leg = approach_leg(fmap, cur, goal, approach, plan_cell)
        if leg is not None:
            return leg
    leg = plan_path(fmap, cur, target, plan_cell)
    if leg is None:
        raise ConfigError(f"no collision-free path from {_fmt(cur)} to {what} at {_fmt(goal.xz)} "
                          f"(body_radius={fmap.body_radius} m)")
    if not np.allclose(target, goal.xz):
        leg = np.concatenate([leg, goal.xz[None]])                                           # onto the furniture
    return leg


# Shorter straight last legs tried, as fractions of `approach`, where the full one is not open floor.
APPROACH_FRACTIONS = (1.0, 0.75, 0.5, 1 / 3)


def approach_leg(fmap: WalkableMap, cur: np.ndarray, goal: Goal, approach: float, plan_cell: float = 0.05):
    """A leg (N, 2) from cur onto goal.xz whose last piece is straight, at least `approach` m
    (or the longest of APPROACH_FRACTIONS of it that is open floor) along the line from
    goal.toward through the goal: the body comes walking at what it acts on, as people do (the
    data's pick-ups come straight at their object) instead of arriving from the side the
    shortest path happens to come from, with the object beside it. A fraction is skipped where
    its piece is blocked or cur is no farther from the goal than the piece is long; None where
    every one is."""
    d = goal.xz - goal.toward
    if np.linalg.norm(d) < 1e-6:
        return None
    u = d / np.linalg.norm(d)
    for f in APPROACH_FRACTIONS:
        length = f * approach
        p0 = goal.xz + length * u                       # where the straight piece begins
        if np.linalg.norm(np.asarray(cur) - goal.xz) <= length or not fmap.segment_free(p0, goal.xz):
            continue
        leg = plan_path(fmap, cur, p0, plan_cell)
        if leg is not None:
            return np.concatenate([leg, goal.xz[None]])
    return None


def plan_scene_route(start, goals: Sequence[Goal], vocabulary: Sequence[str], scene=None, *,
                     walkable: WalkableMap | None = None, path: str = "astar", subgoal_spacing: float = 0.6,
                     body_radius: float = 0.25) -> tuple[Route, WalkableMap | None]:
    """(route, walkable map) for `generate(route=, walkable=)`: `goals` checked against the
    checkpoint's `vocabulary` (`check_actions`), then `plan_route` with `path` / `subgoal_spacing`
    on `walkable`, built from `scene` (an OccupancyGrid or None) with `body_radius` when None
    and path="astar". The map returned is the one planned on (None: no scene, or path="straight"
    without one given): `generate` tests look-ahead targets for line of sight on it.
    Raises ConfigError for unknown actions and bad points or paths."""
    goals = list(goals)
    check_actions(goals, vocabulary)
    if walkable is None and scene is not None and path == "astar":
        walkable = walkable_map(scene, body_radius)
    return plan_route(start, goals, walkable, path, subgoal_spacing), walkable


def action_index(vocabulary: Sequence[str], name: str | None) -> int:
    """The index of action `name` in `vocabulary`; -1 for None or a name it lacks."""
    return vocabulary.index(name) if name is not None and name in vocabulary else -1


def check_actions(goals: Sequence[Goal], vocabulary: Sequence[str]) -> None:
    """Every goal action must be in the checkpoint's vocabulary (case-insensitive match is
    normalised to the vocabulary's spelling)."""
    lower = {v.lower(): v for v in vocabulary}
    for i, g in enumerate(goals):
        if g.action is None:
            continue
        name = lower.get(g.action.strip().lower())
        if name is None:
            raise ConfigError(f"unknown action {g.action!r} for goal {i + 1}; this checkpoint knows: "
                              f"{', '.join(vocabulary)} (or walk)")
        g.action = name
