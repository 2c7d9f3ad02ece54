"""`sample.py`: resolve the scene, goals and checkpoint from a config, generate, write outputs.

Outputs (all written to temporary names in `out` and renamed at the very end, so a failed
run leaves nothing half-written): motion.npz, motion.mp4 (or .gif), trajectories.png,
summary.json, and on request body_<s>.npz (SMPL-X, AMASS layout) and motion_<s>.bvh.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from motiongen.errors import ConfigError, DataError
from motiongen.sampling.autoregressive import LoopConfig, Motion, SamplerSettings, generate
from motiongen.routing import WalkableMap, walkable_map
from motiongen.sampling.goal_input import load_goals_file, parse_goals
from motiongen.sampling.goals import Goal, check_actions, plan_route
from motiongen.staging import StagedOutputs


@dataclass
class SceneInfo:
    grid: object | None                     # OccupancyGrid or None (empty floor)
    label: str
    objects: list = field(default_factory=list)   # [(OccupancyGrid, pose (4, 4))]
    synthetic: object | None = None         # motiongen.data.synthetic.scenes.Scene when known


def _dataset_scene(ds, scene_id: int, label: str, with_objects: bool) -> SceneInfo:
    if scene_id not in ds.scenes:
        raise ConfigError(f"scene {label}: dataset {ds.root} has no scene {scene_id} "
                          f"(scenes: {', '.join(str(s) for s in sorted(ds.scenes)[:20])}...)")
    grid = ds.grid(scene_id)
    objects = []
    if with_objects and ds.object_ids is not None:
        # Movable objects at their resting poses: the first frame of the scene's first sequence.
        seq = next((s for s in ds.sequences if s.scene == scene_id), None)
        if seq is not None:
            from motiongen.data.voxelize import voxelize_mesh

            ids = np.asarray(ds.object_ids[seq.start])
            for slot, oid in enumerate(ids):
                mesh = ds.object_mesh(int(oid)) if oid >= 0 else None
                if mesh is not None:
                    objects.append((voxelize_mesh(mesh, voxel_size=grid.voxel_size),
                                    np.asarray(ds.object_poses[seq.start, slot], np.float64)))
    return SceneInfo(grid, label, objects)


def resolve_scene(spec, ckpt_config=None, voxel_size: float = 0.02, up: str = "y", objects: bool = True) -> SceneInfo:
    """scene=None | 'none' | mesh file/folder | 'synthetic:ID' | 'dataset:PATH:ID'."""
    if spec is None or str(spec).strip().lower() in ("", "none", "null", "empty"):
        return SceneInfo(None, "empty floor")
    spec = str(spec)
    if spec.startswith("synthetic:"):
        sid = _scene_id(spec.split(":", 1)[1], spec)
        from motiongen.data.sources import DataConfig, open_dataset

        data = ckpt_config.get("data") if ckpt_config is not None else None
        if data is not None and data.get("source") == "synthetic":
            dcfg = DataConfig(source="synthetic", size=str(data.get("size", "default")), seed=int(data.get("seed", 0)))
        else:
            dcfg = DataConfig(source="synthetic")
        ds = open_dataset(dcfg, verbose=True)
        info = _dataset_scene(ds, sid, spec, objects)
        info.synthetic = _synthetic_layout(sid, dcfg.seed, info.grid)
        return info
    if spec.startswith("dataset:"):
        rest = spec[len("dataset:"):]
        root, _, sid = rest.rpartition(":")
        if not root:
            raise ConfigError(f"scene={spec!r}: expected dataset:PATH:ID")
        from motiongen.data.format import MotionDataset

        return _dataset_scene(MotionDataset.open(root), _scene_id(sid, spec), spec, objects)
    from motiongen.data.scene import load_scene_grid

    return SceneInfo(load_scene_grid(spec, voxel_size=voxel_size, up=up), spec)


def _scene_id(s: str, spec: str) -> int:
    try:
        return int(s)
    except ValueError:
        raise ConfigError(f"scene={spec!r}: scene id must be an integer, got {s!r}") from None


def _synthetic_layout(scene_id: int, seed: int, grid):
    """The generator's layout of a synthetic scene (seats, beds), rebuilt from its seed; None if
    it does not reproduce the stored grid (another generator version)."""
    try:
        from motiongen.data.synthetic.scenes import make_scene

        scene = make_scene(scene_id, np.random.default_rng([seed, scene_id]))
        g = scene.grid()
        if tuple(g.shape) == tuple(grid.shape) and np.array_equal(np.asarray(g.bits), np.asarray(grid.bits)):
            return scene
    except Exception:  # the layout is a nicety for the demo route; the grid is what matters
        pass
    return None


def default_route_goals(scene: SceneInfo, fmap: WalkableMap | None, action_names, rng: np.random.Generator):
    """(start (2,), goals) for a scene when the user gives none: in a synthetic scene, walk to
    a chair and sit on it (if the vocabulary has 'sit'), then on to a far free point; otherwise
    a tour of free points far apart. On an empty floor: a 3 m walk with a turn."""
    if fmap is None:
        return np.zeros(2), [Goal([0.0, 2.0]), Goal([1.5, 3.0])]
    import scipy.ndimage as ndi

    # Components of the coarse map A* plans on (narrow gaps may be open only at 2 cm).
    cfree, corigin, ccell = fmap.coarse(0.05)
    labels, n = ndi.label(cfree)
    if n == 0:
        raise ConfigError(f"scene {scene.label} has no walkable floor for body_radius={fmap.body_radius} m")
    biggest = 1 + int(np.argmax(ndi.sum(np.ones_like(labels), labels, index=np.arange(1, n + 1))))
    cells = np.argwhere(labels == biggest)
    pts = corigin + (cells + 0.5) * ccell                                                    # (N, 2)
    centre = pts.mean(0)
    start = pts[np.argmin(np.linalg.norm(pts - centre, axis=-1))]
    chosen = [start]
    goals: list[Goal] = []

    def tour(k: int) -> list[Goal]:
        # Farthest-point tour over the walkable component, 0.3 m back from its edge.
        out = []
        for _ in range(k):
            d = np.min(np.stack([np.linalg.norm(pts - c, axis=-1) for c in chosen]), axis=0)
            p = pts[int(np.argmax(d))]
            v = centre - p
            p2 = p + 0.3 * v / max(np.linalg.norm(v), 1e-9)
            p = p2 if fmap.is_free(p2) else p
            out.append(Goal(p))
            chosen.append(p)
        return out

    lower = {a.lower(): a for a in action_names}
    if scene.synthetic is not None and scene.synthetic.seats and "sit" in lower:
        seats = list(scene.synthetic.seats)
        for i in rng.permutation(len(seats)):
            seat = seats[int(i)]
            trial = [Goal(np.asarray(seat.surface, np.float64)[[0, 2]], lower["sit"], 3.0)]
            stand = np.asarray(seat.stand_xz, np.float64)
            if fmap.is_free(stand):
                trial.insert(0, Goal(stand))
            try:
                plan_route(start, [Goal(tour(1)[0].xz)] + trial, fmap)
            except ConfigError:
                chosen.pop()
                continue
            goals = [Goal(chosen[-1])] + trial
            break
    goals += tour(3 - min(len(goals), 2) if goals else 3)
    try:
        plan_route(start, goals, fmap)
    except ConfigError:
        chosen[:] = [start]
        goals = tour(3)
    return start, goals


def _default_start(fmap: WalkableMap | None, first_goal: np.ndarray) -> np.ndarray:
    if fmap is None:
        return np.zeros(2)
    (x0, z0), (x1, z1) = fmap.bounds
    p = fmap.nearest_free(np.array([(x0 + x1) / 2, (z0 + z1) / 2]))
    if p is None:
        raise ConfigError("the scene has no walkable floor to start from")
    return p


# ---------------------------------------------------------------------------------------
# Outputs


def motion_arrays(motion: Motion, extra: dict | None = None) -> dict:
    """The motion.npz payload (no pickled objects: strings as unicode arrays)."""
    r = motion.route
    goals = np.stack([g.xz for g in r.goals]) if r.goals else np.zeros((0, 2))
    d = {
        "joints": motion.joints.astype(np.float32),                                      # (S, T, J, 3)
        "fps": np.float64(motion.fps),
        "joint_names": np.array(motion.joint_names),
        "model_joints": motion.model_joints.astype(np.float32),                          # (S, Tm, J, 3)
        "model_fps": np.float64(motion.model_fps),
        "start": np.asarray(r.start, np.float64),
        "goals": goals.astype(np.float64),                                                # (G, 2) x, z
        "goal_actions": np.array([g.action or "" for g in r.goals]),
        "goal_durations": np.array([g.duration for g in r.goals], np.float64),
        "path": r.path.astype(np.float64),                                                # (N, 2)
        "path_mode": np.array(r.mode),
        "subgoals": r.subgoals.astype(np.float64),                                        # (K, 2)
        "subgoal_goal": r.subgoal_leg.astype(np.int64),
        "actions": motion.actions.astype(np.int16),                                       # (S, T), -1 = none
        "action_names": np.array(motion.action_names),
        "episode_starts": motion.episode_starts.astype(np.int64),                        # (E,) output frames
        "episode_kinds": np.array(motion.episode_kinds),
        "arrival_frames": motion.arrival_frame.astype(np.int64),                         # (S, G)
        "arrival_error": motion.arrival_error.astype(np.float64),
        "arrival_error_body": motion.arrival_error_body.astype(np.float64),
        "finish_frame": motion.finish_frame.astype(np.int64),
        "completed": np.bool_(motion.completed),
        "wall_time": np.float64(motion.wall_time),
    }
    if motion.joints_raw is not None:
        d["joints_raw"] = motion.joints_raw.astype(np.float32)                           # (S, T, J, 3) network's own
    if motion.planted is not None:
        d["planted"] = motion.planted                                                     # (S, T, C) bool
        d["contact_joints"] = np.array(motion.contact_joints)
    if motion.bodies is not None:
        d["betas"] = np.stack([b.betas for b in motion.bodies]).astype(np.float32)       # (S, nβ) one body each
    for k, v in (extra or {}).items():
        d[k] = np.array(v)
    return d


def body_figures(motion: Motion) -> dict:
    """Per sample, what the motion is as a body (docs/metrics.md): bone-length CV and largest
    deviation, grounded-toe median slide speed, foot skating; for the output and for the
    network's own joints. Lists of S values."""
    from motiongen.eval import metrics as M
    from motiongen.skeleton import joint_set_for

    parents = joint_set_for(motion.joint_names).parents
    out: dict[str, list] = {}
    for tag, joints in (("", motion.joints), ("network_", motion.joints_raw)):
        if joints is None:
            continue
        for s in range(motion.num_samples):
            for k, v in M.body_metrics(joints[s], motion.fps, parents).items():
                out.setdefault(tag + k, []).append(float(v))
    return out


def summary_lines(motion: Motion, sampler: SamplerSettings, figures: dict | None = None) -> list[str]:
    """The printed summary; figures: `body_figures(motion)` when already computed."""
    S, T = motion.joints.shape[:2]
    lines = [f"motion: {S} sample(s) x {T} frames = {motion.duration:.1f} s at {motion.fps:g} fps, "
             f"{len(motion.episode_starts)} episodes, {sampler.sampler.upper()}-{sampler.steps}"
             + (f", guidance {sampler.guidance_scale:g}" if sampler.guidance_scale != 1 else "")]
    for g, goal in enumerate(motion.route.goals):
        errs = motion.arrival_error[:, g]
        body = motion.arrival_error_body[:, g]
        reached = np.isfinite(errs)
        what = f" then {goal.action} {goal.duration:g} s" if goal.action else ""
        if reached.any():
            at = motion.arrival_frame[reached, g] / motion.fps
            lines.append(f"goal {g + 1} ({goal.xz[0]:.2f}, {goal.xz[1]:.2f}){what}: reached by {reached.sum()}/{S}, "
                         f"pelvis error {np.nanmean(errs):.3f} m (hips {np.nanmean(body):.3f} m), "
                         f"at {at.mean():.1f} s")
        else:
            lines.append(f"goal {g + 1} ({goal.xz[0]:.2f}, {goal.xz[1]:.2f}){what}: not reached")
    f = body_figures(motion) if figures is None else figures
    if f:
        lines.append("body: bone-length CV {} (network {}), largest bone deviation {} (network {}), "
                     "grounded-toe slide {} m/s (network {}), foot skating {} (network {})".format(
                         *[", ".join(f"{v:.3f}" for v in f.get(tag + k, [])) or "n/a"
                           for k in ("bone_cv", "bone_max_dev", "slide_mps", "foot_skating")
                           for tag in ("", "network_")]))
    lines.append(f"wall time {motion.wall_time:.1f} s, real-time factor {motion.real_time_factor:.2f} "
                 f"({S} x {motion.duration:.1f} s of motion / {motion.wall_time:.1f} s)")
    return lines


# ---------------------------------------------------------------------------------------


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

    from motiongen.training.builders import load_model

    device = str(cfg.device)
    loaded = load_model(ckpt, device)
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
        start = _default_start(fmap, goals[0].xz)
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
    print(f"sampling: {ckpt} (step {loaded.step}) in {scene.label}, {len(goals)} goal(s), "
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
                 "eta": sampler.eta, "guidance_scale": sampler.guidance_scale, "seed": int(cfg.seed)}
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
            from motiongen.export.bvh import export_bvh

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
                   "total_s": time.perf_counter() - t0, "sampler": sampler.__dict__}
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
