"""Everything `motiongen serve` starts from its keys: the model, the scene and its walkable map,
the body, the live sampler (warmed up), the session and the `App` the web server serves."""

from __future__ import annotations

import numpy as np

from motiongen.body.model import load_body_model
from motiongen.export.gltf import body_glb_bytes
from motiongen.loading.keys import load_checkpoint_model, noise_generator
from motiongen.sampling.goal_input import parse_goals, parse_point
from motiongen.sampling.live import LiveSampler
from motiongen.sampling.scene_setup import default_start, scene_for_keys
from motiongen.sampling.settings import SamplerSettings
from motiongen.serve.server import App
from motiongen.serve.serve_config import ServeConfig
from motiongen.serve.session import LiveSession
from motiongen.skeleton import BODY_JOINT_NAMES, BODY_PARENTS


def build_app(cfg: ServeConfig, log=print) -> App:
    """The App for `cfg`, its session not yet started. ConfigError for a bad checkpoint, scene,
    start or goals."""
    loaded = load_checkpoint_model(cfg)
    scene, fmap = scene_for_keys(cfg, loaded.config)
    start = parse_point(cfg.start, "start") if cfg.start is not None else default_start(fmap, None)
    body_model = load_body_model(cfg.body_model)
    gen = noise_generator(loaded, cfg.seed)
    log(f"serve: {cfg.ckpt} (step {loaded.step}, {loaded.precision} layers) in {scene.label}; warming up")
    live = LiveSampler(loaded, scene.grid, fmap, scene.objects, body_model=body_model, start_xz=start,
                       start_yaw=cfg.start_yaw or 0.0, sampler=SamplerSettings.of(cfg), loop=cfg.loop,
                       generator=gen, subgoal_spacing=cfg.subgoal_spacing, approach=cfg.approach)
    session = LiveSession(live, fmap, lead_s=cfg.lead_s, max_pending=cfg.max_pending)
    goals = parse_goals(cfg.goals, cfg.actions, cfg.durations, cfg.action_seconds)
    if goals:
        session.add_goals(goals)
    mesh = scene.mesh
    scene_glb = mesh.export(file_type="glb") if mesh is not None else None
    return App(session, app_info(loaded, fmap, scene_glb is not None, cfg.max_pending, live.out_fps), scene_glb,
               body_glb_bytes(body_model, live.body.betas[0]), body_model, cfg.action_seconds)


def app_info(loaded, fmap, has_scene: bool, max_pending: int, fps: float) -> dict:
    """/api/info: what the page needs to know once."""
    names = list(loaded.action_names)
    actions = ["walk"] + [a for a in names if a != "walk"]
    bounds = None if fmap is None else np.asarray(fmap.bounds, np.float64).tolist()
    return {"actions": actions, "default_action": "walk", "fps": float(fps),
            "joint_names": list(BODY_JOINT_NAMES), "parents": list(BODY_PARENTS), "bounds": bounds,
            "floor_y": 0.0, "scene_url": "/api/scene.glb" if has_scene else None, "body_url": "/api/body.glb",
            "max_pending": int(max_pending)}
