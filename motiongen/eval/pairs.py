"""Start/end pairs of the evaluation protocol (TRUMANS supplement A.1) and its configuration.

Static pairs run between free-floor points, some ending at a spot where the scene's data sits
or lies; dynamic pairs end where the data picks an object up. Pairs depend only on (seed, scene
id, setting): evaluating a subset of scenes gives the same pairs for those scenes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from motiongen.errors import ConfigError
from motiongen.eval.scene_context import SceneContext
from motiongen.sampling.goals import Goal, Route, path_length, plan_route
from motiongen.sampling.settings import CLEANUP_STAGES

SETTINGS = ("static", "dynamic")
MAX_ACTION_SECONDS = 10.0
_SETTING_CODE = {"static": 0, "dynamic": 1}


@dataclass
class ProtocolConfig:
    k: int = 5                          # samples per pair (one batch)
    pairs: int = 5                      # pairs per scene and setting (paper: 5)
    interaction_pairs: int = 2          # static pairs that end at a seat (when the scene has one)
    static_actions: tuple = ("sit", "lie down")   # interactions a static pair may end with
    dynamic_action: str = "pick up"
    action_seconds: float | None = None  # how long the interaction is held; None: as long as the data did there (≤ 10 s)
    min_distance: float = 2.0           # start-end straight-line distance (m), halved if the room is too small
    body_radius: float = 0.25
    subgoal_spacing: float = 0.6
    # Metres of straight walk onto a pick-up spot, along the line from its object (`goals.approach_leg`;
    # 0: the shortest path's own last leg).
    approach: float = 0.0
    max_episodes: int = 24              # per pair; a sample that has not arrived by then counts as a miss
    seed: int = 0
    pskl_frames: int = 60               # PSKL chunk length (frames at 30 fps = 2 s)
    contact_thresh: float = 0.02
    loop: dict = field(default_factory=dict)   # LoopConfig fields set for every pair (the sampler's clean-up)
    # Ablation: on the first `ablation_pairs` pairs of each scene and setting, the output again
    # with each of these clean-up stages off in turn (`sampling.settings.CLEANUP_STAGES`), same
    # pair and noise; 0 pairs or [] = none. Two stages act inside the episode loop and need the
    # pair sampled again; the others redo only the clean-up.
    ablate: tuple = tuple(CLEANUP_STAGES)
    ablation_pairs: int = 1


@dataclass
class Pair:
    setting: str
    scene: int
    index: int
    start: np.ndarray                   # (2,) world x, z on free floor
    goal: Goal                          # end point (+ action)
    route: Route                        # planned legs, subgoals (the "midpoints")
    object_id: int | None = None
    object_pose: np.ndarray | None = None   # (4, 4)

    def describe(self) -> dict:
        return {"setting": self.setting, "scene": self.scene, "index": self.index,
                "start": [round(float(v), 4) for v in self.start],
                "end": [round(float(v), 4) for v in self.goal.xz], "action": self.goal.action,
                "duration_s": self.goal.duration, "object_id": self.object_id,
                "path_length_m": round(path_length(self.route.path), 4),
                "subgoals": int(len(self.route.subgoals))}



def _rng(seed: int, scene: int, setting: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(scene), _SETTING_CODE[setting]])


def pair_seed(seed: int, setting: str, scene: int, index: int) -> int:
    """Seed of the diffusion noise for one pair: a function of the pair alone."""
    return int(np.random.SeedSequence([int(seed), _SETTING_CODE[setting], int(scene), int(index)]).generate_state(1)[0])


def _try_route(ctx: SceneContext, start, goal: Goal, cfg: ProtocolConfig) -> Route | None:
    try:
        return plan_route(start, [goal], ctx.fmap, "astar", cfg.subgoal_spacing, approach=cfg.approach)
    except ConfigError:
        return None


def _random_free(ctx: SceneContext, rng) -> np.ndarray:
    # A random fine free cell, jittered inside it so starts are not on a lattice.
    c = ctx.free_xz[int(rng.integers(len(ctx.free_xz)))]
    return c + rng.uniform(-0.45, 0.45, 2) * ctx.fmap.cell


def make_pairs(ctx: SceneContext, setting: str, cfg: ProtocolConfig, action_names, tries: int = 300) -> list[Pair]:
    """`cfg.pairs` valid pairs for one scene: start on free floor (body-radius clearance),
    end on free floor or at an interaction spot, an A* route between them. Deterministic in
    (cfg.seed, scene, setting). Raises ConfigError when the scene has no valid pair at all."""
    if setting not in SETTINGS:
        raise ConfigError(f"settings: expected a subset of {list(SETTINGS)}, got {setting!r}")
    if not len(ctx.free_xz):
        raise ConfigError(f"scene {ctx.id} has no walkable floor for body_radius={cfg.body_radius} m")
    rng = _rng(cfg.seed, ctx.id, setting)
    vocab = set(action_names)
    if setting == "static":
        spots = [s for a in cfg.static_actions if a in vocab for s in ctx.spots(a)]
        # Interaction pairs at odd positions first (1, 3, ...), so a short run still mixes both kinds.
        order = list(range(1, cfg.pairs, 2)) + list(range(0, cfg.pairs, 2))
        wants = set(order[:min(cfg.interaction_pairs, cfg.pairs)]) if spots else set()
    else:
        if cfg.dynamic_action not in vocab:
            return []
        spots = ctx.spots(cfg.dynamic_action) or ctx.object_spots(cfg.dynamic_action)
        if not spots:
            return []
        wants = set(range(cfg.pairs))
    spot_order = [int(i) for i in rng.permutation(len(spots))] if spots else []
    pairs: list[Pair] = []
    n_spot = 0
    for i in range(cfg.pairs):
        pair = None
        for attempt in range(tries):
            # Small rooms: relax the distance after half the tries rather than fail.
            min_d = cfg.min_distance if attempt < tries // 2 else cfg.min_distance / 2
            start = _random_free(ctx, rng)
            spot = None
            if i in wants and spot_order:
                spot = spots[spot_order[(n_spot + attempt // 10) % len(spot_order)]]
                # Held as long as the data holds it there, so model and data are compared on
                # like segments (sit: 1.8-8.7 s in the test scenes, lie down: 10 s).
                secs = cfg.action_seconds if cfg.action_seconds is not None else min(spot.duration, MAX_ACTION_SECONDS)
                # A pick-up is done to its object; a seat's spot is turned away from, not walked at.
                toward = spot.object_pose[[0, 2], 3] if setting == "dynamic" and spot.object_pose is not None else None
                goal = Goal(spot.xz, spot.action, secs, toward)
            else:
                goal = Goal(_random_free(ctx, rng))
            if np.linalg.norm(goal.xz - start) < min_d:
                continue
            route = _try_route(ctx, start, goal, cfg)
            if route is None:
                continue
            pair = Pair(setting, ctx.id, i, start, goal, route,
                        spot.object_id if spot is not None else None,
                        spot.object_pose if spot is not None else None)
            if spot is not None:
                n_spot += 1
            break
        if pair is None:
            if setting == "dynamic":
                continue
            raise ConfigError(f"scene {ctx.id}: could not find a {setting} start/end pair with a collision-free "
                              f"path in {tries} tries (body_radius={cfg.body_radius} m)")
        pairs.append(pair)
    return pairs
