"""`motiongen sample` (sample.py): resolve the scene, goals and checkpoint named by the keys,
generate, write the outputs. The keys: SampleConfig (motiongen/sampling/sample_config.py)
through configs/sample.yaml; docs/sampling.md.

Outputs (all written to temporary names in `out` and renamed at the very end, so a failed
run leaves nothing half-written): motion.npz, motion.mp4 (or .gif), trajectories.png,
summary.json, and on request body_<s>.npz (SMPL-X, AMASS layout), motion_<s>.bvh and
motion.glb + scene.glb (skinned glTF, `motiongen.export.gltf`). The
directory is locked while the run uses it, and a second run there replaces the first one's
whole set (docs/config.md, "Outputs and locks").
"""

from __future__ import annotations

import json
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from motiongen.body.fit import fit_joints, save_amass_npz
from motiongen.body.model import load_body_model
from motiongen.bvh.export import export_bvh
from motiongen.commands.hydra_app import hydra_command
from motiongen.errors import ConfigError
from motiongen.export.camera import CameraPath
from motiongen.export.gltf import write_motion_glb, write_scene_glb
from motiongen.export.trajectory_plot import plot_trajectories
from motiongen.export.video import render_video, video_suffix
from motiongen.export.video_camera import camera_path, object_points
from motiongen.loading.build import LoadedModel
from motiongen.loading.keys import checkpoint_path, load_checkpoint_model, noise_generator
from motiongen.output_lock import OutputLock, claim_run_dir, refuse_output_over_input
from motiongen.routing import WalkableMap
from motiongen.sampling.autoregressive import generate
from motiongen.sampling.goal_input import load_goals_file, parse_goals
from motiongen.sampling.goals import Goal, Route, check_actions, check_point, plan_route
from motiongen.sampling.interactions import aim_at_objects
from motiongen.sampling.outputs import body_figures, failure_lines, motion_arrays, summary_lines
from motiongen.sampling.sample_config import SampleConfig
from motiongen.sampling.scene_setup import SceneInfo, default_route_goals, default_start, scene_for_keys
from motiongen.sampling.settings import Motion, SamplerSettings, resolve_sampler
from motiongen.staging import StagedOutputs, record_outputs

# The files `write_outputs` may write.
OUTPUT_NAMES = re.compile(r"motion\.(npz|mp4|gif|bvh|glb)|scene\.glb|summary\.json|trajectories\.png|body\.npz|motion_\d+\.bvh|body_\d+\.npz")


@dataclass
class Sampled:
    """One run's model, scene, route and motion: what the output files are written from."""

    ckpt: Path
    loaded: LoadedModel
    scene: SceneInfo
    fmap: WalkableMap | None       # the walkable floor map; None on an empty floor
    route: Route
    motion: Motion
    body_model: object             # the motion's BodyModel


def run(cfg: SampleConfig, default_out: Path) -> dict:
    """The whole `sample` run. Returns the summary dict."""
    t0 = time.perf_counter()
    ckpt = checkpoint_path(cfg)
    goals, file_start = given_goals(cfg)             # cheap checks first: the goals before the model
    # One live run per directory; without out= each run gets a directory of its own.
    with OutputLock(cfg.out, "sample") if cfg.out else claim_run_dir(default_out, "sample") as lock:
        refuse_over_inputs(cfg, lock.dir, ckpt)
        return _generate_and_write(cfg, lock.dir, ckpt, goals, file_start, t0)


def refuse_over_inputs(cfg: SampleConfig, out: Path, ckpt: Path) -> None:
    """No output file may replace a file the run reads (checkpoint, goals, scene, body model)."""
    for inp in (ckpt, cfg.goals_file, cfg.body_model, cfg.scene):
        if inp and OUTPUT_NAMES.fullmatch(Path(inp).name):
            refuse_output_over_input(out / Path(inp).name, [inp], "out")


def _generate_and_write(cfg: SampleConfig, out: Path, ckpt: Path, goals: list[Goal], file_start, t0: float) -> dict:
    loaded = load_checkpoint_model(cfg)
    sampler = resolve_sampler(SamplerSettings.of(cfg), loaded)          # a student's steps unless steps= is given
    scene, fmap = scene_for_keys(cfg, loaded.config)
    route = plan(cfg, scene, fmap, loaded.action_names, goals, file_start)
    print(f"sampling: {ckpt} (step {loaded.step}, {loaded.precision} layers) in {scene.label}, {len(route.goals)} "
          f"goal(s), {len(route.subgoals)} subgoals, {cfg.num_samples} sample(s)", flush=True)
    body_model = load_body_model(cfg.body_model)
    gen = noise_generator(loaded, cfg.seed)
    motion = generate(loaded, scene.grid, route=route, walkable=fmap, start_yaw=cfg.start_yaw,
                      objects=scene.objects, sampler=sampler, num_samples=cfg.num_samples,
                      generator=gen, loop=cfg.loop, body_model=body_model,
                      log=(lambda m: print(m, flush=True)) if cfg.verbose else None)
    summary, lines, written = write_outputs(cfg, out, Sampled(ckpt, loaded, scene, fmap, route, motion, body_model), t0)
    for line in lines:
        print(line, flush=True)
    print("wrote: " + ", ".join(str(p) for p in written), flush=True)
    return summary


def given_goals(cfg: SampleConfig) -> tuple[list[Goal], np.ndarray | None]:
    """The user's goals, from goals_file= or the command line (not both), and the goals file's
    start (None when it gives none)."""
    file_goals, file_start = ([], None)
    if cfg.goals_file:
        file_goals, file_start = load_goals_file(cfg.goals_file, cfg.action_seconds)
    cli_goals = parse_goals(cfg.goals, cfg.actions, cfg.durations, cfg.action_seconds)
    if file_goals and cli_goals:
        raise ConfigError("give goals either on the command line (goals=...) or in goals_file=, not both")
    return file_goals or cli_goals, file_start


def plan(cfg: SampleConfig, scene: SceneInfo, fmap: WalkableMap | None, action_names, goals: list[Goal],
         file_start: np.ndarray | None) -> Route:
    """The route through the goals from the start: the user's, or a default route where the
    user gives no goals (in a synthetic scene or on an empty floor)."""
    start = np.asarray(cfg.start, np.float64) if cfg.start is not None else file_start
    if start is not None and np.asarray(start).shape != (2,):
        raise ConfigError(f"start: expected [x, z], got {cfg.start!r}")
    if not goals:
        if str(cfg.scene or "").startswith("synthetic:") or scene.grid is None:
            d_start, goals = default_route_goals(scene, fmap, action_names, np.random.default_rng(cfg.seed))
            start = d_start if start is None else start
        else:
            raise ConfigError("no goals given: use goals=[[x,z],...] or goals_file=PATH")
    check_actions(goals, action_names)
    if start is None:
        start = default_start(fmap, goals[0].xz)
    if cfg.approach > 0:
        aim_at_objects(goals, scene.objects, cfg.loop.hand_actions)
    route = plan_route(start, goals, fmap if cfg.path == "astar" else None, cfg.path, cfg.subgoal_spacing,
                       approach=cfg.approach)
    if cfg.path == "straight" and fmap is not None:
        # Straight lines still need valid points.
        check_point(fmap, start, "start")
        for i, g in enumerate(goals):
            check_point(fmap, g.xz, f"goal {i + 1}", g.interacts)
    return route


def write_outputs(cfg: SampleConfig, out: Path, res: Sampled, t0: float) -> tuple[dict, list[str], list[Path]]:
    """Every output file, staged and renamed together: (summary, report lines, files written)."""
    out.mkdir(parents=True, exist_ok=True)
    stage = StagedOutputs(out)
    try:
        sampler = resolve_sampler(SamplerSettings.of(cfg), res.loaded)
        extra = {"ckpt": str(res.ckpt), "scene": res.scene.label, "sampler": sampler.sampler, "steps": sampler.steps,
                 "eta": sampler.eta, "guidance_scale": sampler.guidance_scale, "seed": cfg.seed,
                 "precision": res.loaded.precision}
        camera = video_camera(cfg, res) if cfg.video else None
        tmp = stage.tmp("motion.npz")
        np.savez(tmp, **motion_arrays(res.motion, extra), **(camera.arrays() if camera is not None else {}))
        stage.add(tmp, "motion.npz")
        goals_xz = np.stack([g.xz for g in res.route.goals])
        if cfg.plot:
            tmp = plot_trajectories(stage.tmp("trajectories.png"), res.motion.joints, res.fmap, res.route.path,
                                    res.route.subgoals, goals_xz, res.motion.arrival_frame,
                                    title=f"{res.scene.label} — {res.ckpt.name}")
            stage.add(tmp, "trajectories.png")
        if cfg.video:
            write_video(stage, cfg, res, goals_xz, camera)
        write_exports(stage, cfg, res)
        figures = body_figures(res.motion)
        lines = summary_lines(res.motion, sampler, figures)
        summary = summary_dict(res, sampler, figures, t0)
        tmp = stage.tmp("summary.json")
        tmp.write_text(json.dumps(summary, indent=2))
        stage.add(tmp, "summary.json")
        written = stage.commit()
    except BaseException:
        stage.abort()
        raise
    record_outputs(out, "sample", written, keep=[res.ckpt, cfg.goals_file])   # the previous run's extra files go
    return summary, lines, written


def video_camera(cfg: SampleConfig, res: Sampled) -> CameraPath:
    """The video's camera over sample 0 (`video_camera`): what the video shows and motion.npz keeps."""
    motion = res.motion
    return camera_path(cfg.video_camera, motion.joints[0], motion.fps, res.scene.grid, res.scene.mesh,
                       object_points(res.scene.objects))


def write_video(stage: StagedOutputs, cfg: SampleConfig, res: Sampled, goals_xz: np.ndarray,
                camera: CameraPath) -> None:
    motion, tv = res.motion, time.perf_counter()
    tmp = render_video(stage.tmp("motion" + video_suffix()), motion.joints, motion.fps,
                       res.loaded.joint_set.parents, res.scene.grid, res.fmap, res.route.path, res.route.subgoals,
                       goals_xz, video_fps=cfg.video_fps, title=f"{res.scene.label}", bodies=motion.bodies,
                       body_model=res.body_model, planted=motion.planted,
                       contact_joints=res.loaded.layout.contact_joints, style=cfg.video_style, camera=camera,
                       scene_mesh=res.scene.mesh)
    stage.add(tmp, "motion" + tmp.suffix)
    print(f"video: {motion.joints.shape[1] / motion.fps:.1f} s rendered in {time.perf_counter() - tv:.1f} s", flush=True)


def write_exports(stage: StagedOutputs, cfg: SampleConfig, res: Sampled) -> None:
    """On request, each sample as BVH (bvh=true), as SMPL-X parameters (body=true), and all of
    them as skinned glTF (gltf=true)."""
    motion, S = res.motion, res.motion.num_samples
    if cfg.bvh:
        for s in range(S):
            name = "motion.bvh" if S == 1 else f"motion_{s}.bvh"
            stage.add(export_bvh(stage.tmp(name), motion.joints[s], motion.fps), name)
    fits = body_fits(res) if cfg.body or cfg.gltf else None
    if cfg.body:
        for s in range(S):
            name = "body.npz" if S == 1 else f"body_{s}.npz"
            stage.add(save_amass_npz(stage.tmp(name), fits[s], motion.fps), name)
    if cfg.gltf:
        # The motion's own bodies where it has them (rotation matrices as solved), else the fits.
        bodies = motion.bodies if motion.bodies is not None else fits
        stage.add(write_motion_glb(stage.tmp("motion.glb"), bodies, res.body_model, motion.fps), "motion.glb")
        if res.scene.mesh is not None:
            stage.add(write_scene_glb(stage.tmp("scene.glb"), res.scene.mesh), "scene.glb")


def body_fits(res: Sampled) -> list:
    """Each sample's SMPL-X parameters (`FitResult`): the motion's own body where it is one (no
    second fit), else a fit to its joints (body projection off)."""
    motion = res.motion
    if motion.bodies is not None:
        return [body.as_fit(joints) for body, joints in zip(motion.bodies, motion.joints)]
    fits = []
    for s in range(motion.num_samples):
        fits.append(fit_joints(motion.joints[s][:, :22], res.body_model))
        print(f"body fit sample {s}: MPJPE {fits[-1].mpjpe * 1000:.1f} mm", flush=True)
    return fits


def summary_dict(res: Sampled, sampler: SamplerSettings, figures: dict, t0: float) -> dict:
    """summary.json: the motion's size and rate, its body figures, arrivals and timings."""
    motion = res.motion
    return {"frames": int(motion.joints.shape[1]), "fps": motion.fps, "duration_s": motion.duration,
            "body": figures,
            "num_samples": motion.num_samples, "episodes": int(len(motion.episode_starts)),
            "completed": motion.completed, "goals_failed": motion.failed_goals(),
            "arrival_error_m": np.where(np.isfinite(motion.arrival_error), motion.arrival_error, -1).tolist(),
            "arrival_error_body_m": np.where(np.isfinite(motion.arrival_error_body),
                                             motion.arrival_error_body, -1).tolist(),
            "generation_s": motion.wall_time, "real_time_factor": motion.real_time_factor,
            "total_s": time.perf_counter() - t0, "sampler": sampler.__dict__,
            "precision": res.loaded.precision}


# The exit status of a run that wrote its outputs but did not reach every goal (2: bad input).
INCOMPLETE = 3


def exit_status(summary: dict) -> int:
    """0 when every sample reached every goal; else INCOMPLETE, each goal not reached named on
    stderr (summary.json's `goals_failed`)."""
    for line in failure_lines(summary["goals_failed"]):
        print(line, file=sys.stderr, flush=True)
    return 0 if summary["completed"] else INCOMPLETE


def _app(cfg: DictConfig, run_dir: Path) -> None:
    status = exit_status(run(OmegaConf.to_object(cfg), run_dir))
    if status:
        sys.exit(status)


main = hydra_command("sample", _app)


if __name__ == "__main__":
    main()
