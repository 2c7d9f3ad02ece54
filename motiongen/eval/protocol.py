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
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from motiongen import metrics as M
from motiongen.body.model import load_body_model
from motiongen.eval.mesh_scores import BodyMeshes, pooled
from motiongen.eval.motion_scores import ReferenceResult, reference_metrics
from motiongen.eval.pair_runs import Measured, PairResult, run_pair
from motiongen.eval.pairs import SETTINGS, Pair, ProtocolConfig, make_pairs
from motiongen.eval.pskl_sets import action_figures, by_action_keys, pskl_equal, reference_halves
from motiongen.eval.scene_context import SceneContext
from motiongen.rates import DATA_FPS
from motiongen.sampling import SamplerSettings


# ---------------------------------------------------------------------------------------
# Aggregation


BODY_KEYS = ("bone_cv", "bone_max_dev", "slide_mps", "foot_skating", "toe_height_m", "heading_deg", "knee_walk_deg",
             "penetration_frames", "penetration_max_m", "mesh_penetration_frames", "mesh_penetration_max_m",
             "floor_penetration_frames", "jerk", "seam_ratio")


def view(r: PairResult, row: str) -> Measured:
    """One row's motions of a pair: "model" (the output), "model_raw" (the network's joints) or
    an ablated stage's output."""
    if row == "model":
        return Measured(r.per_sample, r.kept, r.apd, r.completed, r.labels)
    if row == "model_raw":
        return Measured(r.per_sample_raw, r.kept_raw, r.apd_raw, r.completed, r.labels)
    return r.ablation[row]


@dataclass
class RefSet:
    """What a model row's PSKL is measured against: the scenes' data, labelled."""
    motions: list[np.ndarray]           # (T_i, J, 3) per sequence
    labels: list[np.ndarray]            # (T_i, A) bool per sequence, columns `names`
    names: list[str]                    # the data's action names
    model_names: list[str]              # the checkpoint's action names (the generated labels index them)


def summarize_model(results: list[PairResult], ref: RefSet, fps: float,
                    cfg: ProtocolConfig, raw: bool = False, row: str | None = None) -> dict:
    """Setting-level numbers for the model row (means over samples; contact pooled over frames).
    raw: the row of the network's own joints instead of the output motions; row: any `view`
    (an ablated stage: over the pairs that have it). Goal success counts the body (hips
    midpoint), which no pin can put on the goal. PSKL over every chunk, and by action
    (`pskl_sets.action_figures`: each action's chunks against the data's of the same action)."""
    row = row or ("model_raw" if raw else "model")
    views = [view(r, row) for r in results if row in ("model", "model_raw") or row in r.ablation]
    samples = [m for v in views for m in v.per_sample]
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
    out.update(pooled(samples))
    out["apd_m"] = M.finite_mean(v.apd for v in views)
    _, half = reference_halves(ref.motions, cfg.pskl_frames)
    kept, labels = [x for v in views for x in v.kept], [x for v in views for x in v.labels]
    out["pskl_gen_ref"], out["pskl_ref_gen"], out["pskl_chunks"] = pskl_equal(kept, half, fps, cfg.pskl_frames)
    out.update(by_action_keys(action_figures(kept, labels, ref.model_names, ref.motions, ref.labels, ref.names,
                                             cfg.pskl_frames, fps), "gen"))
    out["completed"] = M.finite_mean(v.completed for v in views)
    out["n_pairs"], out["n_samples"] = len(views), len(samples)
    out["seconds_per_pair"] = M.finite_mean(r.wall_s for r in results)
    return out


def summarize_ablation(results: list[PairResult], ref: RefSet, fps: float, cfg: ProtocolConfig) -> dict:
    """The ablation table of a setting: the output and the network's joints on the pairs that
    were ablated, and the output without each stage on the same pairs ({} when none was)."""
    subset = [r for r in results if r.ablation]
    if not subset:
        return {}
    out = {"model": summarize_model(subset, ref, fps, cfg),
           "model_raw": summarize_model(subset, ref, fps, cfg, raw=True)}
    for stage in subset[0].ablation:
        out[stage] = summarize_model(subset, ref, fps, cfg, row=stage)
    return out


def summarize_reference(refs: list[ReferenceResult], fps: float, cfg: ProtocolConfig, names=()) -> dict:
    """The reference row: per-sequence means; goal metrics and APD are n/a (see docs/evaluation.md);
    PSKL between two halves of the sequences (alternating), the noise floor of the metric, over
    every chunk and by action (`names`: the data's action names, the labels' columns)."""
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
    out.update(pooled(seqs))
    a, b = reference_halves(motions, cfg.pskl_frames)
    out["pskl_gen_ref"], out["pskl_ref_gen"], out["pskl_chunks"] = pskl_equal(a, b, fps, cfg.pskl_frames)
    labels = [x for r in refs for x in r.labels]
    out.update(by_action_keys(action_figures([], [], list(names), motions, labels, list(names), cfg.pskl_frames, fps),
                              "floor"))
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
    ablation: dict[str, dict] = field(default_factory=dict)    # setting -> summarize_ablation
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
    meshes = BodyMeshes(body_model, loaded.joint_set)
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
                results[st].append(run_pair(loaded, ctxs[pair.scene], pair, cfg, sampler, body_model, meshes))
                bar.update(1)
    finally:
        bar.close()
    ep = episode_frames(loaded, ds.fps)
    refs = {st: [reference_metrics(ctxs[sid], st, cfg, ep, meshes) for sid in ctxs] for st in settings}
    first = refs[settings[0]] if settings else []
    ref = RefSet([m for r in first for m in r.motions], [x for r in first for x in r.labels], list(ds.action_names),
                 names)
    model = {st: summarize_model(results[st], ref, ds.fps, cfg) for st in settings}
    model_raw = {st: summarize_model(results[st], ref, ds.fps, cfg, raw=True) for st in settings}
    reference = {st: summarize_reference(refs[st], ds.fps, cfg, ds.action_names) for st in settings}
    ablation = {st: summarize_ablation(results[st], ref, ds.fps, cfg) for st in settings}
    return Evaluation(list(settings), pairs, results, refs, model, reference, model_raw, ablation, ctxs, notes,
                      time.perf_counter() - t0)
