"""The autoregressive episode loop: motions of any length through a scene, towards goals.

One episode samples one model window (L frames at the model rate, e.g. 16 frames at 10 fps)
for all S samples at once:

1. Canonicalise at the first transition frame: the last k frames of the previous episode
   (k = the transition length the checkpoint was trained with) become frames 0..k-1 of the
   new window, expressed in the frame of frame 0 — exactly how training windows are
   canonicalised, so the pinned frames look like training data.
2. Pin those k frames (all channels) and the target's pelvis x, z at the last frame, in
   *normalised* coordinates (stats.normalize on the full vector, then the pelvis channels).
3. Condition on the local occupancy around the target (scene grid plus placed objects),
   yaw-aligned with the window frame, and on per-frame action labels.
4. Sample, denormalise, map back to world, keep frames k..L-1 (the first k are the pinned
   copies of frames we already have), continue from the new last k frames.

Improvements over the reference loop (DESIGN.md §3):
* Look-ahead targets: each episode pins the farthest subgoal that is still within the
  model's reach (taken from the training statistics) and in line of sight on the walkable
  map, instead of one 0.6 m subgoal per 1.6 s window, which forces a slow shuffle. Subgoals
  farther than the reach are clamped (the episode walks towards them and the next continues).
  `lookahead=False` gives the reference behaviour (one episode per subgoal).
* Per-sample progress in a batch: S samples advance through goals independently in one
  batched call per episode; a finished sample idles at its last goal until all are done.
* Interactions: a goal with an action holds the pelvis target there with that action label
  for its duration.
* Stops at the final goal within tolerance, or at `max_episodes` with a warning saying how
  far each sample got.
* The output is resampled to 30 fps with a cubic spline over the whole sequence, so episode
  seams (already continuous because the transition frames are pinned copies) stay smooth.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch
from scipy.interpolate import CubicSpline

from motiongen.diffusion.masks import known_mask
from motiongen.errors import ConfigError
from motiongen.geometry import canonical_frame, invert_rigid, local_to_world, transform_points
from motiongen.sampling.goals import Goal, Route, WalkableMap, check_actions, plan_route
from motiongen.skeleton import LEFT_HIP, PELVIS, RIGHT_HIP


@dataclass
class SamplerSettings:
    sampler: str = "ddim"          # ddpm | ddim
    steps: int = 25                # denoising steps (ddpm: respaced when < the training steps)
    eta: float = 0.0               # DDIM stochasticity
    guidance_scale: float = 1.0    # classifier-free guidance; 1 = conditional pass only


@dataclass
class LoopConfig:
    warmup: int = 2                # episodes standing at the start before walking
    keep_warmup: bool = False      # include the warm-up frames in the output
    transition: int | None = None  # pinned frames k; None = the checkpoint's mask.max_transition
    reach: float | None = None     # max target distance per episode (m); None = from the stats
    reach_fraction: float = 0.7    # reach = this x the farthest pelvis offset seen in training
    lookahead: bool = True         # target the farthest visible subgoal within reach
    tolerance: float = 0.25        # pelvis distance (m) that counts as arriving
    max_episodes: int = 200
    out_fps: float = 30.0
    source_fps: float = 30.0       # rate of the data the model was trained on (before stride)


@dataclass
class Episode:
    kind: str                      # warmup | walk | act | idle (majority over samples)
    start: int                     # index of its first *new* frame in the model-rate output
    transition: int                # frames pinned at the start of the window
    target: np.ndarray             # (S, 2) world pelvis target (after clamping)
    window: np.ndarray             # (S, L, J, 3) world joints of the whole sampled window
    to_world: np.ndarray           # (S, 4, 4) the window's local -> world frame


@dataclass
class Motion:
    """The result of `generate`: world joints at `fps` and everything needed to explain them."""

    joints: np.ndarray             # (S, T, J, 3) float32 world, y-up, metres, at fps
    fps: float
    joint_names: list[str]
    model_joints: np.ndarray       # (S, Tm, J, 3) float32 at the model rate
    model_fps: float
    actions: np.ndarray            # (S, T) int16 action index per output frame, -1 = none
    action_names: list[str]
    episode_starts: np.ndarray     # (E,) int: first output frame of each episode's new frames
    episode_kinds: list[str]
    route: Route
    arrival_frame: np.ndarray      # (S, G) int output frame of arrival at each goal, -1 = never
    arrival_error: np.ndarray      # (S, G) pelvis (x, z) distance to the goal there (m), nan = never
    arrival_error_body: np.ndarray  # (S, G) same for the hips' midpoint (not pinned: the body's own)
    finish_frame: np.ndarray       # (S,) output frame where the sample reached its final goal, -1 = never
    completed: bool                # every sample reached every goal
    wall_time: float               # seconds spent generating
    episodes: list[Episode] = field(default_factory=list, repr=False)

    @property
    def num_samples(self) -> int:
        return self.joints.shape[0]

    @property
    def duration(self) -> float:
        """Seconds of motion per sample."""
        return (self.joints.shape[1] - 1) / self.fps

    @property
    def real_time_factor(self) -> float:
        """Seconds of motion produced (all samples) per second of compute."""
        return self.num_samples * self.duration / max(self.wall_time, 1e-9)


# ---------------------------------------------------------------------------------------


def model_reach(stats, cfg: LoopConfig) -> float:
    """How far (m) an episode may pin its target: reach_fraction x the largest forward pelvis
    offset in the training windows (pelvis z channel max; windows start facing +z)."""
    if cfg.reach is not None:
        return float(cfg.reach)
    forward = float(stats.center[2] + stats.half_range[2])
    return max(0.05, cfg.reach_fraction * forward)


def _scene_spec(window):
    from motiongen.data.scene import LocalGridSpec

    lo, hi = window.grid_lo, window.grid_hi
    return LocalGridSpec(tuple(int(r) for r in window.grid_res), (lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2]))


class _SceneQuery:
    """Local occupancy at episode targets: (S, Hy, Hx, Hz) float32, or None for a model
    without scene conditioning. No scene = an empty floor (all free)."""

    def __init__(self, loaded, grid, objects, device):
        from motiongen.data.scene import DynamicObjects, GridBank, TorchOccupancy

        self.enabled = loaded.window.scene and getattr(loaded.model, "scene_encoder", None) is not None
        self.spec = _scene_spec(loaded.window)
        self.outside = bool(loaded.window.outside_occupied)
        self.device = device
        self.bank = TorchOccupancy(grid, device) if (grid is not None and self.enabled) else None
        self.objects = None
        if objects and self.enabled and loaded.window.objects:
            bank = GridBank([g for g, _ in objects], device)
            poses = torch.as_tensor(np.stack([np.asarray(p, np.float64) for _, p in objects]), dtype=torch.float32)
            self._obj = (bank, poses)                                                        # poses (K, 4, 4)
            self.objects = DynamicObjects
        self._ids = None

    def __call__(self, at_goal: np.ndarray) -> torch.Tensor | None:
        """at_goal (S, 4, 4) local -> world frames centred on the targets."""
        if not self.enabled:
            return None
        S = at_goal.shape[0]
        if self.bank is None and self.objects is None:
            return torch.zeros((S, *self.spec.out_shape), dtype=torch.float32, device=self.device)
        from motiongen.data.scene import local_occupancy

        T = torch.as_tensor(at_goal, dtype=torch.float32, device=self.device)
        objs = None
        if self.objects is not None:
            bank, poses = self._obj
            K = poses.shape[0]
            ids = torch.arange(K, device=self.device)[None].expand(S, K)                   # (S, K)
            objs = self.objects(bank, ids, poses.to(self.device)[None].expand(S, K, 4, 4))
        if self.bank is None:
            # Objects on an empty floor: an all-free 1-voxel grid far away plays the scene.
            from motiongen.data.occupancy import OccupancyGrid
            from motiongen.data.scene import TorchOccupancy

            self.bank = TorchOccupancy(OccupancyGrid.from_dense(np.zeros((1, 1, 1), bool), [1e6, 1e6, 1e6], 1.0),
                                       self.device)
            self.outside = False
        occ = local_occupancy(self.bank, T, self.spec, objects=objs, outside=self.outside)  # (S, Hy, Hx, Hz)
        return occ.float()


def _label(names: Sequence[str], name: str | None) -> int:
    return names.index(name) if name is not None and name in names else -1


def generate(loaded, scene=None, start=(0.0, 0.0), goals: Sequence[Goal] = (), *, route: Route | None = None,
             walkable: WalkableMap | None = None, path: str = "astar", subgoal_spacing: float = 0.6,
             body_radius: float = 0.25, start_yaw: float | None = None,
             objects: Sequence[tuple] = (), sampler: SamplerSettings = SamplerSettings(),
             num_samples: int = 1, generator: torch.Generator | None = None,
             loop: LoopConfig = LoopConfig(), log=None) -> Motion:
    """Generate S = num_samples motions from `start` through `goals` in `scene`.

    loaded: a `LoadedModel` (training.builders.load_model). scene: an OccupancyGrid or None
    (empty floor, no bounds). start (2,) world (x, z); goals: `Goal`s (actions from
    loaded.action_names). route: a precomputed `plan_route` result (else planned here with
    `path` / `subgoal_spacing` on `walkable`, built from `scene` with `body_radius` if None).
    objects: [(object OccupancyGrid, pose (4, 4) object -> world)] placed in the scene.
    generator: torch.Generator for the diffusion noise (reproducible runs).
    log: optional callable(str) for progress lines.
    Raises ConfigError for bad goals/actions/paths; returns a `Motion`.
    """
    t_start = time.perf_counter()
    names = list(loaded.action_names)
    if route is None:
        goals = list(goals)
        check_actions(goals, names)
        if walkable is None and scene is not None and path == "astar":
            from motiongen.sampling.goals import walkable_map

            walkable = walkable_map(scene, body_radius)
        route = plan_route(start, goals, walkable, path, subgoal_spacing)
    goals = route.goals
    if num_samples < 1:
        raise ConfigError(f"num_samples must be >= 1, got {num_samples}")

    model, diffusion, stats, win = loaded.model, loaded.diffusion, loaded.stats, loaded.window
    device = next(model.parameters()).device
    J = loaded.joint_set.num_joints
    L, D, S, G = win.length, J * 3, num_samples, len(goals)
    k = loop.transition if loop.transition is not None else int(loaded.mask.max_transition)
    if not 1 <= k < L:
        raise ConfigError(f"transition frames must be in 1..{L - 1} (checkpoint trained with up to "
                          f"{loaded.mask.max_transition}); got {k}")
    if k > loaded.mask.max_transition:
        warnings.warn(f"pinning {k} transition frames; the model was trained with at most {loaded.mask.max_transition}")
    new = L - k                                                                              # new frames per episode
    model_fps = loop.source_fps / win.stride
    reach = model_reach(stats, loop)
    A = len(names)
    walk_label, idle_label = _label(names, "walk"), _label(names, "stand")
    if idle_label < 0:
        idle_label = walk_label
    query = _SceneQuery(loaded, scene, objects, device)
    sub, sub_leg = route.subgoals, route.subgoal_leg
    leg_last = np.array([np.flatnonzero(sub_leg == g).max() for g in range(G)])             # (G,)
    goal_xz = np.stack([g.xz for g in goals])                                                # (G, 2)
    act_eps = [int(math.ceil(g.duration * model_fps / new)) if g.interacts and g.duration > 0 else 0 for g in goals]

    def log_(msg):
        if log is not None:
            log(msg)

    # Per-sample progress.
    leg = np.zeros(S, np.int64)            # goal being approached (or acted at)
    ptr = np.zeros(S, np.int64)            # first subgoal not yet reached
    acting = np.zeros(S, np.int64)         # action episodes left at goal `leg`
    done = np.zeros(S, bool)
    arrival_m = np.full((S, G), -1, np.int64)
    arrival_err = np.full((S, G), np.nan)
    arrival_body = np.full((S, G), np.nan)
    finish_m = np.full(S, -1, np.int64)

    frames: list[np.ndarray] = []          # model-rate world frames, each (S, n, J, 3) float64
    labels: list[np.ndarray] = []          # (S, n) int action index per frame
    n_frames = 0
    episodes: list[Episode] = []
    tail = None                            # (S, k, J, 3) world: the last k frames so far
    tail_labels = np.full((S, k), walk_label, np.int64)

    if start_yaw is None:
        d = sub[0] - route.start
        start_yaw = math.atan2(d[0], d[1]) if np.linalg.norm(d) > 1e-6 else 0.0

    # Goal vector in normalised units: stats.normalize acts per channel, so normalising a full
    # vector that holds only the pelvis x, z gives the right values in those two channels.
    def pin_goal_channels(local_xz: np.ndarray) -> np.ndarray:                               # (S, 2) -> (S, 2)
        v = np.zeros((local_xz.shape[0], D), np.float32)
        v[:, 3 * PELVIS + 0], v[:, 3 * PELVIS + 2] = local_xz[:, 0], local_xz[:, 1]
        n = stats.normalize(v)
        return n[:, [3 * PELVIS + 0, 3 * PELVIS + 2]]

    def run_episode(kind: str, target: np.ndarray, label: np.ndarray, first: bool) -> None:
        """Sample one window for all samples towards world targets (S, 2) with per-sample labels (S,)."""
        nonlocal tail, tail_labels, n_frames
        if first:
            # No history: the window frame is the start pose; nothing pinned but the target.
            Tw = np.repeat(local_to_world(np.float64(start_yaw), np.asarray(route.start, np.float64))[None], S, 0)
            kk = 0
        else:
            Tw = canonical_frame(tail[:, 0])                                                 # (S, 4, 4)
            kk = k
        inv = invert_rigid(Tw)                                                               # (S, 4, 4) world -> local
        tgt3 = np.stack([target[:, 0], np.zeros(S), target[:, 1]], -1)                      # (S, 3)
        local_t = transform_points(inv, tgt3[:, None])[:, 0][:, [0, 2]]                      # (S, 2)
        dist = np.linalg.norm(local_t, axis=-1, keepdims=True)
        local_t = np.where(dist > reach, local_t * (reach / np.maximum(dist, 1e-9)), local_t)  # split far targets
        known = np.zeros((S, L, D), np.float32)
        if kk:
            local_tail = transform_points(inv[:, None], tail)                                # (S, k, J, 3)
            known[:, :kk] = stats.normalize(local_tail.reshape(S, kk, D).astype(np.float32))
        known[:, -1, [3 * PELVIS + 0, 3 * PELVIS + 2]] = pin_goal_channels(local_t)
        mask = known_mask(S, L, J, transition=kk, goal_xz=True, goal_joint=PELVIS)         # (S, L, D)

        # Scene around the target, in the window's orientation, floor at y = 0.
        at_goal = Tw.copy()
        at_goal[:, :3, 3] = transform_points(Tw, np.stack([local_t[:, 0], np.zeros(S), local_t[:, 1]], -1)[:, None])[:, 0]
        at_goal[:, 1, 3] = 0.0
        lab = np.repeat(label[:, None], L, 1)                                                # (S, L)
        if kk:
            lab[:, :kk] = tail_labels
        act = np.zeros((S, L, A), np.float32)
        s_idx, f_idx = np.nonzero(lab >= 0)
        act[s_idx, f_idx, lab[s_idx, f_idx]] = 1.0
        from motiongen.models import Condition

        cond = Condition(scene=query(at_goal), actions=torch.from_numpy(act).to(device) if A else None)
        x0 = diffusion.sample(model, (S, L, D), cond, known=torch.from_numpy(known).to(device),
                              known_mask=mask.to(device), sampler=sampler.sampler, steps=sampler.steps,
                              eta=sampler.eta, guidance_scale=sampler.guidance_scale, generator=generator)
        local = stats.denormalize(x0.float().cpu().numpy()).astype(np.float64).reshape(S, L, J, 3)
        world = transform_points(Tw[:, None], local)                                         # (S, L, J, 3)
        episodes.append(Episode(kind, n_frames, kk, target.copy(), world.astype(np.float32), Tw))
        if kk:
            # The pinned frames come back as the previous frames up to float32 rounding of the
            # normalised values; keep the exact originals so seams carry no rounding jitter.
            world[:, :kk] = tail
        keep = world[:, kk:]
        frames.append(keep)
        labels.append(lab[:, kk:])
        n_frames += keep.shape[1]
        tail, tail_labels = world[:, L - k:], lab[:, L - k:]

    def pelvis_xz(x):                                                                        # (..., J, 3) -> (..., 2)
        return x[..., PELVIS, :][..., [0, 2]]

    # -- warm-up: stand at the start, settle into a natural pose ------------------------
    start_t = np.repeat(np.asarray(route.start, np.float64)[None], S, 0)
    warm_label = np.full(S, idle_label, np.int64)
    for w in range(max(1, loop.warmup)):
        run_episode("warmup", start_t, warm_label, first=(w == 0))
    if not loop.keep_warmup:
        # Output starts with the last k warm-up frames: the history the first walk episode pins.
        frames, labels = [tail.copy()], [tail_labels.copy()]
        n_frames = k
        episodes[-1].start = 0
    first_kept = len(episodes) - 1 if not loop.keep_warmup else 0

    # -- goal episodes ------------------------------------------------------------------
    n_ep = 0
    while not done.all() and n_ep < loop.max_episodes:
        pos = pelvis_xz(tail[:, -1])                                                         # (S, 2)
        target = np.empty((S, 2))
        label = np.empty(S, np.int64)
        kinds = []
        chosen = np.full(S, -1, np.int64)
        for s in range(S):
            g = min(leg[s], G - 1)
            if done[s]:
                target[s] = goal_xz[-1]
                label[s] = _label(names, goals[-1].action) if goals[-1].interacts else idle_label
                kinds.append("idle")
            elif acting[s] > 0:
                target[s] = goal_xz[g]
                label[s] = _label(names, goals[g].action)
                kinds.append("act")
            else:
                j = ptr[s]
                if loop.lookahead:
                    while (j + 1 <= leg_last[g] and np.linalg.norm(sub[j + 1] - pos[s]) <= reach
                           and (walkable is None or walkable.segment_free(pos[s], sub[j + 1]))):
                        j += 1
                chosen[s] = j
                target[s] = sub[j]
                label[s] = walk_label
                kinds.append("walk")
        kind = max(set(kinds), key=kinds.count)
        before = n_frames
        run_episode(kind, target, label, first=False)
        n_ep += 1
        pel = pelvis_xz(frames[-1])                                                          # (S, new, 2)
        hips = 0.5 * (frames[-1][:, :, LEFT_HIP] + frames[-1][:, :, RIGHT_HIP])[..., [0, 2]]  # (S, new, 2)
        for s in range(S):
            g = min(leg[s], G - 1)
            if done[s]:
                continue
            if acting[s] > 0:
                acting[s] -= 1
            else:
                j = chosen[s]
                if np.linalg.norm(pel[s, -1] - sub[j]) > loop.tolerance:
                    ptr[s] = j                                                               # not there yet: retarget
                    continue
                ptr[s] = j + 1
                if j != leg_last[g]:
                    continue
                # Arrived at goal g: record the closest approach within this episode.
                d = np.linalg.norm(pel[s] - goal_xz[g], axis=-1)                            # (new,)
                f = int(np.argmin(d))
                arrival_m[s, g] = before + f
                arrival_err[s, g] = d[f]
                arrival_body[s, g] = np.linalg.norm(hips[s, f] - goal_xz[g])
                acting[s] = act_eps[g]
                log_(f"sample {s}: goal {g + 1}/{G} reached after {n_ep} episodes ({d[f]:.2f} m)")
            if acting[s] == 0:
                if leg[s] >= G - 1:
                    done[s] = True
                    finish_m[s] = before + pel.shape[1] - 1
                else:
                    leg[s] += 1

    completed = bool(done.all())
    if not completed:
        parts = []
        for s in range(S):
            if done[s]:
                continue
            g = min(leg[s], G - 1)
            dist = float(np.linalg.norm(pelvis_xz(tail[s, -1]) - goal_xz[g]))
            parts.append(f"sample {s} reached {int((arrival_m[s] >= 0).sum())}/{G} goals, {dist:.2f} m from goal {g + 1}")
        warnings.warn(f"stopped after max_episodes={loop.max_episodes} episodes: " + "; ".join(parts), stacklevel=2)

    # -- assemble and resample to the output rate --------------------------------------
    model_joints = np.concatenate(frames, 1)                                                 # (S, Tm, J, 3)
    model_labels = np.concatenate(labels, 1)                                                 # (S, Tm)
    Tm = model_joints.shape[1]
    ratio = loop.out_fps / model_fps
    t_model = np.arange(Tm) / model_fps
    T = int(math.floor((Tm - 1) * ratio + 1e-6)) + 1
    t_out = np.arange(T) / loop.out_fps
    if Tm >= 2 and abs(ratio - 1) > 1e-9:
        out = CubicSpline(t_model, model_joints, axis=1)(t_out)                              # (S, T, J, 3)
    else:
        out = model_joints.copy()
    near = np.minimum(np.round(t_out * model_fps).astype(np.int64), Tm - 1)                 # (T,) nearest model frame
    to_out = lambda m: np.where(m >= 0, np.round(m * ratio).astype(np.int64), -1)            # noqa: E731
    kept = episodes[first_kept:]
    starts = np.array([to_out(np.int64(e.start)) for e in kept], np.int64)
    return Motion(
        joints=out.astype(np.float32), fps=float(loop.out_fps), joint_names=list(loaded.joint_set.names),
        model_joints=model_joints.astype(np.float32), model_fps=float(model_fps),
        actions=model_labels[:, near].astype(np.int16), action_names=names,
        episode_starts=starts, episode_kinds=[e.kind for e in kept], route=route,
        arrival_frame=to_out(arrival_m), arrival_error=arrival_err, arrival_error_body=arrival_body,
        finish_frame=to_out(finish_m), completed=completed, wall_time=time.perf_counter() - t_start,
        episodes=episodes)
