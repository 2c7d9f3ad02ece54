"""The API's request bodies and query values, checked: RequestError (HTTP 400 unless it says
otherwise) with a one-line reason for anything malformed."""

from __future__ import annotations

import math
from http import HTTPStatus

from motiongen.sampling.goal_input import MAX_COORD
from motiongen.sampling.goals import Goal

MAX_GOALS_PER_REQUEST = 100


class RequestError(Exception):
    """A request the API refuses: one line, and the HTTP status to answer with."""

    def __init__(self, message: str, status: HTTPStatus = HTTPStatus.BAD_REQUEST):
        super().__init__(message)
        self.status = status


def parse_goals_body(body, action_seconds: float = 3.0) -> tuple[list[Goal], bool]:
    """{"goals": [{"x": .., "z": .., "action": name|null, "seconds": s?}, ...], "replace": bool?} or
    the bare list -> (Goals, replace); action "walk" or null: walk there; seconds: how long to act
    (default action_seconds); replace: drop the pending goals first."""
    if isinstance(body, dict) and set(body) - {"goals", "replace"}:
        raise RequestError(f"unknown field(s) {', '.join(sorted(set(body) - {'goals', 'replace'}))}")
    replace = body.get("replace", False) if isinstance(body, dict) else False
    if not isinstance(replace, bool):
        raise RequestError(f"replace: expected true or false, got {replace!r:.40}")
    items = body.get("goals") if isinstance(body, dict) else body
    if not isinstance(items, list) or not items:
        raise RequestError('expected {"goals": [{"x": X, "z": Z, "action": NAME}, ...]} with at least one goal')
    if len(items) > MAX_GOALS_PER_REQUEST:
        raise RequestError(f"{len(items)} goals in one request; at most {MAX_GOALS_PER_REQUEST}")
    return [_goal(item, i, action_seconds) for i, item in enumerate(items)], replace


def _goal(item, i: int, action_seconds: float) -> Goal:
    if not isinstance(item, dict):
        raise RequestError(f"goals[{i}]: expected an object with x, z and an optional action, got {item!r:.60}")
    unknown = set(item) - {"x", "z", "action", "seconds"}
    if unknown:
        raise RequestError(f"goals[{i}]: unknown field(s) {', '.join(sorted(unknown))}")
    x, z = (_number(item.get(k), f"goals[{i}].{k}", MAX_COORD) for k in ("x", "z"))
    action = item.get("action")
    if action is not None and not isinstance(action, str):
        raise RequestError(f"goals[{i}].action: expected a name or null, got {action!r:.60}")
    action = None if action is None or action.strip().lower() in ("", "walk") else action.strip()
    seconds = action_seconds if item.get("seconds") is None else _number(item["seconds"], f"goals[{i}].seconds", 600)
    if seconds < 0:
        raise RequestError(f"goals[{i}].seconds: expected >= 0, got {seconds:g}")
    return Goal([x, z], action, seconds if action else 0.0)


def _number(v, what: str, limit: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or abs(v) > limit:
        raise RequestError(f"{what}: expected a number within ±{limit:g}, got {v!r:.60}")
    return float(v)


def parse_playing(body) -> bool:
    if not isinstance(body, dict) or not isinstance(body.get("playing"), bool):
        raise RequestError('expected {"playing": true} or {"playing": false}')
    return body["playing"]


def parse_int(query: dict, key: str, default):
    """A query value `key` as a non-negative integer (default when absent)."""
    values = query.get(key)
    if not values:
        return default
    try:
        v = int(values[0])
    except ValueError:
        raise RequestError(f"{key}: expected an integer, got {values[0]!r:.40}") from None
    if v < 0:
        raise RequestError(f"{key}: expected >= 0, got {v}")
    return v
