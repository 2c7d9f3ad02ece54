"""Goals, walkable maps, A* routes and subgoals for autoregressive sampling.

Everything here works on the ground plane: points are (x, z) in world metres (y-up).

* `Goal`: a target point, optionally with an action to perform there for `duration` seconds.
* `WalkableMap`: the free floor of a scene (from `motiongen.data.scene.floor_map`), dilated by
  a body radius so that the body can be planned as a point, and coarsened for planning.
* `astar`: 8-connected A* on the coarse map (no corner cutting), then line-of-sight
  shortening on the fine map, so routes are short polylines rather than staircases.
* `plan_route`: start + goals -> per-goal legs, the full path and subgoals every `spacing` m.
* `parse_goals` / `load_goals_file`: command-line values and JSON / CSV goal files.

Goals that carry an interaction (sit, lie down, ...) may lie on furniture: the route then
leads to the nearest walkable point ("approach") and its last, short piece goes straight onto
the goal, which the sampler pins as the pelvis target.
"""

from __future__ import annotations

import csv
import heapq
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
import scipy.ndimage as ndi

from motiongen.errors import ConfigError, DataError

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

    def __post_init__(self):
        self.xz = np.asarray(self.xz, np.float64).reshape(2)
        if self.action is not None and str(self.action).strip().lower() in WALK_NAMES:
            self.action = None
        self.duration = float(self.duration)

    @property
    def interacts(self) -> bool:
        return self.action is not None


# ---------------------------------------------------------------------------------------
# Walkable map


@dataclass
class WalkableMap:
    """Free floor cells. `free` (X, Z) bool at `cell` metres, cell (i, k) covering
    [origin + (i, k) * cell, origin + (i+1, k+1) * cell). `free` already excludes cells within
    `body_radius` of an obstacle; `open` is the same without that margin (raw obstacles)."""

    free: np.ndarray             # (X, Z) bool, clearance applied
    open: np.ndarray             # (X, Z) bool, no clearance
    origin: np.ndarray           # (2,) float64 world x, z of cell (0, 0)'s min corner
    cell: float
    body_radius: float = 0.0
    # Coarse planning map (built lazily): a coarse cell is free iff all its fine cells are.
    _coarse: tuple | None = field(default=None, repr=False)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 2): [[x_min, z_min], [x_max, z_max]]."""
        return np.stack([self.origin, self.origin + np.asarray(self.free.shape) * self.cell])

    def in_bounds(self, xz) -> np.ndarray:
        xz = np.asarray(xz, np.float64)
        lo, hi = self.bounds
        return np.all((xz >= lo) & (xz < hi), axis=-1)

    def _cells(self, xz) -> tuple[np.ndarray, np.ndarray]:
        ik = np.floor((np.asarray(xz, np.float64) - self.origin) / self.cell).astype(np.int64)   # (..., 2)
        inside = np.all((ik >= 0) & (ik < np.asarray(self.free.shape)), axis=-1)
        return np.where(inside[..., None], ik, 0), inside

    def is_free(self, xz, clearance: bool = True) -> np.ndarray:
        """(...,) bool for points (..., 2); outside the map is not free."""
        ik, inside = self._cells(xz)
        m = self.free if clearance else self.open
        return inside & m[ik[..., 0], ik[..., 1]]

    def segment_free(self, a, b, clearance: bool = True) -> bool:
        """Every point of segment a-b (2,) lies on free floor (sampled at half a cell)."""
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        n = max(2, int(math.ceil(np.linalg.norm(b - a) / (0.5 * self.cell))) + 1)
        pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)                               # (n, 2)
        return bool(self.is_free(pts, clearance).all())

    def nearest_free(self, xz, max_dist: float = math.inf) -> np.ndarray | None:
        """The free cell centre (2,) nearest to xz, or None if none lies within max_dist."""
        ik, inside = self._cells(xz)
        if inside and self.free[ik[0], ik[1]]:
            return np.asarray(xz, np.float64)
        if not self.free.any():
            return None
        cand = np.argwhere(self.free)                                                        # (N, 2)
        centres = self.origin + (cand + 0.5) * self.cell
        d = np.linalg.norm(centres - np.asarray(xz, np.float64), axis=-1)
        i = int(np.argmin(d))
        return centres[i] if d[i] <= max_dist else None

    def coarse(self, cell: float) -> tuple[np.ndarray, np.ndarray, float]:
        """(free (Xc, Zc) bool, origin (2,), cell size): blocks of fine cells, free iff all are."""
        f = max(1, int(round(cell / self.cell)))
        if self._coarse is not None and self._coarse[0] == f:
            return self._coarse[1:]
        X, Z = self.free.shape
        Xc, Zc = -(-X // f), -(-Z // f)
        pad = np.zeros((Xc * f, Zc * f), bool)
        pad[:X, :Z] = self.free
        cfree = pad.reshape(Xc, f, Zc, f).all(axis=(1, 3))                                   # (Xc, Zc)
        self._coarse = (f, cfree, self.origin.copy(), self.cell * f)
        return self._coarse[1:]


def walkable_map(grid, body_radius: float = 0.25, body_height: tuple[float, float] = (0.1, 1.7),
                 floor_y: float = 0.0) -> WalkableMap:
    """The walkable map of an OccupancyGrid: free where nothing occupies the body's height band,
    and (for `free`) farther than `body_radius` from anything that does."""
    from motiongen.data.scene import floor_map

    open_, origin, cell = floor_map(grid, tuple(body_height), floor_y, clearance=0.0)
    if body_radius > 0:
        # Distance transform instead of a disk dilation: O(cells) whatever the radius.
        dist = ndi.distance_transform_edt(open_) * cell                                      # to nearest blocked cell
        free = open_ & (dist > body_radius)
    else:
        free = open_.copy()
    # The map's border touches space the grid does not cover (walls or nothing): keep the
    # body off it too.
    r = int(math.ceil(body_radius / cell))
    if r > 0:
        free[:r], free[-r:], free[:, :r], free[:, -r:] = False, False, False, False
    return WalkableMap(free, open_, np.asarray(origin, np.float64), float(cell), float(body_radius))


# ---------------------------------------------------------------------------------------
# A*

_NEIGHBOURS = [(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)]


def _astar_cells(free: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> list[tuple[int, int]] | None:
    """8-connected A* over free (X, Z) cells with the octile heuristic; diagonal moves only
    when both orthogonal neighbours are free (no squeezing between two blocked corners)."""
    X, Z = free.shape
    sq2 = math.sqrt(2.0)

    def h(c):
        dx, dz = abs(c[0] - goal[0]), abs(c[1] - goal[1])
        return (dx + dz) + (sq2 - 2) * min(dx, dz)

    g = {start: 0.0}
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    heap = [(h(start), 0.0, start)]
    closed = np.zeros_like(free)
    while heap:
        _, gc, c = heapq.heappop(heap)
        if closed[c]:
            continue
        if c == goal:
            path = [c]
            while c in parent:
                c = parent[c]
                path.append(c)
            return path[::-1]
        closed[c] = True
        ci, ck = c
        for di, dk in _NEIGHBOURS:
            ni, nk = ci + di, ck + dk
            if not (0 <= ni < X and 0 <= nk < Z) or not free[ni, nk] or closed[ni, nk]:
                continue
            if di and dk and not (free[ci + di, ck] and free[ci, ck + dk]):
                continue
            ng = gc + (sq2 if di and dk else 1.0)
            n = (ni, nk)
            if ng < g.get(n, math.inf):
                g[n] = ng
                parent[n] = c
                heapq.heappush(heap, (ng + h(n), ng, n))
    return None


def shortcut(path: np.ndarray, fmap: WalkableMap) -> np.ndarray:
    """Greedy line-of-sight shortening of a polyline (N, 2) -> (M, 2), M <= N, same ends."""
    out = [path[0]]
    i = 0
    while i < len(path) - 1:
        j = len(path) - 1
        while j > i + 1 and not fmap.segment_free(path[i], path[j]):
            j -= 1
        out.append(path[j])
        i = j
    return np.asarray(out)


def astar(fmap: WalkableMap, start, goal, plan_cell: float = 0.05) -> np.ndarray | None:
    """A collision-free polyline (N, 2) from start to goal (both must be free), or None.

    Plans on cells of `plan_cell` metres (a coarse cell is free only if all of its fine cells
    are), then shortens the route by line of sight on the fine map.
    """
    start, goal = np.asarray(start, np.float64), np.asarray(goal, np.float64)
    if fmap.segment_free(start, goal):
        return np.stack([start, goal])
    cfree, origin, cell = fmap.coarse(plan_cell)

    def snap(p):
        # The coarse cell containing p, or the nearest free coarse cell reachable in a
        # straight free line (p may sit in a partly blocked coarse cell near a wall).
        ik = tuple(np.clip(np.floor((p - origin) / cell).astype(int), 0, np.asarray(cfree.shape) - 1))
        if cfree[ik]:
            return ik
        cand = np.argwhere(cfree)
        if not len(cand):
            return None
        centres = origin + (cand + 0.5) * cell
        order = np.argsort(np.linalg.norm(centres - p, axis=-1))[:64]
        for o in order:
            if fmap.segment_free(p, centres[o]):
                return tuple(cand[o])
        return None

    s, g = snap(start), snap(goal)
    if s is None or g is None:
        return None
    cells = _astar_cells(cfree, s, g)
    if cells is None:
        return None
    mid = origin + (np.asarray(cells, np.float64) + 0.5) * cell                              # (N, 2)
    return shortcut(np.concatenate([start[None], mid, goal[None]]), fmap)


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
               spacing: float = 0.6, plan_cell: float = 0.05) -> Route:
    """Route from `start` (2,) through `goals`: A* legs on `fmap` (mode="astar") or straight
    lines (mode="straight", or no map), with subgoals every `spacing` metres.
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
        if mode == "straight" or fmap is None:
            leg = np.stack([cur, goal.xz])
        else:
            leg = astar(fmap, cur, target, plan_cell)
            if leg is None:
                raise ConfigError(f"no collision-free path from {_fmt(cur)} to {what} at {_fmt(goal.xz)} "
                                  f"(body_radius={fmap.body_radius} m)")
            if not np.allclose(target, goal.xz):
                leg = np.concatenate([leg, goal.xz[None]])                                   # onto the furniture
        sg = place_subgoals(leg, spacing)
        legs.append(leg)
        subgoals.append(sg)
        owner.append(np.full(len(sg), g, np.int64))
        cur = goal.xz
    return Route(start, list(goals), legs, np.concatenate(subgoals), np.concatenate(owner), mode)


# ---------------------------------------------------------------------------------------
# Parsing


def _num_pair(v, what: str, path=None) -> np.ndarray:
    try:
        a = np.asarray([float(x) for x in v], np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (2,) or not np.all(np.isfinite(a)):
        msg = f"expected a point [x, z] of two numbers, got {v!r}"
        if path is not None:
            raise DataError(path, what, msg)
        raise ConfigError(f"{what}: {msg}")
    return a


def parse_goals(points, actions=None, durations=None, default_duration: float = 3.0) -> list[Goal]:
    """Goals from command-line lists: points [[x, z], ...], actions [name|walk, ...] (one per
    goal, or None), durations [seconds, ...] (one per goal, or None = default_duration for
    goals with an action)."""
    if points is None:
        return []
    points = list(points)
    if points and not isinstance(points[0], (list, tuple)) and len(points) == 2:
        points = [points]                                                                    # goals=[x,z]
    goals = [Goal(_num_pair(p, f"goals[{i}]")) for i, p in enumerate(points)]
    if actions is not None:
        actions = [actions] if isinstance(actions, str) else list(actions)
        if len(actions) != len(goals):
            raise ConfigError(f"actions: expected one per goal ({len(goals)}), got {len(actions)}")
        for g, a in zip(goals, actions):
            g.action = None if a is None or str(a).strip().lower() in WALK_NAMES else str(a)
    if durations is not None:
        durations = [durations] if isinstance(durations, (int, float)) else list(durations)
        if len(durations) != len(goals):
            raise ConfigError(f"durations: expected one per goal ({len(goals)}), got {len(durations)}")
        for g, d in zip(goals, durations):
            g.duration = float(d)
    for g in goals:
        if g.action is not None and durations is None:
            g.duration = default_duration
    return goals


def _goal_from_obj(o, i: int, path: Path, default_duration: float) -> Goal:
    where = f"goals[{i}]"
    if isinstance(o, (list, tuple)):
        if len(o) == 2:
            return Goal(_num_pair(o, where, path))
        if len(o) in (3, 4):
            d = default_duration if len(o) == 3 else o[3]
            return Goal(_num_pair(o[:2], where, path), None if o[2] is None else str(o[2]), _float(d, where, path))
    if isinstance(o, dict):
        if "xz" in o:
            xz = _num_pair(o["xz"], where, path)
        elif "x" in o and "z" in o:
            xz = _num_pair([o["x"], o["z"]], where, path)
        else:
            raise DataError(path, where, "a goal object needs 'xz': [x, z] or 'x' and 'z'")
        action = o.get("action")
        has_action = action is not None and str(action).strip().lower() not in WALK_NAMES
        d = o.get("duration", default_duration if has_action else 0.0)
        return Goal(xz, None if action is None else str(action), _float(d, where, path))
    raise DataError(path, where, f"expected [x, z], [x, z, action(, seconds)] or an object, got {o!r}")


def _float(v, where, path) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        raise DataError(path, where, f"duration must be a number, got {v!r}") from None
    if not math.isfinite(f) or f < 0:
        raise DataError(path, where, f"duration must be a finite number >= 0, got {v!r}")
    return f


def load_goals_file(path, default_duration: float = 3.0) -> tuple[list[Goal], np.ndarray | None]:
    """Goals (and an optional start) from a JSON or CSV file.

    JSON: a list of goals, or {"start": [x, z], "goals": [...]}; a goal is [x, z],
    [x, z, action], [x, z, action, seconds] or {"xz": [x, z] | "x", "z", "action", "duration"}.
    CSV: columns x, z[, action[, duration]], with or without a header row.
    Returns (goals, start (2,) or None).
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(path, None, "goals file does not exist")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise DataError(path, None, f"cannot read goals file ({type(e).__name__})") from None
    start = None
    if path.suffix.lower() == ".json" or text.lstrip()[:1] in ("[", "{"):
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as e:
            raise DataError(path, None, f"not valid JSON (line {e.lineno}: {e.msg})") from None
        if isinstance(obj, dict):
            if "goals" not in obj:
                raise DataError(path, "goals", "missing; expected {\"goals\": [...]} or a list of goals")
            if obj.get("start") is not None:
                start = _num_pair(obj["start"], "start", path)
            obj = obj["goals"]
        if not isinstance(obj, list):
            raise DataError(path, "goals", "expected a list of goals")
        goals = [_goal_from_obj(o, i, path, default_duration) for i, o in enumerate(obj)]
    else:
        rows = [r for r in csv.reader(text.splitlines()) if r and any(c.strip() for c in r)]
        if rows and rows[0] and rows[0][0].strip().lower() in ("x", "goal_x"):
            rows = rows[1:]
        goals = []
        for i, r in enumerate(rows):
            r = [c.strip() for c in r]
            if len(r) not in (2, 3, 4):
                raise DataError(path, f"row {i + 1}", f"expected x, z[, action[, duration]], got {len(r)} columns")
            xz = _num_pair(r[:2], f"row {i + 1}", path)
            action = r[2] if len(r) > 2 and r[2] else None
            has_action = action is not None and action.lower() not in WALK_NAMES
            d = _float(r[3], f"row {i + 1}", path) if len(r) == 4 and r[3] else (default_duration if has_action else 0.0)
            goals.append(Goal(xz, action, d))
    if not goals:
        raise DataError(path, "goals", "the file holds no goals")
    return goals, start


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
