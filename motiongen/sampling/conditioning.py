"""What the network is told for one episode: the window's frame, the pinned frames and goal
(normalised), which entries are known, the local occupancy around the target and the
per-frame action labels.

The window is canonicalised at its first frame (the previous episode's first pinned frame), as
training windows are, so the pinned frames look like training data. The first episode has no
history: its frame is the start pose and nothing but the target is given.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from motiongen.diffusion.masks import known_mask
from motiongen.geometry import canonical_frame, invert_rigid, transform_points
from motiongen.models import Condition
from motiongen.sampling.episode import LoopSpec, Tail
from motiongen.sampling.interactions import HandReach, hand_reach
from motiongen.sampling.progress import Targets
from motiongen.sampling.scene_query import SceneQuery
from motiongen.skeleton import PELVIS

GOAL_XZ = [3 * PELVIS + 0, 3 * PELVIS + 2]          # the pelvis x, z channels
GOAL_Y = 3 * PELVIS + 1


@dataclass
class NetworkInputs:
    """One episode's inputs to the denoiser, for all S samples."""

    pinned: int                    # k frames pinned at the start (0 for the first episode)
    to_world: np.ndarray           # (S, 4, 4) the window's local -> world frame
    known: np.ndarray              # (S, L, D) float32 normalised values of the known entries
    mask: torch.Tensor             # (S, L, D) bool known entries, on the network's device
    labels: np.ndarray             # (S, L) int action index per frame
    cond: Condition                # scene (S, Hy, Hx, Hz) and actions (S, L, A)


def condition_episode(spec: LoopSpec, loaded, query: SceneQuery, tail: Tail | None, t: Targets) -> NetworkInputs:
    """The inputs that sample one window for all samples towards the world targets `t`."""
    S, L, D, A = spec.samples, spec.length, spec.channels, len(loaded.action_names)
    pinned = 0 if tail is None else spec.transition
    to_world = (np.repeat(spec.start_frame[None], S, 0) if tail is None
                else canonical_frame(tail.joints[:, 0]))                                      # (S, 4, 4)
    inv = invert_rigid(to_world)                                                             # world -> local
    local_t = local_target(inv, t.target, spec.reach)
    known, give_y = known_values(loaded.stats, loaded.layout, inv, tail, local_t, t.height, L)
    hand = t.hand if t.hand is not None else np.full(S, -1, np.int64)                        # (S,)
    hand_values(known, loaded.stats, inv, hand, t.hand_point)
    mask = known_mask(S, L, loaded.joint_set.num_joints, transition=pinned, goal_xz=True,
                      goal_y=torch.from_numpy(give_y), hand=torch.from_numpy(hand >= 0),
                      hand_joint=torch.from_numpy(np.maximum(hand, 0)), goal_joint=PELVIS, channels=D)   # (S, L, D)
    labels = np.repeat(t.label[:, None], L, 1)                                               # (S, L)
    if pinned:
        labels[:, :pinned] = tail.labels
    cond = Condition(scene=query(target_frame(to_world, local_t)),
                     actions=torch.from_numpy(one_hot(labels, A)).to(spec.device) if A else None)
    if spec.facing_goal:
        # only while acting unless asked: facing the object as it walks onto the spot, the demo
        # network turned early and stopped 0.2 m off it (docs/results.md, "A facing goal as an angle")
        asked = hand if spec.facing_on_arrival else np.where(t.hand_labels() == t.label, hand, -1)   # (S,)
        facing, given = facing_values(inv, local_t, asked, t.hand_point)
        cond = replace(cond, facing=torch.from_numpy(facing).to(spec.device),
                       facing_given=torch.from_numpy(given).to(spec.device))
    return NetworkInputs(pinned, to_world, known, mask.to(spec.device), labels, cond)


def local_target(inv: np.ndarray, target: np.ndarray, reach: float) -> np.ndarray:
    """World targets (S, 2) -> window-frame (S, 2) through inv (S, 4, 4) world -> local; a
    target farther than `reach` is clamped onto it (the episode walks towards it, the next
    one continues)."""
    S = target.shape[0]
    tgt3 = np.stack([target[:, 0], np.zeros(S), target[:, 1]], -1)                          # (S, 3)
    local_t = transform_points(inv, tgt3[:, None])[:, 0][:, [0, 2]]                          # (S, 2)
    dist = np.linalg.norm(local_t, axis=-1, keepdims=True)
    return np.where(dist > reach, local_t * (reach / np.maximum(dist, 1e-9)), local_t)


def known_values(stats, layout, inv: np.ndarray, tail: Tail | None, local_t: np.ndarray,
                 height: np.ndarray | None, L: int) -> tuple[np.ndarray, np.ndarray]:
    """(known (S, L, D) float32 normalised, give_y (S,) bool): the tail's frames (every channel,
    stance too) in the window frame, the target's pelvis x, z at the last frame and, where
    `height` (S,) is finite, its pelvis y (floor at y = 0)."""
    S, D = local_t.shape[0], layout.channels
    known = np.zeros((S, L, D), np.float32)
    if tail is not None:
        k = tail.joints.shape[1]                                                             # pinned frames
        local_tail = transform_points(inv[:, None], tail.joints)                             # (S, k, J, 3)
        known[:, :k] = stats.normalize(layout.encode(local_tail, tail.stance).astype(np.float32))
    known[:, -1, GOAL_XZ] = goal_channels(stats, D, local_t)
    give_y = np.isfinite(height) if height is not None else np.zeros(S, bool)
    if give_y.any():
        v = np.zeros((S, D), np.float32)
        v[:, GOAL_Y] = np.where(give_y, height, 0.0)
        known[:, -1, GOAL_Y] = stats.normalize(v)[:, GOAL_Y]
    return known, give_y


def hand_values(known: np.ndarray, stats, inv: np.ndarray, hand: np.ndarray, point: np.ndarray) -> None:
    """Write each sample's wrist goal (joint hand (S,), -1 none; world point (S, 3)) into the
    last frame of known (S, L, D) normalised, in the window frame (absolute layout: joint j at
    channels 3j..3j+2)."""
    D = known.shape[-1]
    for s in np.flatnonzero(hand >= 0):
        c = slice(3 * hand[s], 3 * hand[s] + 3)
        v = np.zeros(D, np.float32)
        v[c] = transform_points(inv[s], point[s][None])[0]
        known[s, -1, c] = stats.normalize(v[None])[0, c]


def facing_values(inv: np.ndarray, local_t: np.ndarray, hand: np.ndarray, point: np.ndarray | None,
                  min_dist: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """(facing (S, 2) float32 (sin, cos) of the window-frame yaw that faces each sample's wrist
    goal (world point (S, 3)) from its pelvis goal local_t (S, 2), given (S,) bool): given where
    a hand goal is (hand (S,) >= 0) and lies at least `min_dist` m from the pelvis goal across
    the floor (nearer, the way to it says nothing)."""
    S = local_t.shape[0]
    facing, given = np.zeros((S, 2), np.float32), np.zeros(S, bool)
    for s in np.flatnonzero(hand >= 0):
        d = transform_points(inv[s], point[s][None])[0][[0, 2]] - local_t[s]                    # (2,) x, z
        n = float(np.linalg.norm(d))
        if n >= min_dist:
            facing[s], given[s] = d / n, True          # yaw θ faces (sin θ, cos θ) in x, z
    return facing, given


def goal_channels(stats, D: int, local_xz: np.ndarray) -> np.ndarray:
    """Window-frame pelvis x, z (S, 2) in normalised units (S, 2): stats.normalize acts per
    channel, so normalising a full vector that holds only the pelvis x, z gives the right
    values in those two channels."""
    v = np.zeros((local_xz.shape[0], D), np.float32)
    v[:, GOAL_XZ[0]], v[:, GOAL_XZ[1]] = local_xz[:, 0], local_xz[:, 1]
    return stats.normalize(v)[:, GOAL_XZ]


def target_frame(to_world: np.ndarray, local_t: np.ndarray) -> np.ndarray:
    """(S, 4, 4) local -> world frames at the targets, in the window's orientation, floor at
    y = 0: where the scene is queried."""
    S = local_t.shape[0]
    at_goal = to_world.copy()
    at_goal[:, :3, 3] = transform_points(to_world, np.stack([local_t[:, 0], np.zeros(S), local_t[:, 1]], -1)[:, None])[:, 0]
    at_goal[:, 1, 3] = 0.0
    return at_goal


def one_hot(labels: np.ndarray, A: int) -> np.ndarray:
    """(S, L) action indices (-1 = none) -> (S, L, A) float32 one-hot."""
    act = np.zeros((*labels.shape, A), np.float32)
    s_idx, f_idx = np.nonzero(labels >= 0)
    act[s_idx, f_idx, labels[s_idx, f_idx]] = 1.0
    return act


def loop_hand_reach(loaded, objects, scene, loop) -> HandReach | None:
    """The in-loop hand goal of a call (`LoopConfig.hand_goal`): only for checkpoints trained to
    take one (mask.p_hand or mask.p_hand_action > 0) on absolute joints, where the hand channels are the wrist's
    position in the window frame; with objects placed. The wrists it may give a goal for are
    the ones it was trained on."""
    m = loaded.mask
    if not loop.hand_goal or not objects or not m.hand_goals or loaded.layout.representation != "absolute":
        return None
    return hand_reach(objects, scene, list(loaded.action_names), loop.hand_goal, m.goal_hands)
