"""Sampling: goal routes (shortest paths, subgoals) and the autoregressive episode loop."""

from motiongen.sampling.autoregressive import generate
from motiongen.sampling.episode import model_reach
from motiongen.sampling.goal_input import load_goals_file, parse_goals
from motiongen.sampling.goals import Goal, Route, check_actions, place_subgoals, plan_route, plan_scene_route
from motiongen.sampling.settings import Episode, LoopConfig, Motion, SamplerSettings

__all__ = [
    "Episode", "LoopConfig", "Motion", "SamplerSettings", "generate", "model_reach", "Goal", "Route",
    "check_actions", "load_goals_file", "parse_goals", "place_subgoals", "plan_route", "plan_scene_route",
]
