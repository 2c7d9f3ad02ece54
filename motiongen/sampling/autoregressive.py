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

Route planning comes before (`goals.plan_route`, `goals.plan_scene_route`). The stages, each
in the module that owns it: plan the next targets (`progress`), condition the network
(`conditioning`), denoise (`denoising`), put the window on the body (`projection`), keep its
frames and move every sample on (`episode`, `progress`); after the last episode, clean up
(`cleanup`).

Improvements over the reference loop (the public TRUMANS code; docs/sampling.md, "Differences
from the reference loop"):
* Look-ahead targets: each episode targets the farthest subgoal that is still within the
  model's reach (taken from the training statistics) and in line of sight on the walkable
  map, instead of one 0.6 m subgoal per 1.6 s window, which forces a slow shuffle. Subgoals
  farther than the reach are clamped (the episode walks towards them and the next continues).
  `lookahead=False` gives the reference behaviour (one episode per subgoal).
* Per-sample progress in a batch: S samples advance through goals independently in one
  batched call per episode; a finished sample idles at its last goal until all are done.
* Interactions: a goal with an action holds the pelvis target there with that action label
  for its duration.
* Stops at the final goal within tolerance (then `loop.settle` idle episodes, so the body
  comes to rest there rather than ending mid-stride), or at `max_episodes` with a warning saying how
  far each sample got; a sample that makes no progress for `loop.stall_s` seconds of motion
  stops early (`progress.stall_rule`), idling where it stands, and the loop ends once every
  sample is done or stopped. `Motion.goal_outcome` says what became of each goal.
* Output: the projected frames are resampled to 30 fps (cubic spline) and solved once more on
  the body over the whole motion, with every foot joint the model predicts planted held in
  place (foot locking, `loop.foot_lock`). The network's own joints stay available
  (`Motion.joints_raw`) so that what the clean-up did can be measured.
"""

from __future__ import annotations

import time
import warnings
from typing import Mapping, Sequence

import numpy as np
import torch

from motiongen.body.model import load_body_model
from motiongen.body.solve import MotionBody
from motiongen.errors import ConfigError
from motiongen.routing import WalkableMap
from motiongen.sampling.cleanup import CleanMotion, clean_up
from motiongen.sampling.conditioning import condition_episode, loop_hand_reach
from motiongen.sampling.denoising import denoise
from motiongen.sampling.episode import EpisodeState, LoopSpec, Window, drop_warmup, loop_spec, record_episode
from motiongen.sampling.goals import Route
from motiongen.sampling.interactions import hand_goals
from motiongen.sampling.progress import (Progress, Targets, advance, goal_outcomes, goal_plan, next_targets,
                                         output_arrival_errors, shortfall)
from motiongen.sampling.projection import project_window
from motiongen.sampling.scene_query import SceneQuery
from motiongen.sampling.settings import POST_LOOP_FIELDS, LoopConfig, Motion, SamplerSettings


def generate(loaded, scene=None, *, route: Route, walkable: WalkableMap | None = None,
             start_yaw: float | None = None, objects: Sequence[tuple] = (),
             sampler: SamplerSettings = SamplerSettings(), num_samples: int = 1,
             generator: torch.Generator | None = None, loop: LoopConfig = LoopConfig(), log=None,
             body_model=None, cleanups: Mapping[str, LoopConfig] | None = None) -> Motion:
    """Generate S = num_samples motions along `route` in `scene`.

    loaded: a `LoadedModel` (loading.build.load_model). scene: an OccupancyGrid or None
    (empty floor, no bounds). route: a `goals.plan_route` / `goals.plan_scene_route` result
    (the goals, their actions from loaded.action_names, and the subgoals); the motion starts
    at route.start. walkable: the map the route was planned on; look-ahead targets must be in
    line of sight on it (None: every subgoal is). start_yaw: the start heading (None: facing the first subgoal).
    objects: [(object OccupancyGrid, pose (4, 4) object -> world)] placed in the scene.
    generator: torch.Generator for the diffusion noise (reproducible runs).
    body_model: the `BodyModel` of the motion's body (default `load_body_model()`: the user's
    SMPL-X file from $MOTIONGEN_SMPLX_MODEL, else the procedural one); used when loop.project.
    log: optional callable(str) for progress lines.
    cleanups: {name: LoopConfig} differing from `loop` in the clean-up after the last episode
    only (`settings.POST_LOOP_FIELDS`): the same episodes cleaned up each way, in
    `Motion.variants[name]` (evaluation's ablation rows).
    Raises ConfigError for bad settings; returns a `Motion`.
    """
    t_start = time.perf_counter()
    if num_samples < 1:
        raise ConfigError(f"num_samples must be >= 1, got {num_samples}")
    spec = loop_spec(loaded, route, num_samples, loop, start_yaw, sampler, generator)
    check_cleanups(loop, cleanups or {})
    if loop.project and body_model is None:
        body_model = load_body_model()
    plan = goal_plan(route, loaded.action_names, scene, loop, spec, loaded.mask.p_goal_y, walkable)
    query = SceneQuery(loaded, scene, objects, spec.device)
    reach = loop_hand_reach(loaded, objects, scene, loop)
    state, progress = EpisodeState(), Progress.start(num_samples, len(route.goals))
    body_model = body_model if loop.project else None          # None: no body, no final solve

    # Warm-up: stand at the start, settle into a natural pose.
    stand = Targets.stand(route.start, plan.idle_label, num_samples)
    for _ in range(max(1, loop.warmup)):
        run_episode(spec, loaded, query, body_model, state, stand)
    first_kept = 0
    if not loop.keep_warmup:
        drop_warmup(state, spec.transition)
        first_kept = len(state.episodes) - 1

    # Goal episodes, until every sample has acted at its last goal or stalled; then, when every
    # sample walked to a last goal without an action (arriving within the tolerance, mid-stride),
    # `loop.settle` more for the bodies to come to rest on it.
    n_ep = 0
    while not progress.finished.all() and n_ep < loop.max_episodes:
        before = state.n_frames
        targets = goal_episode(spec, loaded, query, body_model, state, progress, plan, reach)
        n_ep += 1
        for line in advance(progress, plan, targets, state.frames[-1], before, n_ep):
            if log is not None:
                log(line)
    for _ in range(loop.settle if progress.done.all() and not plan.goals[-1].interacts else 0):
        goal_episode(spec, loaded, query, body_model, state, progress, plan, reach)
    if not progress.finished.all():
        warnings.warn(f"stopped after max_episodes={loop.max_episodes} episodes: "
                      + shortfall(progress, plan, state.pelvis_now()), stacklevel=2)
    if progress.stalled.any():
        warnings.warn(f"stopped early, no progress for loop.stall_s={loop.stall_s:g} s: "
                      + shortfall(progress, plan, state.pelvis_now(), progress.stalled), stacklevel=2)

    def finish(lc: LoopConfig) -> Motion:
        out = clean_up(state, loaded.layout, spec.model_fps, plan, lc, objects, scene, loaded.swing_rise)
        return as_motion(loaded, route, lc.out_fps, spec.model_fps, state.episodes[first_kept:], state, progress,
                         out, time.perf_counter() - t_start)

    motion = finish(loop)
    motion.variants = {name: finish(lc) for name, lc in (cleanups or {}).items()}
    return motion


def goal_episode(spec: LoopSpec, loaded, query: SceneQuery, body_model, state: EpisodeState, progress: Progress,
                 plan, reach) -> Targets:
    """One episode towards each sample's next target (`progress.next_targets`), with its hand
    goal where the loop gives one; returns the targets."""
    targets = next_targets(progress, plan, state.pelvis_now())
    if reach is not None:
        targets.hand, targets.hand_point = hand_goals(reach, state.tail.joints, targets.hand_labels())
    run_episode(spec, loaded, query, body_model, state, targets)
    return targets


def check_cleanups(loop: LoopConfig, cleanups: Mapping[str, LoopConfig]) -> None:
    """Each variant may differ from `loop` only where the clean-up after the last episode reads."""
    for name, lc in cleanups.items():
        bad = [f for f in LoopConfig.__dataclass_fields__
               if f not in POST_LOOP_FIELDS and getattr(lc, f) != getattr(loop, f)]
        if bad:
            raise ConfigError(f"cleanups[{name!r}]: {', '.join(bad)} change(s) the episodes, not their clean-up")


def run_episode(spec: LoopSpec, loaded, query: SceneQuery, body_model, state: EpisodeState, t: Targets,
                between=None) -> None:
    """One window for all samples towards the targets `t`: condition, denoise, put on the body
    (its shape fitted to the first window; body_model None: none), keep. `between()`, when
    given, is called after each of the first two stages; it may raise to stop the episode with
    `state` unchanged (the live sampler stops an episode whose frames a click threw away)."""
    inputs = condition_episode(spec, loaded, query, state.tail, t)
    if between is not None:
        between()
    raw, stance = denoise(spec, loaded, inputs)
    if between is not None:
        between()
    if body_model is not None and state.body is None:
        state.body = MotionBody.estimate(body_model, loaded.joint_set, raw)
    world, stance, rot = project_window(raw, stance, state.tail, inputs.pinned, spec.blend_frames, state.body,
                                        spec.body_scale)
    record_episode(state, spec, t.kind, t.target,
                   Window(inputs.pinned, inputs.to_world, raw, world, stance, rot, inputs.labels))


def as_motion(loaded, route: Route, out_fps: float, model_fps: float, kept: list, state: EpisodeState,
              progress: Progress, out: CleanMotion, wall_time: float) -> Motion:
    """The `Motion`: the clean-up's output, the kept episodes' starts and the progress, model
    frames counted in output frames (-1 stays -1)."""
    ratio = out_fps / model_fps
    to_out = lambda m: np.where(m >= 0, np.round(m * ratio).astype(np.int64), -1)            # noqa: E731
    names = loaded.joint_set.names
    # The goal errors a user reads are the output's, measured after smoothing and the final solve.
    arrival = to_out(progress.arrival_frame)
    goal_xz = np.array([g.xz for g in route.goals], np.float64).reshape(-1, 2)
    pelvis_err, hips_err = output_arrival_errors(out.joints, arrival, goal_xz, out_fps)
    return Motion(
        joints=out.joints.astype(np.float32), fps=float(out_fps), joint_names=list(names),
        model_joints=out.model_joints.astype(np.float32), model_fps=float(model_fps),
        actions=out.actions.astype(np.int16), action_names=list(loaded.action_names),
        episode_starts=np.array([to_out(np.int64(e.start)) for e in kept], np.int64),
        episode_kinds=[e.kind for e in kept], route=route, arrival_frame=arrival,
        arrival_error=pelvis_err, arrival_error_body=hips_err,
        finish_frame=to_out(progress.finish_frame), completed=bool(progress.done.all()), wall_time=wall_time,
        joints_raw=out.joints_raw.astype(np.float32), planted=out.planted,
        contact_joints=[names[j] for j in loaded.layout.contact_joints], bodies=out.bodies,
        episodes=state.episodes, goal_outcome=goal_outcomes(progress, len(route.goals)))
