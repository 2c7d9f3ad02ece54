"""Sampling: goal routes (A*, subgoals) and the autoregressive episode loop."""

from motiongen.sampling.autoregressive import Episode, LoopConfig, Motion, SamplerSettings, generate, model_reach
from motiongen.sampling.goals import (Goal, Route, WalkableMap, astar, check_actions, load_goals_file,
                                      parse_goals, place_subgoals, plan_route, walkable_map)

__all__ = [
    "Episode", "LoopConfig", "Motion", "SamplerSettings", "generate", "model_reach", "Goal", "Route",
    "WalkableMap", "astar", "check_actions", "load_goals_file", "parse_goals", "place_subgoals", "plan_route",
    "walkable_map",
]
