"""Each sample's way through its goals, one episode at a time: the goal state machine.

Per sample: walk towards goal g through its subgoals (look-ahead: the farthest one still within
the model's reach and in line of sight), arrive within `loop.tolerance` of its last subgoal (the
goal), act there for the goal's duration, go on to goal g + 1; after the last goal, idle there
until every sample is done. Samples advance independently in one batch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from motiongen.routing import WalkableMap
from motiongen.sampling.episode import LoopSpec, pelvis_xz
from motiongen.sampling.goals import Goal, Route, action_index
from motiongen.sampling.interactions import seat_height
from motiongen.sampling.settings import LoopConfig
from motiongen.skeleton import LEFT_HIP, RIGHT_HIP


@dataclass(frozen=True)
class GoalPlan:
    """The route's goals as the loop uses them (fixed for one `generate` call)."""

    goals: list[Goal]
    names: list[str]               # the checkpoint's action vocabulary
    subgoals: np.ndarray           # (K, 2) world x, z
    leg_last: np.ndarray           # (G,) index of each goal's last subgoal (the goal itself)
    goal_xz: np.ndarray            # (G, 2) world x, z
    goal_labels: tuple[int, ...]   # (G,) action index of each goal, -1 = none
    act_episodes: tuple[int, ...]  # (G,) episodes to act at each goal (its duration)
    seat_y: np.ndarray             # (G,) pelvis height while acting on a seat or bed; NaN: the model decides
    walk_label: int
    idle_label: int                # "stand", else the walk label
    reach: float                   # m: look-ahead targets lie within it
    lookahead: bool
    tolerance: float               # pelvis distance (m) that counts as arriving
    walkable: WalkableMap | None   # look-ahead targets must be in line of sight on it

    @property
    def final_label(self) -> int:
        """What a sample does once done: the last goal's action, else standing."""
        return self.goal_labels[-1] if self.goals[-1].interacts else self.idle_label


def goal_plan(route: Route, names, scene, loop: LoopConfig, spec: LoopSpec, p_goal_y: float,
              walkable: WalkableMap | None) -> GoalPlan:
    """The `GoalPlan` of a route. Seat heights only for checkpoints trained to take a pelvis
    height (p_goal_y > 0) and only in a scene."""
    names, goals = list(names), route.goals
    new = spec.length - spec.transition                                                       # new frames per episode
    walk, idle = action_index(names, "walk"), action_index(names, "stand")
    act_eps = tuple(int(math.ceil(g.duration * spec.model_fps / new)) if g.interacts and g.duration > 0 else 0
                    for g in goals)
    seat_y = np.array([seat_height(scene, g.xz) + loop.seat_offset
                       if scene is not None and g.action in loop.seat_actions and p_goal_y > 0
                       else np.nan for g in goals])
    leg_last = np.array([np.flatnonzero(route.subgoal_leg == g).max() for g in range(len(goals))])
    return GoalPlan(goals, names, route.subgoals, leg_last, np.stack([g.xz for g in goals]),
                    tuple(action_index(names, g.action) for g in goals), act_eps, seat_y, walk,
                    idle if idle >= 0 else walk, spec.reach, loop.lookahead, loop.tolerance, walkable)


@dataclass
class Progress:
    """Per-sample state of the goal state machine; frames count model frames kept."""

    leg: np.ndarray                # (S,) int goal being approached (or acted at)
    ptr: np.ndarray                # (S,) int first subgoal not yet reached
    acting: np.ndarray             # (S,) int action episodes left at goal `leg`
    done: np.ndarray               # (S,) bool reached (and acted at) the last goal
    arrival_frame: np.ndarray      # (S, G) int frame of the closest approach on arrival, -1 = never
    arrival_error: np.ndarray      # (S, G) pelvis (x, z) distance to the goal there (m), nan = never
    arrival_body: np.ndarray       # (S, G) same for the hips' midpoint
    finish_frame: np.ndarray       # (S,) int last frame of the episode that finished the sample, -1 = never

    @classmethod
    def start(cls, S: int, G: int) -> "Progress":
        return cls(np.zeros(S, np.int64), np.zeros(S, np.int64), np.zeros(S, np.int64), np.zeros(S, bool),
                   np.full((S, G), -1, np.int64), np.full((S, G), np.nan), np.full((S, G), np.nan),
                   np.full(S, -1, np.int64))


@dataclass
class Targets:
    """What one episode asks of each sample."""

    kind: str                      # warmup | walk | act | idle (majority over samples)
    target: np.ndarray             # (S, 2) world pelvis target x, z
    label: np.ndarray              # (S,) int action index over the new frames
    chosen: np.ndarray | None = None   # (S,) int subgoal targeted by walking samples, -1 others
    height: np.ndarray | None = None   # (S,) pelvis height at the target where finite

    @classmethod
    def stand(cls, xz, label: int, S: int) -> "Targets":
        """The warm-up: stand at xz (2,)."""
        return cls("warmup", np.repeat(np.asarray(xz, np.float64)[None], S, 0), np.full(S, label, np.int64))


def next_targets(p: Progress, plan: GoalPlan, pos: np.ndarray) -> Targets:
    """The next episode's targets, from the pelvis positions (S, 2) now."""
    S, G = len(p.leg), len(plan.goals)
    target, label = np.empty((S, 2)), np.empty(S, np.int64)
    chosen, height = np.full(S, -1, np.int64), np.full(S, np.nan)
    kinds = []
    for s in range(S):
        g = min(p.leg[s], G - 1)
        if p.done[s]:
            target[s], label[s] = plan.goal_xz[-1], plan.final_label
            kinds.append("idle")
        elif p.acting[s] > 0:
            target[s], label[s], height[s] = plan.goal_xz[g], plan.goal_labels[g], plan.seat_y[g]
            kinds.append("act")
        else:
            chosen[s] = j = _farthest_visible(plan, p.ptr[s], g, pos[s])
            target[s], label[s] = plan.subgoals[j], plan.walk_label
            kinds.append("walk")
    return Targets(max(set(kinds), key=kinds.count), target, label, chosen, height)


def _farthest_visible(plan: GoalPlan, j, g: int, pos: np.ndarray):
    """From subgoal j on, the last subgoal of goal g's leg that is within reach of pos (2,) and
    in line of sight (look-ahead), else j."""
    sub = plan.subgoals
    if plan.lookahead:
        while (j + 1 <= plan.leg_last[g] and np.linalg.norm(sub[j + 1] - pos) <= plan.reach
               and (plan.walkable is None or plan.walkable.segment_free(pos, sub[j + 1]))):
            j += 1
    return j


def advance(p: Progress, plan: GoalPlan, t: Targets, new: np.ndarray, before: int, n_ep: int) -> list[str]:
    """Move every sample on after episode n_ep, whose kept frames `new` (S, n, J, 3) start at
    model frame `before`. Returns the progress lines (one per goal reached)."""
    G = len(plan.goals)
    pel = pelvis_xz(new)                                                                     # (S, n, 2)
    hips = 0.5 * (new[:, :, LEFT_HIP] + new[:, :, RIGHT_HIP])[..., [0, 2]]                  # (S, n, 2)
    lines = []
    for s in range(len(p.leg)):
        g = min(p.leg[s], G - 1)
        if p.done[s]:
            continue
        if p.acting[s] > 0:
            p.acting[s] -= 1
        elif not _walked(p, plan, s, g, t.chosen[s], pel[s, -1]):
            continue
        else:
            lines.append(_arrive(p, plan, s, g, pel[s], hips[s], before, n_ep))
        if p.acting[s] == 0:
            if p.leg[s] >= G - 1:
                p.done[s] = True
                p.finish_frame[s] = before + pel.shape[1] - 1
            else:
                p.leg[s] += 1
    return lines


def _walked(p: Progress, plan: GoalPlan, s: int, g: int, j, end: np.ndarray) -> bool:
    """Sample s walked towards subgoal j and ended at `end` (2,): whether it reached goal g
    (the last subgoal of its leg). Not there yet: it retargets j next episode."""
    if np.linalg.norm(end - plan.subgoals[j]) > plan.tolerance:
        p.ptr[s] = j
        return False
    p.ptr[s] = j + 1
    return j == plan.leg_last[g]


def _arrive(p: Progress, plan: GoalPlan, s: int, g: int, pel: np.ndarray, hips: np.ndarray, before: int,
            n_ep: int) -> str:
    """Sample s arrived at goal g: record its closest approach over this episode's frames
    (pelvis pel, hips midpoint hips, (n, 2) each) and start acting."""
    d = np.linalg.norm(pel - plan.goal_xz[g], axis=-1)                                      # (n,)
    f = int(np.argmin(d))
    p.arrival_frame[s, g] = before + f
    p.arrival_error[s, g] = d[f]
    p.arrival_body[s, g] = np.linalg.norm(hips[f] - plan.goal_xz[g])
    p.acting[s] = plan.act_episodes[g]
    return f"sample {s}: goal {g + 1}/{len(plan.goals)} reached after {n_ep} episodes ({d[f]:.2f} m)"


def shortfall(p: Progress, plan: GoalPlan, pos: np.ndarray) -> str:
    """How far each unfinished sample got, from the pelvis positions (S, 2) now."""
    G, parts = len(plan.goals), []
    for s in range(len(p.leg)):
        if p.done[s]:
            continue
        g = min(p.leg[s], G - 1)
        dist = float(np.linalg.norm(pos[s] - plan.goal_xz[g]))
        parts.append(f"sample {s} reached {int((p.arrival_frame[s] >= 0).sum())}/{G} goals, {dist:.2f} m from goal {g + 1}")
    return "; ".join(parts)
