"""`sample.py`: resolve the scene, goals and checkpoint from a config, generate, write outputs.

Outputs (all written to temporary names in `out` and renamed at the very end, so a failed
run leaves nothing half-written): motion.npz, motion.mp4 (or .gif), trajectories.png,
summary.json, and on request body_<s>.npz (SMPL-X, AMASS layout) and motion_<s>.bvh.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

from motiongen.errors import ConfigError, DataError
from motiongen.routing import walkable_map
from motiongen.sampling.autoregressive import LoopConfig, SamplerSettings, generate
from motiongen.sampling.goal_input import load_goals_file, parse_goals
from motiongen.sampling.goals import check_actions, plan_route
from motiongen.sampling.outputs import body_figures, motion_arrays, summary_lines
from motiongen.sampling.scene_setup import default_route_goals, default_start, resolve_scene
from motiongen.staging import StagedOutputs


def _bool(cfg, key, default=False) -> bool:
    v = cfg.get(key, default)
    return bool(v) if v is not None else default


def run(cfg, default_out: Path) -> dict:
    """The whole `sample.py` run for a resolved config. Returns the summary dict."""
    from omegaconf import OmegaConf

    t0 = time.perf_counter()
    if not cfg.get("ckpt"):
        raise ConfigError("ckpt=PATH is required (a checkpoint written by train.py)")
    out = Path(cfg.out) if cfg.get("out") else Path(default_out)
    threads = int(cfg.get("threads") or 0)
    if threads > 0:
        torch.set_num_threads(threads)
    sampler = SamplerSettings(str(cfg.sampler), int(cfg.steps), float(cfg.eta), float(cfg.guidance_scale))
    if sampler.sampler not in ("ddpm", "ddim"):
        raise ConfigError(f"sampler: expected ddpm or ddim, got {sampler.sampler!r}")
    if sampler.steps < 1:
        raise ConfigError(f"steps must be >= 1, got {sampler.steps}")
    if int(cfg.num_samples) < 1:
        raise ConfigError(f"num_samples must be >= 1, got {cfg.num_samples}")

    # Cheap checks first: goals file and scene file before loading the model.
    file_goals, file_start = ([], None)
    if cfg.get("goals_file"):
        file_goals, file_start = load_goals_file(cfg.goals_file, float(cfg.action_seconds))
    cli_goals = parse_goals(_plain(cfg.get("goals")), _plain(cfg.get("actions")), _plain(cfg.get("durations")),
                            float(cfg.action_seconds))
    if file_goals and cli_goals:
        raise ConfigError("give goals either on the command line (goals=...) or in goals_file=, not both")
    ckpt = Path(str(cfg.ckpt))
    if not ckpt.is_file():
        raise DataError(ckpt, None, "checkpoint file does not exist")

    from motiongen.loading.build import load_model

    device = str(cfg.device)
    loaded = load_model(ckpt, device, precision=str(cfg.get("precision") or "auto"))
    scene = resolve_scene(cfg.get("scene"), loaded.config, float(cfg.voxel_size), str(cfg.scene_up),
                          _bool(cfg, "objects", True))
    fmap = None
    if scene.grid is not None:
        fmap = walkable_map(scene.grid, float(cfg.body_radius), tuple(cfg.body_height))

    goals = file_goals or cli_goals
    start = cfg.get("start")
    start = np.asarray(_plain(start), np.float64) if start is not None else file_start
    if start is not None and np.asarray(start).shape != (2,):
        raise ConfigError(f"start: expected [x, z], got {_plain(cfg.get('start'))!r}")
    if not goals:
        if str(cfg.get("scene") or "").startswith("synthetic:") or scene.grid is None:
            rng = np.random.default_rng(int(cfg.seed))
            d_start, goals = default_route_goals(scene, fmap, loaded.action_names, rng)
            start = d_start if start is None else start
        else:
            raise ConfigError("no goals given: use goals=[[x,z],...] or goals_file=PATH")
    check_actions(goals, loaded.action_names)
    if start is None:
        start = default_start(fmap, goals[0].xz)
    route = plan_route(start, goals, fmap if str(cfg.path) == "astar" else None, str(cfg.path),
                       float(cfg.subgoal_spacing))
    if str(cfg.path) == "straight" and fmap is not None:
        # Straight lines still need valid points.
        from motiongen.sampling.goals import check_point

        check_point(fmap, start, "start")
        for i, g in enumerate(goals):
            check_point(fmap, g.xz, f"goal {i + 1}", g.interacts)

    lc = cfg.get("loop") or {}
    loop = LoopConfig(**{k: (None if v is None else v) for k, v in OmegaConf.to_container(lc).items()}) \
        if lc else LoopConfig()
    gen = torch.Generator(device=loaded.device if loaded.device.type != "mps" else "cpu").manual_seed(int(cfg.seed))
    yaw = cfg.get("start_yaw")
    print(f"sampling: {ckpt} (step {loaded.step}, {loaded.precision} layers) in {scene.label}, {len(goals)} goal(s), "
          f"{len(route.subgoals)} subgoals, {cfg.num_samples} sample(s)", flush=True)
    from motiongen.body.model import load_body_model

    body_model = load_body_model(cfg.get("body_model"))
    motion = generate(loaded, scene.grid, route.start, route=route, walkable=fmap,
                      start_yaw=None if yaw is None else float(yaw), objects=scene.objects, sampler=sampler,
                      num_samples=int(cfg.num_samples), generator=gen, loop=loop, body_model=body_model,
                      log=(lambda m: print(m, flush=True)) if _bool(cfg, "verbose") else None)

    out.mkdir(parents=True, exist_ok=True)
    stage = StagedOutputs(out)
    written = []
    try:
        extra = {"ckpt": str(ckpt), "scene": scene.label, "sampler": sampler.sampler, "steps": sampler.steps,
                 "eta": sampler.eta, "guidance_scale": sampler.guidance_scale, "seed": int(cfg.seed),
                 "precision": loaded.precision}
        tmp = stage.tmp("motion.npz")
        np.savez(tmp, **motion_arrays(motion, extra))
        stage.add(tmp, "motion.npz")
        goals_xz = np.stack([g.xz for g in route.goals])
        if _bool(cfg, "plot", True):
            from motiongen.export.plots import plot_trajectories

            tmp = plot_trajectories(stage.tmp("trajectories.png"), motion.joints, fmap, route.path, route.subgoals,
                                    goals_xz, motion.arrival_frame, title=f"{scene.label} — {ckpt.name}")
            stage.add(tmp, "trajectories.png")
        if _bool(cfg, "video", True):
            from motiongen.export.video import render_video, video_suffix

            tv = time.perf_counter()
            vfps = cfg.get("video_fps")
            tmp = render_video(stage.tmp("motion" + video_suffix()), motion.joints, motion.fps,
                               loaded.joint_set.parents, scene.grid, fmap, route.path, route.subgoals, goals_xz,
                               video_fps=None if vfps is None else float(vfps), title=f"{scene.label}",
                               bodies=motion.bodies, body_model=body_model, planted=motion.planted,
                               contact_joints=loaded.layout.contact_joints, style=str(cfg.get("video_style", "body")))
            stage.add(tmp, "motion" + tmp.suffix)
            print(f"video: {motion.joints.shape[1] / motion.fps:.1f} s rendered in {time.perf_counter() - tv:.1f} s",
                  flush=True)
        S = motion.num_samples
        if _bool(cfg, "bvh"):
            from motiongen.bvh.export import export_bvh

            for s in range(S):
                name = "motion.bvh" if S == 1 else f"motion_{s}.bvh"
                stage.add(export_bvh(stage.tmp(name), motion.joints[s], motion.fps), name)
        if _bool(cfg, "body"):
            from motiongen.body.fit import fit_joints, save_amass_npz

            for s in range(S):
                name = "body.npz" if S == 1 else f"body_{s}.npz"
                if motion.bodies is not None:
                    # The motion is already a body: its own SMPL-X parameters, no second fit.
                    fit = motion.bodies[s].as_fit(motion.joints[s])
                else:
                    fit = fit_joints(motion.joints[s][:, :22], body_model)
                    print(f"body fit sample {s}: MPJPE {fit.mpjpe * 1000:.1f} mm", flush=True)
                stage.add(save_amass_npz(stage.tmp(name), fit, motion.fps), name)
        figures = body_figures(motion)
        lines = summary_lines(motion, sampler, figures)
        summary = {"frames": int(motion.joints.shape[1]), "fps": motion.fps, "duration_s": motion.duration,
                   "body": figures,
                   "num_samples": S, "episodes": int(len(motion.episode_starts)), "completed": motion.completed,
                   "arrival_error_m": np.where(np.isfinite(motion.arrival_error), motion.arrival_error, -1).tolist(),
                   "arrival_error_body_m": np.where(np.isfinite(motion.arrival_error_body),
                                                    motion.arrival_error_body, -1).tolist(),
                   "generation_s": motion.wall_time, "real_time_factor": motion.real_time_factor,
                   "total_s": time.perf_counter() - t0, "sampler": sampler.__dict__,
                   "precision": loaded.precision}
        tmp = stage.tmp("summary.json")
        tmp.write_text(json.dumps(summary, indent=2))
        stage.add(tmp, "summary.json")
        written = stage.commit()
    except BaseException:
        stage.abort()
        raise
    for line in lines:
        print(line, flush=True)
    print("wrote: " + ", ".join(str(p) for p in written), flush=True)
    return summary


def _plain(v):
    """OmegaConf containers -> plain lists / scalars."""
    from omegaconf import DictConfig, ListConfig, OmegaConf

    if isinstance(v, (ListConfig, DictConfig)):
        return OmegaConf.to_container(v, resolve=True)
    return v
