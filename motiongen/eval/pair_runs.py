"""One pair of the protocol, sampled and measured: k motions in one batch, the output and the
network's own joints, and on the pairs chosen for it the ablation, each clean-up stage of the
sampler switched off in turn on the same pair and noise (`sampling.settings.CLEANUP_STAGES`)."""

from __future__ import annotations

import dataclasses
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import torch

from motiongen import metrics as M
from motiongen.eval.mesh_scores import BodyMeshes, InteractionObject
from motiongen.eval.motion_scores import MeshInput, goal_metrics, motion_metrics
from motiongen.eval.pairs import Pair, ProtocolConfig, pair_seed
from motiongen.eval.scene_context import SceneContext
from motiongen.sampling import LoopConfig, generate
from motiongen.sampling.assemble import smoothing_sigma
from motiongen.sampling.settings import CLEANUP_STAGES, IN_LOOP_STAGES, Motion


@dataclass
class Measured:
    """One batch's motions of one kind (the output, an ablation) and their scores."""
    per_sample: list[dict]              # k metric dicts
    kept: list[np.ndarray]              # k arrays (T_s, J, 3): each sample up to its finish
    apd: float
    completed: float                    # fraction of samples that reached the final goal
    labels: list[np.ndarray] = field(default_factory=list)   # k arrays (T_s,) action index per kept frame, -1 none


@dataclass
class PairResult:
    pair: Pair
    per_sample: list[dict]              # k metric dicts of the output motions
    per_sample_raw: list[dict]          # the same metrics on the network's own joints (before the body)
    apd: float
    apd_raw: float                      # the network's own joints' APD
    joints: np.ndarray                  # (k, T, J, 3) float32 world joints at 30 fps, the whole batch
    kept: list[np.ndarray]              # k arrays (T_s, J, 3): each sample up to its finish
    kept_raw: list[np.ndarray]          # the same for the network's own joints
    completed: float                    # fraction of samples that reached the final goal
    wall_s: float
    ablation: dict[str, Measured] = field(default_factory=dict)   # stage switched off -> the output without it
    labels: list[np.ndarray] = field(default_factory=list)        # k arrays (T_s,) action index per kept frame


def pair_loop(ctx: SceneContext, cfg: ProtocolConfig) -> LoopConfig:
    """The sampler's loop for every pair: its defaults, the protocol's episode budget (no stall
    rule) and the clean-up keys the run sets (`loop.*`)."""
    return LoopConfig(max_episodes=cfg.max_episodes, out_fps=ctx.ds.fps, source_fps=ctx.ds.fps, stall_s=None,
                      **cfg.loop)


def sample_pair(loaded, ctx: SceneContext, pair: Pair, cfg: ProtocolConfig, sampler, body_model, loop: LoopConfig,
                cleanups: dict | None = None) -> tuple[Motion, float]:
    """k motions of one pair in one batch, the noise seeded by the pair: (motion, seconds)."""
    target = (pair.object_id, pair.object_pose) if pair.object_id is not None else None
    dev = loaded.device if loaded.device.type != "mps" else torch.device("cpu")
    gen = torch.Generator(device=dev).manual_seed(pair_seed(cfg.seed, pair.setting, pair.scene, pair.index))
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        # generate warns when samples stop before the goal; the report counts them instead.
        warnings.simplefilter("ignore")
        motion = generate(loaded, ctx.grid, route=pair.route, walkable=ctx.fmap, objects=ctx.objects_for_generate(target),
                          sampler=sampler, num_samples=cfg.k, generator=gen, body_model=body_model, loop=loop,
                          cleanups=cleanups)
    return motion, time.perf_counter() - t0


def run_pair(loaded, ctx: SceneContext, pair: Pair, cfg: ProtocolConfig, sampler, body_model=None,
             meshes: BodyMeshes | None = None) -> PairResult:
    """Sample k motions for one pair (one batch) and measure them: the output, the network's
    own joints before they were put on a body, and (the first `cfg.ablation_pairs` pairs of a
    scene) the output with each stage of `cfg.ablate` off. meshes: the mesh figures, on the
    output's own body and on a body put on the network's joints."""
    loop = pair_loop(ctx, cfg)
    stages = list(cfg.ablate) if pair.index < cfg.ablation_pairs else []
    acting = [s for s in stages if stage_can_act(s, loaded, pair, loop)]
    after = {s: dataclasses.replace(loop, **CLEANUP_STAGES[s]) for s in acting if s not in IN_LOOP_STAGES}
    motion, wall = sample_pair(loaded, ctx, pair, cfg, sampler, body_model, loop, after)
    out, raw = measure(motion, ctx, pair, cfg, meshes), measure(motion, ctx, pair, cfg, meshes, raw=True)
    ablation = {s: measure(motion.variants[s], ctx, pair, cfg, meshes) for s in after}
    for s in stages:
        if s not in acting:
            ablation[s] = out                      # nothing to switch off: the output itself
        elif s in IN_LOOP_STAGES:
            # The stage shapes what the next episode sees: sample again, same pair, same noise.
            again, _ = sample_pair(loaded, ctx, pair, cfg, sampler, body_model,
                                   dataclasses.replace(loop, **CLEANUP_STAGES[s]))
            ablation[s] = measure(again, ctx, pair, cfg, meshes)
    return PairResult(pair, out.per_sample, raw.per_sample, out.apd, raw.apd, motion.joints, out.kept, raw.kept,
                      out.completed, wall, {s: ablation[s] for s in stages}, out.labels)


def stage_can_act(stage: str, loaded, pair: Pair, loop: LoopConfig) -> bool:
    """Whether switching `stage` off can change this pair's output. A stage with nothing to act
    on (no hand goal given, no pick-up for the hand reach, no seat for the seat height, no
    smoothing at the model's rate) has the output itself as its ablation row: sampling or
    solving again would give the same motion bit for bit, at the cost of a final solve."""
    actions = {g.action for g in pair.route.goals}
    if stage == "hand_goal":
        return gives_hand_goals(loaded, pair, loop)
    if stage == "hand_reach":
        return bool(actions & set(loop.hand_actions))
    if stage == "seat_height":
        return bool(actions & set(loop.seat_actions))
    if stage == "smoothing":
        return smoothing_sigma(loop.smooth, loaded.model_fps) > 0
    return True


def gives_hand_goals(loaded, pair: Pair, loop) -> bool:
    """Whether the loop tells the network a hand goal anywhere on this pair's route: a
    checkpoint trained with them and a goal whose action gets one (`LoopConfig.hand_goal`)."""
    return loaded.mask.hand_goals and any(g.action in loop.hand_goal for g in pair.route.goals)


def measure(motion: Motion, ctx: SceneContext, pair: Pair, cfg: ProtocolConfig, meshes: BodyMeshes | None,
            raw: bool = False) -> Measured:
    """Every sample's scores: the output (its own body for the mesh figures, or a body put on
    its joints where it has none) or, raw, the network's joints (on a body put on them)."""
    names, actions = list(motion.joint_names), list(motion.action_names)
    joints = motion.joints_raw if raw else motion.joints                                    # (k, T, J, 3)
    boundaries = [int(b) for b in motion.episode_starts[1:]]
    scores, kept, kept_labels = [], [], []
    for s in range(motion.num_samples):
        # A sample that finished early idles while the batch goes on: cut it at its finish so
        # the padding does not dilute its metrics (APD below uses the full, equal-length batch).
        T = int(motion.finish_frame[s]) + 1 if motion.finish_frame[s] >= 0 else joints.shape[1]
        T = max(T, 4)
        js = joints[s, :T]                                                                   # (T, J, 3)
        lab = np.zeros((T, len(actions)), bool)                                              # (T, A)
        a = motion.actions[s, :T]
        lab[np.flatnonzero(a >= 0), a[a >= 0]] = True
        oposes = [(pair.object_id, np.repeat(pair.object_pose[None], T, 0))] if pair.object_id is not None else []
        mesh = None
        if meshes is not None:
            body = motion.bodies[s] if motion.bodies and not raw else meshes.of_joints(js)
            mesh = MeshInput(meshes, body, interaction_frames(lab, actions, cfg, oposes))
        m = motion_metrics(ctx, js, motion.fps, names, lab, actions, pair.setting, cfg, boundaries, oposes, mesh)
        m.update(goal_metrics(js, motion.arrival_frame[s, -1], pair.goal.xz, pair.route.subgoals))
        scores.append(m)
        kept.append(js)
        kept_labels.append(np.asarray(a, np.int64))
    apd = M.apd(joints) if motion.num_samples >= 2 else float("nan")
    return Measured(scores, kept, apd, float(np.mean(motion.finish_frame >= 0)), kept_labels)


def interaction_frames(labels, action_names, cfg: ProtocolConfig, oposes) -> list:
    """The sample's interaction for the mesh figures: its frames labelled `cfg.dynamic_action`
    and the pair's object, [(frames (F,) int, InteractionObject)] ([] without an object). A
    sample that never got to act has no frames: it counts as an interaction without touch."""
    if not oposes or cfg.dynamic_action not in action_names:
        return []
    frames = np.flatnonzero(labels[:, action_names.index(cfg.dynamic_action)])
    return [(frames, InteractionObject(oposes[0][0], oposes[0][1]))]
