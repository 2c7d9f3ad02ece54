"""The evaluation protocol: the TRUMANS supplement's static and dynamic settings (A.1).

* Static: per test scene, `pairs` start/end pairs on free floor; some end at a real sit spot
  (taken from the scene's own motion data: pelvis of the middle frame of each "sit" segment)
  with the sit action. Midpoints come from the planner (`sampling.goals.plan_route`).
* Dynamic: per test scene, `pairs` (object, human start) pairs: the object is one the data
  interacts with ("pick up" segments: the object nearest the hands at the segment's start,
  at its pose there), the route ends where the data's pelvis stood during the interaction,
  and the goal carries the interaction action. Objects are placed through `generate(objects=)`.
* Each pair is sampled k times in one batch (`num_samples=k`); every metric of
  `motiongen.metrics` is computed per sample (APD per pair) and averaged.
* The reference row applies the same metrics to the dataset's own motion in the same scenes.

Pairs depend only on (seed, scene id, setting): evaluating a subset of scenes gives the same
pairs for those scenes. Diffusion noise is seeded per pair the same way.

This module samples the pairs and aggregates; the pieces: `eval.scene_context` (the scene),
`eval.pairs` (configuration and pairs), `eval.motion_scores` (per-motion scores, reference).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from motiongen import metrics as M
from motiongen.body.model import load_body_model
from motiongen.eval.motion_scores import ReferenceResult, goal_metrics, motion_metrics, reference_metrics
from motiongen.eval.pairs import SETTINGS, Pair, ProtocolConfig, make_pairs, pair_seed
from motiongen.eval.scene_context import SceneContext
from motiongen.rates import DATA_FPS
from motiongen.sampling import LoopConfig, SamplerSettings, generate


@dataclass
class PairResult:
    pair: Pair
    per_sample: list[dict]              # k metric dicts of the output motions
    per_sample_raw: list[dict]          # the same metrics on the network's own joints (before the body)
    apd: float
    joints: np.ndarray                  # (k, T, J, 3) float32 world joints at 30 fps, the whole batch
    kept: list[np.ndarray]              # k arrays (T_s, J, 3): each sample up to its finish
    kept_raw: list[np.ndarray]          # the same for the network's own joints
    completed: float                    # fraction of samples that reached the final goal
    wall_s: float


def body_vertices(bm, body, frames: int, every_frame: int = 3, every_vertex: int = 8) -> np.ndarray:
    """(T', V', 3) mesh vertices of the first `frames` frames of a `BodyMotion`: every 3rd frame,
    every 8th vertex (enough to find skin in furniture; a fraction of the cost of whole meshes)."""
    return bm.motion_vertices(body, slice(0, frames, every_frame), np.arange(0, bm.num_vertices, every_vertex))


def run_pair(loaded, ctx: SceneContext, pair: Pair, cfg: ProtocolConfig, sampler, body_model=None) -> PairResult:
    """Sample k motions for one pair (one batch) and measure them (the output, and the network's
    own joints before they were put on a body)."""
    target = (pair.object_id, pair.object_pose) if pair.object_id is not None else None
    objs = ctx.objects_for_generate(target)
    dev = loaded.device if loaded.device.type != "mps" else torch.device("cpu")
    gen = torch.Generator(device=dev).manual_seed(pair_seed(cfg.seed, pair.setting, pair.scene, pair.index))
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        # generate warns when samples stop before the goal; the report counts them instead.
        warnings.simplefilter("ignore")
        motion = generate(loaded, ctx.grid, route=pair.route, walkable=ctx.fmap, objects=objs,
                          sampler=sampler, num_samples=cfg.k, generator=gen, body_model=body_model,
                          loop=LoopConfig(max_episodes=cfg.max_episodes, out_fps=ctx.ds.fps, source_fps=ctx.ds.fps,
                                          stall_s=None, **cfg.loop))   # the protocol's own budget: max_episodes
    wall = time.perf_counter() - t0
    names = list(motion.joint_names)
    A = len(motion.action_names)
    joints = motion.joints                                                                   # (k, T, J, 3)
    boundaries = [int(b) for b in motion.episode_starts[1:]]
    goal_xz = pair.goal.xz
    results, raw_results, kept, kept_raw = [], [], [], []
    for s in range(cfg.k):
        # A sample that finished early idles while the batch goes on: cut it at its finish so
        # the padding does not dilute its metrics (APD below uses the full, equal-length batch).
        T = int(motion.finish_frame[s]) + 1 if motion.finish_frame[s] >= 0 else joints.shape[1]
        T = max(T, 4)
        js = joints[s, :T]                                                                   # (T, J, 3)
        kept.append(js)
        kept_raw.append(motion.joints_raw[s, :T])
        lab = np.zeros((T, A), bool)                                                         # (T, A)
        a = motion.actions[s, :T]
        lab[np.flatnonzero(a >= 0), a[a >= 0]] = True
        oposes = [(pair.object_id, np.repeat(pair.object_pose[None], T, 0))] if target else []
        verts = None
        if body_model is not None and motion.bodies is not None:
            verts = body_vertices(body_model, motion.bodies[s], T)
        for out, js_, v in ((results, js, verts), (raw_results, motion.joints_raw[s, :T], None)):
            m = motion_metrics(ctx, js_, motion.fps, names, lab, list(motion.action_names), pair.setting, cfg,
                               boundaries, oposes, vertices=v)
            m.update(goal_metrics(js_, motion.arrival_frame[s, -1], goal_xz, pair.route.subgoals))
            out.append(m)
    apd = M.apd(joints) if cfg.k >= 2 else float("nan")
    done = float(np.mean(motion.finish_frame >= 0))
    return PairResult(pair, results, raw_results, apd, joints, kept, kept_raw, done, wall)


# ---------------------------------------------------------------------------------------
# Aggregation


def _chunks(motions, n: int) -> list[np.ndarray]:
    """Non-overlapping n-frame chunks of every motion (PSKL needs one length)."""
    return [m[i:i + n] for m in motions for i in range(0, len(m) - n + 1, n)]


def pskl_sets(a, b, fps: float, n: int) -> tuple[float, float]:
    ca, cb = _chunks(a, n), _chunks(b, n)
    if not ca or not cb:
        return float("nan"), float("nan")
    return M.pskl(ca, cb, fps, length=n)


BODY_KEYS = ("bone_cv", "bone_max_dev", "slide_mps", "foot_skating", "penetration_frames", "penetration_max_m",
             "mesh_penetration_frames", "mesh_penetration_max_m", "floor_penetration_frames", "jerk", "seam_ratio")


def summarize_model(results: list[PairResult], ref_motions: list[np.ndarray], fps: float,
                    cfg: ProtocolConfig, raw: bool = False) -> dict:
    """Setting-level numbers for the model row (means over samples; contact pooled over frames).
    raw: the row of the network's own joints instead of the output motions. Goal success
    counts the body (hips midpoint), which no pin can put on the goal."""
    samples = [m for r in results for m in (r.per_sample_raw if raw else r.per_sample)]
    if not samples:
        return {}
    d_final = [m["goal_dist_body_m"] for m in samples]
    succ = M.goal_success(np.asarray(d_final), (0.2, 0.5))
    out = {k: M.finite_mean(m.get(k) for m in samples) for k in
           BODY_KEYS + ("goal_dist_m", "goal_dist_body_m", "object_dist_m")}
    out["slide_mps"] = M.finite_median(m.get("slide_mps") for m in samples)
    out["success_0.2"], out["success_0.5"] = succ[0.2], succ[0.5]
    out["traj_fail_rate"] = M.trajectory_fail_rate([np.asarray(m["_waypoints"]) for m in samples], 0.5)
    hits, frames = sum(m["_contact_hits"] for m in samples), sum(m["_contact_frames"] for m in samples)
    out["contact_rate"] = hits / frames if frames else float("nan")
    out["apd_m"] = M.finite_mean(r.apd for r in results)
    mine = [x for r in results for x in (r.kept_raw if raw else r.kept)]
    kab, kba = pskl_sets(mine, ref_motions, fps, cfg.pskl_frames)
    out["pskl_gen_ref"], out["pskl_ref_gen"] = kab, kba
    out["completed"] = M.finite_mean(r.completed for r in results)
    out["n_pairs"], out["n_samples"] = len(results), len(samples)
    out["seconds_per_pair"] = M.finite_mean(r.wall_s for r in results)
    return out


def summarize_reference(refs: list[ReferenceResult], fps: float, cfg: ProtocolConfig) -> dict:
    """The reference row: per-sequence means; goal metrics and APD are n/a (see docs/evaluation.md);
    PSKL between two halves of the sequences (alternating), the noise floor of the metric."""
    seqs = [m for r in refs for m in r.per_sequence]
    motions = [x for r in refs for x in r.motions]
    if not seqs:
        return {}
    out = {k: M.finite_mean(m.get(k) for m in seqs) for k in BODY_KEYS + ("object_dist_m",)}
    out["slide_mps"] = M.finite_median(m.get("slide_mps") for m in seqs)
    for k in ("goal_dist_m", "goal_dist_body_m", "success_0.2", "success_0.5", "traj_fail_rate", "apd_m",
              "completed", "seconds_per_pair"):
        out[k] = None
    hits, frames = sum(m["_contact_hits"] for m in seqs), sum(m["_contact_frames"] for m in seqs)
    out["contact_rate"] = hits / frames if frames else float("nan")
    kab, kba = pskl_sets(motions[0::2], motions[1::2], fps, cfg.pskl_frames) if len(motions) >= 2 \
        else (float("nan"), float("nan"))
    out["pskl_gen_ref"], out["pskl_ref_gen"] = kab, kba
    out["n_sequences"] = len(seqs)
    out["n_frames"] = int(sum(len(x) for x in motions))
    return out


def episode_frames(loaded, out_fps: float = DATA_FPS) -> int:
    """Output frames one autoregressive episode adds: (L - k) model frames at the output rate."""
    k = int(loaded.mask.max_transition)
    return int(round((loaded.window.length - k) * out_fps / loaded.model_fps))


@dataclass
class Evaluation:
    """Everything one protocol run produced (report.py turns it into files)."""
    settings: list[str]
    pairs: dict[str, list[Pair]]                       # setting -> pairs (all scenes)
    results: dict[str, list[PairResult]]               # setting -> sampled pairs
    references: dict[str, list[ReferenceResult]]      # setting -> one per scene
    model: dict[str, dict]                             # setting -> summary (summarize_model)
    reference: dict[str, dict]                         # setting -> summary (summarize_reference)
    model_raw: dict[str, dict] = field(default_factory=dict)   # setting -> the network's own joints
    contexts: dict[int, SceneContext] = field(repr=False, default_factory=dict)
    notes: list[str] = field(default_factory=list)
    wall_s: float = 0.0


def evaluate(loaded, ds, scene_ids, cfg: ProtocolConfig, settings=SETTINGS, sampler=None,
             progress: bool = True, log=None, body_model=None) -> Evaluation:
    """Run the protocol: pairs for every scene and setting, k samples each, the reference row.
    body_model: the motions' body model (default `load_body_model()`), also for skin penetration."""
    t0 = time.perf_counter()
    sampler = sampler or SamplerSettings()
    body_model = body_model if body_model is not None else load_body_model()
    say = log or (lambda m: None)
    names = list(loaded.action_names)
    ctxs = {sid: SceneContext(ds, sid, cfg.body_radius) for sid in scene_ids}
    pairs: dict[str, list[Pair]] = {}
    notes: list[str] = []
    for st in settings:
        pairs[st] = []
        for sid, ctx in ctxs.items():
            ps = make_pairs(ctx, st, cfg, names)
            pairs[st] += ps
            if st == "static" and not any(p.goal.interacts for p in ps) and cfg.interaction_pairs:
                notes.append(f"scene {sid}: its motion data has no {'/'.join(cfg.static_actions)} segment, "
                             "so all static pairs end on free floor")
            if st == "dynamic" and not ps:
                why = (f"the checkpoint has no {cfg.dynamic_action!r} action" if cfg.dynamic_action not in names
                       else "no object to interact with")
                notes.append(f"scene {sid}: no dynamic pairs ({why})")
    n_total = sum(len(v) for v in pairs.values())
    say(f"evaluating {len(ctxs)} scene(s), {n_total} pair(s) x k={cfg.k}: "
        + ", ".join(f"{st} {len(pairs[st])}" for st in settings))
    results: dict[str, list[PairResult]] = {st: [] for st in settings}
    bar = tqdm(total=n_total, desc="evaluate", unit="pair", disable=not progress, dynamic_ncols=True)
    try:
        for st in settings:
            for pair in pairs[st]:
                bar.set_postfix_str(f"{st} scene {pair.scene} pair {pair.index}")
                results[st].append(run_pair(loaded, ctxs[pair.scene], pair, cfg, sampler, body_model))
                bar.update(1)
    finally:
        bar.close()
    ep = episode_frames(loaded, ds.fps)
    refs = {st: [reference_metrics(ctxs[sid], st, cfg, ep) for sid in ctxs] for st in settings}
    ref_motions = [m for r in refs[settings[0]] for m in r.motions] if settings else []
    model = {st: summarize_model(results[st], ref_motions, ds.fps, cfg) for st in settings}
    model_raw = {st: summarize_model(results[st], ref_motions, ds.fps, cfg, raw=True) for st in settings}
    reference = {st: summarize_reference(refs[st], ds.fps, cfg) for st in settings}
    return Evaluation(list(settings), pairs, results, refs, model, reference, model_raw, ctxs, notes,
                      time.perf_counter() - t0)
