"""Goals from the user: command-line lists (`parse_goals`) and JSON / CSV goal files
(`load_goals_file`). Bad values name the file and entry (DataError) or the key (ConfigError)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from motiongen.checks import require_range
from motiongen.errors import ConfigError, DataError
from motiongen.sampling.goals import WALK_NAMES, Goal

# Metres from the origin a point may lie: a scene is at most a few hundred metres across, so
# a goal at 1e300 is a typo (it overflowed the grid lookups).
MAX_COORD = 1e4


def parse_point(v, what: str, path=None) -> np.ndarray:
    try:
        a = np.asarray([float(x) for x in v], np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (2,) or not np.all(np.abs(a) <= MAX_COORD):     # nan fails too
        msg = f"expected a point [x, z] of two numbers within ±{MAX_COORD:g} m, got {v!r}"
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
    goals = [Goal(parse_point(p, f"goals[{i}]")) for i, p in enumerate(points)]
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
        for i, (g, d) in enumerate(zip(goals, durations)):
            g.duration = float(require_range(f"durations[{i}]", d, 0, 3600))
    for g in goals:
        if g.action is not None and durations is None:
            g.duration = default_duration
    return goals


def _goal_from_obj(o, i: int, path: Path, default_duration: float) -> Goal:
    where = f"goals[{i}]"
    if isinstance(o, (list, tuple)):
        if len(o) == 2:
            return Goal(parse_point(o, where, path))
        if len(o) in (3, 4):
            d = default_duration if len(o) == 3 else o[3]
            return Goal(parse_point(o[:2], where, path), None if o[2] is None else str(o[2]), _float(d, where, path))
    if isinstance(o, dict):
        if "xz" in o:
            xz = parse_point(o["xz"], where, path)
        elif "x" in o and "z" in o:
            xz = parse_point([o["x"], o["z"]], where, path)
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
                start = parse_point(obj["start"], "start", path)
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
            xz = parse_point(r[:2], f"row {i + 1}", path)
            action = r[2] if len(r) > 2 and r[2] else None
            has_action = action is not None and action.lower() not in WALK_NAMES
            d = _float(r[3], f"row {i + 1}", path) if len(r) == 4 and r[3] else (default_duration if has_action else 0.0)
            goals.append(Goal(xz, action, d))
    if not goals:
        raise DataError(path, "goals", "the file holds no goals")
    return goals, start
