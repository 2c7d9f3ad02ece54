"""The autoregressive episode loop: motions of any length through a scene, towards goals.

One episode samples one model window (L frames at the model rate, e.g. 16 frames at 10 fps)
for all S samples at once:

1. Canonicalise at the first transition frame: the last k frames of the previous episode
   (k = the transition length the checkpoint was trained with) become frames 0..k-1 of the
   new window, expressed in the frame of frame 0 — exactly how training windows are
   canonicalised, so the pinned frames look like training data.
2. Pin those k frames (every channel: pose and stance) and give the target's pelvis x, z at the
   last frame, in *normalised* coordinates. Transitions are written into the result; the goal
   only conditions the model, which predicts the pelvis there like everything else
   (`mask.predict_goal`; older checkpoints pin it), so arrival distances measure the model.
3. Condition on the local occupancy around the target (scene grid plus placed objects),
   yaw-aligned with the window frame, and on per-frame action labels.
4. Sample, denormalise, decode (`motiongen.data.representation`), map back to world, and
   project onto the motion's one body (`motiongen.body.solve`; its shape is fitted to the first
   window): bone lengths are the body's whatever the network predicted, and the next episode
   continues from a rigid body. Keep frames k..L-1, continue from the new last k frames.

Improvements over the reference loop (DESIGN.md §3):
* Look-ahead targets: each episode targets the farthest subgoal that is still within the
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
* Output: the projected frames are resampled to 30 fps (cubic spline) and solved once more on
  the body over the whole motion, with every foot joint the model predicts planted held in
  place (foot locking, `loop.foot_lock`). The network's own joints stay available
  (`Motion.joints_raw`) so that what the clean-up did can be measured.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from typing import Sequence

import numpy as np
import torch

from motiongen.diffusion.masks import known_mask, replace_mask
from motiongen.diffusion.samplers import sample
from motiongen.errors import ConfigError
from motiongen.geometry import canonical_frame, invert_rigid, local_to_world, transform_points
from motiongen.routing import WalkableMap
from motiongen.sampling.assemble import blend_seam, solve_smoothness_for_rate
from motiongen.sampling.goals import Goal, Route, check_actions, plan_route
from motiongen.sampling.settings import Episode, LoopConfig, Motion, SamplerSettings
from motiongen.sampling.interactions import hand_targets, merge_targets, seat_height, seat_shift
from motiongen.sampling.scene_query import SceneQuery
from motiongen.skeleton import LEFT_HIP, PELVIS, RIGHT_HIP


# ---------------------------------------------------------------------------------------


def model_reach(stats, cfg: LoopConfig) -> float:
    """How far (m) an episode may pin its target: reach_fraction x the largest forward pelvis
    offset in the training windows (pelvis z channel max; windows start facing +z)."""
    if cfg.reach is not None:
        return float(cfg.reach)
    forward = float(stats.center[2] + stats.half_range[2])
    return max(0.05, cfg.reach_fraction * forward)


def _label(names: Sequence[str], name: str | None) -> int:
    return names.index(name) if name is not None and name in names else -1


def generate(loaded, scene=None, start=(0.0, 0.0), goals: Sequence[Goal] = (), *, route: Route | None = None,
             walkable: WalkableMap | None = None, path: str = "astar", subgoal_spacing: float = 0.6,
             body_radius: float = 0.25, start_yaw: float | None = None,
             objects: Sequence[tuple] = (), sampler: SamplerSettings = SamplerSettings(),
             num_samples: int = 1, generator: torch.Generator | None = None,
             loop: LoopConfig = LoopConfig(), log=None, body_model=None) -> Motion:
    """Generate S = num_samples motions from `start` through `goals` in `scene`.

    loaded: a `LoadedModel` (loading.build.load_model). scene: an OccupancyGrid or None
    (empty floor, no bounds). start (2,) world (x, z); goals: `Goal`s (actions from
    loaded.action_names). route: a precomputed `plan_route` result (else planned here with
    `path` / `subgoal_spacing` on `walkable`, built from `scene` with `body_radius` if None).
    objects: [(object OccupancyGrid, pose (4, 4) object -> world)] placed in the scene.
    generator: torch.Generator for the diffusion noise (reproducible runs).
    body_model: the `BodyModel` of the motion's body (default `load_body_model()`: the user's
    SMPL-X file from $MOTIONGEN_SMPLX_MODEL, else the procedural one); used when loop.project.
    log: optional callable(str) for progress lines.
    Raises ConfigError for bad goals/actions/paths; returns a `Motion`.
    """
    t_start = time.perf_counter()
    names = list(loaded.action_names)
    if route is None:
        goals = list(goals)
        check_actions(goals, names)
        if walkable is None and scene is not None and path == "astar":
            from motiongen.routing import walkable_map

            walkable = walkable_map(scene, body_radius)
        route = plan_route(start, goals, walkable, path, subgoal_spacing)
    goals = route.goals
    if num_samples < 1:
        raise ConfigError(f"num_samples must be >= 1, got {num_samples}")

    model, diffusion, stats, win = loaded.model, loaded.diffusion, loaded.stats, loaded.window
    device = next(model.parameters()).device
    layout = loaded.layout
    J, C = loaded.joint_set.num_joints, layout.num_contacts
    L, D, S, G = win.length, layout.channels, num_samples, len(goals)
    k = loop.transition if loop.transition is not None else int(loaded.mask.max_transition)
    if not 1 <= k < L:
        raise ConfigError(f"transition frames must be in 1..{L - 1} (checkpoint trained with up to "
                          f"{loaded.mask.max_transition}); got {k}")
    if k > loaded.mask.max_transition:
        warnings.warn(f"pinning {k} transition frames; the model was trained with at most {loaded.mask.max_transition}")
    new = L - k                                                                              # new frames per episode
    source_fps = float(loop.source_fps if loop.source_fps is not None else loaded.fps)
    model_fps = source_fps / win.stride
    blend_s = LoopConfig.seam_blend if loop.seam_blend is None else float(loop.seam_blend)
    predict_goal = loaded.predict_goal and not loop.pin_goal
    body = None                            # MotionBody, fitted to the first window
    if loop.project and body_model is None:
        from motiongen.body.model import load_body_model

        body_model = load_body_model()
    reach = model_reach(stats, loop)
    A = len(names)
    walk_label, idle_label = _label(names, "walk"), _label(names, "stand")
    if idle_label < 0:
        idle_label = walk_label
    query = SceneQuery(loaded, scene, objects, device)
    sub, sub_leg = route.subgoals, route.subgoal_leg
    leg_last = np.array([np.flatnonzero(sub_leg == g).max() for g in range(G)])             # (G,)
    goal_xz = np.stack([g.xz for g in goals])                                                # (G, 2)
    act_eps = [int(math.ceil(g.duration * model_fps / new)) if g.interacts and g.duration > 0 else 0 for g in goals]
    # Pelvis height while acting on a seat or bed (NaN: the model decides).
    seat_y = np.array([seat_height(scene, g.xz) + loop.seat_offset
                       if scene is not None and g.action in loop.seat_actions and loaded.mask.p_goal_y > 0
                       else np.nan for g in goals])

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
    raws: list[np.ndarray] = []            # the same frames as the network predicted them
    stances: list[np.ndarray] = []         # (S, n, C) bool predicted planted flags
    rots: list[torch.Tensor] = []          # (S, n, 22, 3, 3) local rotations on the body
    labels: list[np.ndarray] = []          # (S, n) int action index per frame
    n_frames = 0
    episodes: list[Episode] = []
    tail = None                            # (S, k, J, 3) world: the last k frames so far
    tail_stance = np.zeros((S, k, C), bool)
    tail_rot = None                        # (S, k, 22, 3, 3)
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

    def run_episode(kind: str, target: np.ndarray, label: np.ndarray, first: bool,
                    height: np.ndarray | None = None) -> None:
        """Sample one window for all samples towards world targets (S, 2) with per-sample labels
        (S,) and, where finite, pelvis heights (S,) at the target."""
        nonlocal tail, tail_stance, tail_rot, tail_labels, n_frames, body
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
            known[:, :kk] = stats.normalize(layout.encode(local_tail, tail_stance).astype(np.float32))
        known[:, -1, [3 * PELVIS + 0, 3 * PELVIS + 2]] = pin_goal_channels(local_t)
        give_y = np.isfinite(height) if height is not None else np.zeros(S, bool)
        if give_y.any():
            v = np.zeros((S, D), np.float32)
            v[:, 3 * PELVIS + 1] = np.where(give_y, height, 0.0)                            # floor at y = 0
            known[:, -1, 3 * PELVIS + 1] = stats.normalize(v)[:, 3 * PELVIS + 1]
        mask = known_mask(S, L, J, transition=kk, goal_xz=True, goal_y=torch.from_numpy(give_y),
                          goal_joint=PELVIS, channels=D)                                     # (S, L, D)

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
        mask = mask.to(device)
        x0 = sample(diffusion, model, (S, L, D), cond, known=torch.from_numpy(known).to(device),
                              known_mask=mask, replace_mask=replace_mask(mask, predict_goal),
                              sampler=sampler.sampler, steps=sampler.steps, eta=sampler.eta,
                              guidance_scale=sampler.guidance_scale, generator=generator)
        local, stance = layout.decode(stats.denormalize(x0.float().cpu().numpy()).astype(np.float64))
        raw = transform_points(Tw[:, None], local)                                           # (S, L, J, 3) world
        # the network's joints stay in `raw`; the clean-up starts with the seam (a second
        # difference, so blending in the world frame equals blending in the window's)
        world = blend_seam(raw, kk, round(blend_s * model_fps))
        rot = None
        if loop.project:
            if body is None:
                from motiongen.body.solve import MotionBody

                body = MotionBody.estimate(body_model, loaded.joint_set, raw)
            world, rot, _ = body.project(world, None if tail_rot is None else tail_rot[:, -1])
        if kk:
            # The pinned frames come back as the previous frames up to float32 rounding of the
            # normalised values; keep the exact originals so seams carry no rounding jitter.
            world = world.copy()
            world[:, :kk], stance[:, :kk] = tail, tail_stance
            if rot is not None:
                rot[:, :kk] = tail_rot
        episodes.append(Episode(kind, n_frames, kk, target.copy(), world.astype(np.float32), Tw,
                                raw.astype(np.float32)))
        frames.append(world[:, kk:])
        raws.append(raw[:, kk:])
        stances.append(stance[:, kk:])
        if rot is not None:
            rots.append(rot[:, kk:])
        labels.append(lab[:, kk:])
        n_frames += L - kk
        tail, tail_stance, tail_labels = world[:, L - k:], stance[:, L - k:], lab[:, L - k:]
        tail_rot = None if rot is None else rot[:, L - k:]

    def pelvis_xz(x):                                                                        # (..., J, 3) -> (..., 2)
        return x[..., PELVIS, :][..., [0, 2]]

    # -- warm-up: stand at the start, settle into a natural pose ------------------------
    start_t = np.repeat(np.asarray(route.start, np.float64)[None], S, 0)
    warm_label = np.full(S, idle_label, np.int64)
    for w in range(max(1, loop.warmup)):
        run_episode("warmup", start_t, warm_label, first=(w == 0))
    if not loop.keep_warmup:
        # Output starts with the last k warm-up frames: the history the first walk episode pins.
        frames, raws, labels = [tail.copy()], [raws[-1][:, -k:].copy()], [tail_labels.copy()]
        stances, rots = [tail_stance.copy()], ([tail_rot.clone()] if tail_rot is not None else [])
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
        height = np.full(S, np.nan)
        for s in range(S):
            g = min(leg[s], G - 1)
            if done[s]:
                target[s] = goal_xz[-1]
                label[s] = _label(names, goals[-1].action) if goals[-1].interacts else idle_label
                kinds.append("idle")
            elif acting[s] > 0:
                target[s] = goal_xz[g]
                label[s] = _label(names, goals[g].action)
                height[s] = seat_y[g]
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
        run_episode(kind, target, label, first=False, height=height)
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

    # -- assemble, resample to the output rate, solve on the body -------------------------
    from motiongen.sampling.assemble import output_times, planted_at_output, resample, solve_bodies

    model_joints = np.concatenate(frames, 1)                                                 # (S, Tm, J, 3)
    model_labels = np.concatenate(labels, 1)                                                 # (S, Tm)
    Tm = model_joints.shape[1]
    ratio = loop.out_fps / model_fps
    _, near = output_times(Tm, model_fps, loop.out_fps)                                      # (T,) nearest model frame
    out = resample(model_joints, model_fps, loop.out_fps)                                     # (S, T, J, 3)
    raw_out = resample(np.concatenate(raws, 1), model_fps, loop.out_fps)
    planted = planted_at_output(np.concatenate(stances, 1), out, layout.contact_joints, model_fps,
                                loop.out_fps) if C else None
    if loop.smooth > 0:
        from scipy.ndimage import gaussian_filter1d

        # Network jitter sits near the model rate's Nyquist frequency (3-5 Hz at 10 fps), where
        # real motion has little power (docs/sampling.md); steps (1-2 Hz) pass. On by default
        # since the final solve's swing clearance holds the swing up: full evaluate.py, PSKL
        # 4.9x -> 3.6x (demo), 3.35x -> 3.05x (quality), skating no higher (docs/quality.md).
        # The feet keep their own timing: smoothing would flatten each swing into a shuffle
        # (lower, longer, near the floor); the final solve's lock and acceleration terms
        # handle their jitter.
        keep = list(layout.contact_joints)
        feet = out[:, :, keep].copy()
        out = gaussian_filter1d(out, loop.smooth, axis=1, mode="nearest")
        out[:, :, keep] = feet
    seat_goals: dict[int, list[int]] = {}
    for g, goal in enumerate(goals):
        if np.isfinite(seat_y[g]):
            seat_goals.setdefault(_label(names, goal.action), []).append(g)
    seats = [None] * S
    if seat_goals and loop.project:
        targets = [[goal_xz[g, 0], seat_y[g], goal_xz[g, 1]] for g in range(G)]
        shifted = [seat_shift(out[s], model_labels[s, near], seat_goals, targets) for s in range(S)]
        out, seats = np.stack([x for x, _ in shifted]), [r for _, r in shifted]
    bodies = None
    if body is not None:
        hands = hand_targets(out, model_labels[:, near], names, loop.hand_actions, objects, scene) or [None] * S
        from motiongen.body.solve import SOLVE_CONFIG

        w = solve_smoothness_for_rate(model_fps) if loop.solve_smoothness is None else float(loop.solve_smoothness)
        bodies = solve_bodies(body, out, torch.cat(rots, 1), planted if loop.foot_lock else None,
                              layout.contact_joints, model_fps, loop.out_fps,
                              [merge_targets(h, p) for h, p in zip(hands, seats)],
                              cfg=dataclasses.replace(SOLVE_CONFIG, w_smooth_joints=w))
        out = np.stack([b.joints for b in bodies])
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
        joints_raw=raw_out.astype(np.float32), planted=planted,
        contact_joints=[loaded.joint_set.names[j] for j in layout.contact_joints], bodies=bodies,
        episodes=episodes)
