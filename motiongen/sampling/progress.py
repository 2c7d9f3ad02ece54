"""Each sample's way through its goals, one episode at a time: the goal state machine.

Per sample: walk towards goal g through its subgoals (look-ahead: the farthest one still within
the model's reach and in line of sight), arrive within `loop.tolerance` of its last subgoal (the
goal), act there for the goal's duration, go on to goal g + 1; after the last goal, idle there
until every sample is done. Samples advance independently in one batch.

A sample that makes no progress for `loop.stall_s` seconds of motion stalls (`stall_rule`): it
idles where it stands, like a finished sample, and its goal counts as failed (`goal_outcomes`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from motiongen.routing import WalkableMap
from motiongen.sampling.episode import LoopSpec, pelvis_xz
from motiongen.sampling.goals import Goal, Route, action_index
from motiongen.sampling.interactions import seat_height
from motiongen.sampling.settings import EPISODE_LIMIT, NOT_ATTEMPTED, REACHED, STALLED, LoopConfig
from motiongen.skeleton import LEFT_HIP, PELVIS, RIGHT_HIP

# How much closer (m) to its current subgoal a sample must come for that to count as progress:
# above a standing body's pelvis sway between episodes (a few cm), below what one episode of
# even a slow walk covers (0.4 m/s x 1.4 s). Smaller steps still count once they add up to it.
STALL_MARGIN = 0.1


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
    model_fps: float               # frames per second of the kept frames
    stall_s: float                 # seconds of motion without progress after which a sample stalls (inf: never)
    hand_goal_on_arrival: bool = False  # the episode walking onto a goal's spot gets that goal's hand goal (LoopConfig's)

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
    stall_s = float(loop.stall_s) if loop.stall_s else math.inf                               # null or 0: off
    return GoalPlan(goals, names, route.subgoals, leg_last, np.stack([g.xz for g in goals]),
                    tuple(action_index(names, g.action) for g in goals), act_eps, seat_y, walk,
                    idle if idle >= 0 else walk, spec.reach, loop.lookahead, loop.tolerance, walkable,
                    spec.model_fps, stall_s, loop.hand_goal_on_arrival)


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
    best: np.ndarray               # (S,) closest distance (m) to subgoal `ptr` since the last progress, inf = none yet
    moved: np.ndarray              # (S,) int last frame at which the sample made progress, -1 = none yet
    stalled: np.ndarray            # (S,) bool stopped for want of progress (at goal `leg`)
    halt_xz: np.ndarray            # (S, 2) where a stalled sample stands, nan = not stalled

    @classmethod
    def start(cls, S: int, G: int) -> "Progress":
        return cls(np.zeros(S, np.int64), np.zeros(S, np.int64), np.zeros(S, np.int64), np.zeros(S, bool),
                   np.full((S, G), -1, np.int64), np.full((S, G), np.nan), np.full((S, G), np.nan),
                   np.full(S, -1, np.int64), np.full(S, np.inf), np.full(S, -1, np.int64), np.zeros(S, bool),
                   np.full((S, 2), np.nan))

    @property
    def finished(self) -> np.ndarray:
        """(S,) bool: done, or stalled; either way the sample only idles from now on."""
        return self.done | self.stalled


@dataclass
class Targets:
    """What one episode asks of each sample."""

    kind: str                      # warmup | walk | act | idle (majority over samples; ties: act, walk, idle)
    target: np.ndarray             # (S, 2) world pelvis target x, z
    label: np.ndarray              # (S,) int action index over the new frames
    chosen: np.ndarray | None = None   # (S,) int subgoal targeted by walking samples, -1 others
    height: np.ndarray | None = None   # (S,) pelvis height at the target where finite
    hand: np.ndarray | None = None     # (S,) wrist joint given a goal at the window's last frame, -1 = none
    hand_point: np.ndarray | None = None   # (S, 3) world position of that wrist goal
    hand_label: np.ndarray | None = None   # (S,) int the action whose hand goal each sample gets; None: `label`

    def hand_labels(self) -> np.ndarray:
        """(S,) the action each sample's hand goal is for (`interactions.hand_goals`)."""
        return self.label if self.hand_label is None else self.hand_label

    @classmethod
    def stand(cls, xz, label: int, S: int) -> "Targets":
        """The warm-up: stand at xz (2,)."""
        return cls("warmup", np.repeat(np.asarray(xz, np.float64)[None], S, 0), np.full(S, label, np.int64))


def next_targets(p: Progress, plan: GoalPlan, pos: np.ndarray) -> Targets:
    """The next episode's targets, from the pelvis positions (S, 2) now."""
    S, G = len(p.leg), len(plan.goals)
    target, label = np.empty((S, 2)), np.empty(S, np.int64)
    chosen, height = np.full(S, -1, np.int64), np.full(S, np.nan)
    hand_label = np.full(S, -1, np.int64)          # an arriving walker's goal action, -1: its own label
    kinds = []
    for s in range(S):
        g = min(p.leg[s], G - 1)
        if p.done[s]:
            target[s], label[s] = plan.goal_xz[-1], plan.final_label
            kinds.append("idle")
        elif p.stalled[s]:
            target[s], label[s] = p.halt_xz[s], plan.idle_label
            kinds.append("idle")
        elif p.acting[s] > 0:
            target[s], label[s], height[s] = plan.goal_xz[g], plan.goal_labels[g], plan.seat_y[g]
            kinds.append("act")
        else:
            chosen[s] = j = _farthest_visible(plan, p.ptr[s], g, pos[s])
            target[s], label[s] = plan.subgoals[j], plan.walk_label
            if plan.hand_goal_on_arrival and j == plan.leg_last[g]:
                hand_label[s] = plan.goal_labels[g]                 # -1 for a goal without an action
            kinds.append("walk")
    # The majority; a tie goes to the busier kind (act, walk, idle), never to set order (hash-seeded).
    kind = max((k for k in ("act", "walk", "idle") if k in kinds), key=kinds.count)
    return Targets(kind, target, label, chosen, height, hand_label=np.where(hand_label >= 0, hand_label, label))


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
    model frame `before`. Returns the progress lines (one per goal reached, one per sample that
    stalled)."""
    G = len(plan.goals)
    pel = pelvis_xz(new)                                                                     # (S, n, 2)
    hips = 0.5 * (new[:, :, LEFT_HIP] + new[:, :, RIGHT_HIP])[..., [0, 2]]                  # (S, n, 2)
    lines, active, ptr, acted = [], ~p.finished, p.ptr.copy(), p.acting > 0
    for s in range(len(p.leg)):
        g = min(p.leg[s], G - 1)
        if p.finished[s]:
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
    return lines + _stalls(p, plan, active & ~p.done, ptr, acted, pel[:, -1], before + pel.shape[1] - 1)


def stall_rule(best: np.ndarray, moved: np.ndarray, passed: np.ndarray, dist: np.ndarray, now: int,
               limit: float, margin: float = STALL_MARGIN) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stall rule, over (S,) arrays of the samples still on their way: a sample progressed
    when it `passed` a subgoal or acted (its target moved on), or came `margin` closer to its
    subgoal than its `best` distance since its last progress (`dist` now); one that has not
    progressed for `limit` frames up to frame `now` (since `moved`) has stalled.
    Returns the new (best, moved, stalled); best restarts from the distance now at each progress."""
    progressed = passed | (dist < best - margin)
    best = np.where(progressed, dist, best)
    moved = np.where(progressed, now, moved)
    return best, moved, ~progressed & (now - moved >= limit)


def _stalls(p: Progress, plan: GoalPlan, walking: np.ndarray, ptr: np.ndarray, acted: np.ndarray,
            end: np.ndarray, now: int) -> list[str]:
    """Apply `stall_rule` to the samples `walking` (not finished before this episode nor by it),
    whose subgoal pointer was `ptr` and which `acted` over it, now at `end` (S, 2); stop the ones
    that stalled where they stand. Returns a line per sample stopped."""
    if not math.isfinite(plan.stall_s):
        return []
    dist = np.linalg.norm(end - plan.subgoals[np.minimum(p.ptr, len(plan.subgoals) - 1)], axis=-1)   # (S,)
    best, moved, stalled = stall_rule(p.best, p.moved, acted | (p.ptr != ptr), dist, now,
                                      plan.stall_s * plan.model_fps)
    p.best, p.moved = np.where(walking, best, p.best), np.where(walking, moved, p.moved)
    lines = []
    for s in np.flatnonzero(walking & stalled):
        p.stalled[s], p.halt_xz[s] = True, end[s]
        g = min(p.leg[s], len(plan.goals) - 1)
        far = float(np.linalg.norm(end[s] - plan.goal_xz[g]))
        lines.append(f"sample {s}: stalled at goal {g + 1}/{len(plan.goals)}, {far:.2f} m from it: no progress "
                     f"for {(now - p.moved[s]) / plan.model_fps:.1f} s")
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


def output_arrival_errors(joints: np.ndarray, arrival_frame: np.ndarray, goal_xz: np.ndarray, fps: float,
                          window_s: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Arrival errors measured on the output motion, after the clean-up moved it: joints
    (S, T, J, 3) at `fps`, arrival_frame (S, G) output frame of each arrival (-1: never),
    goal_xz (G, 2). Per arrival, the pelvis's closest approach to the goal within `window_s`
    of the arrival frame, and the hips' midpoint's distance at that frame. Returns (pelvis,
    hips) (S, G) in metres, NaN where never reached."""
    S, G = arrival_frame.shape
    pel_err, hip_err = np.full((S, G), np.nan), np.full((S, G), np.nan)
    pel = joints[:, :, PELVIS][..., [0, 2]]                                                   # (S, T, 2)
    hips = 0.5 * (joints[:, :, LEFT_HIP] + joints[:, :, RIGHT_HIP])[..., [0, 2]]             # (S, T, 2)
    w = int(round(window_s * fps))
    for s, g in zip(*np.nonzero(arrival_frame >= 0)):
        a = min(int(arrival_frame[s, g]), joints.shape[1] - 1)
        lo, hi = max(a - w, 0), a + w + 1
        d = np.linalg.norm(pel[s, lo:hi] - goal_xz[g], axis=-1)                               # (n,)
        f = int(np.argmin(d))
        pel_err[s, g], hip_err[s, g] = d[f], np.linalg.norm(hips[s, lo + f] - goal_xz[g])
    return pel_err, hip_err


def shortfall(p: Progress, plan: GoalPlan, pos: np.ndarray, which: np.ndarray | None = None) -> str:
    """How far each sample in `which` (S,) bool (default: every unfinished one) got, from the
    pelvis positions (S, 2) now."""
    G, parts = len(plan.goals), []
    which = ~p.finished if which is None else which
    for s in range(len(p.leg)):
        if not which[s]:
            continue
        g = min(p.leg[s], G - 1)
        dist = float(np.linalg.norm(pos[s] - plan.goal_xz[g]))
        parts.append(f"sample {s} reached {int((p.arrival_frame[s] >= 0).sum())}/{G} goals, {dist:.2f} m from goal {g + 1}")
    return "; ".join(parts)


def goal_outcomes(p: Progress, G: int) -> np.ndarray:
    """(S, G) str: each goal REACHED (arrived and acted there), else why not: the goal a sample
    stopped at STALLED or cut by the EPISODE_LIMIT (also when its action there was cut), the
    goals after it NOT_ATTEMPTED."""
    out = np.where(p.arrival_frame >= 0, REACHED, NOT_ATTEMPTED).astype("<U16")
    for s in np.flatnonzero(~p.done):
        g = min(int(p.leg[s]), G - 1)
        out[s, g] = STALLED if p.stalled[s] else EPISODE_LIMIT
    return out
