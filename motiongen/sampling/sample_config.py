"""The keys of `motiongen sample` (sample.py): a structured config registered with Hydra
(motiongen/config.py), so every default lives here once and OmegaConf checks each value's type
as the command line is read. docs/sampling.md explains them."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from motiongen.checks import require_choice, require_fps, require_range
from motiongen.errors import ConfigError
from motiongen.export.camera import CAMERA_MODES
from motiongen.loading.keys import CheckpointKeys
from motiongen.sampling.assemble import SOLVE_METHODS
from motiongen.sampling.goal_input import parse_point
from motiongen.sampling.settings import LoopConfig, SamplerSettings


@dataclass
class SceneRouteKeys(CheckpointKeys):
    # Scene: a mesh file or folder (voxelised once, cached), synthetic:ID (the embedded
    # synthetic dataset's scene), dataset:PATH:ID, or None (empty floor).
    scene: str | None = None
    scene_up: str = "y"            # up axis of mesh files: y | z
    scene_unit: str = "m"          # length unit of mesh files: m | cm | mm (scaled to metres)
    voxel_size: float = 0.02       # metres, for mesh scenes
    objects: bool = True           # dataset scenes: add their movable objects to the occupancy queries
    # Route. Points are [x, z]; `goals=[x,z]` is one goal, `actions=sit` one action.
    start: Any = None              # [x, z]; default: a free spot (or the goals file's start)
    start_yaw: float | None = None  # radians (yaw 0 faces +z); default: facing the first subgoal
    goals: Any = None              # [[x, z], ...]
    goals_file: str | None = None  # JSON or CSV: x, z[, action[, seconds]] per goal (docs/sampling.md)
    actions: Any = None            # [name|walk, ...]: one per goal, performed on arrival
    durations: Any = None          # [seconds, ...]: one per goal; default action_seconds for goals with an action
    action_seconds: float = 3.0
    path: str = "astar"            # astar (collision-free, on the walkable floor map) | straight
    subgoal_spacing: float = 0.6   # metres between subgoals along the path
    # Metres of straight walk onto a hand action's goal (loop.hand_actions: pick up) along the line from
    # the nearest placed object within reach (`goals.approach_leg`); 0: the shortest path's own last leg.
    approach: float = 0.0
    body_radius: float = 0.25      # clearance kept from obstacles when planning (m)
    body_height: list[float] = field(default_factory=lambda: [0.1, 1.7])   # height band (m above the floor) that must be free to walk


# The keys in the order `--help` lists them: a dataclass takes the fields of its bases in reverse
# order (SceneRouteKeys with its CheckpointKeys, then SamplerSettings), then its own.
@dataclass
class SampleConfig(SamplerSettings, SceneRouteKeys):
    seed: int = 0
    num_samples: int = 1           # motions generated together in one batch
    loop: LoopConfig = field(default_factory=LoopConfig)   # the episode loop and its clean-up
    # Outputs.
    out: str | None = None         # directory; default: the Hydra run directory
    video: bool = True
    video_fps: float | None = None  # None = every frame, at the motion's rate; a number skips frames
    video_style: str = "body"      # body (the skinned mesh of the motion's body) | skeleton
    video_camera: str = "adaptive"  # adaptive (ring camera keeping body and hand in view) | follow | top
    plot: bool = True
    bvh: bool = False
    gltf: bool = False             # motion.glb (skinned body + animation per sample) and scene.glb (the scene mesh)
    body: bool = False             # the motion's SMPL-X parameters -> body.npz (AMASS layout)
    verbose: bool = False

    def __post_init__(self):
        super().__post_init__()
        check_sampler_settings(self)
        check_scene_route_keys(self)
        require_range("seed", self.seed, 0, integer=True)
        require_range("num_samples", self.num_samples, 1, MAX_SAMPLES, integer=True)
        require_fps("video_fps", self.video_fps, allow_none=True)
        require_choice("video_style", self.video_style, ("body", "skeleton"))
        require_choice("video_camera", self.video_camera, CAMERA_MODES)
        check_loop(self.loop)


# One batch of motions: beyond this the batch alone needs tens of GB (num_samples=1e6 asked for
# terabytes); run several seeds instead.
MAX_SAMPLES = 1024
MAX_STEPS = 10000                  # denoising steps: a DDPM of 1000 steps is the most a model has


def check_sampler_settings(keys: SamplerSettings) -> None:
    """The sampler's numbers (SamplerSettings checks the sampler's name and steps >= 1)."""
    require_range("steps", keys.steps, 1, MAX_STEPS, integer=True, allow_none=True)
    require_range("eta", keys.eta, 0, 1)
    require_range("guidance_scale", keys.guidance_scale, 0, 100, allow_none=True)


def check_scene_route_keys(keys: SceneRouteKeys) -> None:
    """The scene, route and device keys, before any model or scene is loaded."""
    require_range("threads", keys.threads, 0, integer=True)
    require_choice("scene_up", keys.scene_up, ("y", "z"))
    require_choice("scene_unit", keys.scene_unit, ("m", "cm", "mm"))
    # Finer than 5 mm, a room's grid runs to billions of voxels; coarser than 0.5 m the body
    # fits between voxels (the grid's size is checked again against the scene itself).
    require_range("voxel_size", keys.voxel_size, 0.005, 0.5)
    if keys.start is not None:
        parse_point(keys.start, "start")
    require_range("start_yaw", keys.start_yaw, allow_none=True)
    require_range("action_seconds", keys.action_seconds, 0, 3600)
    require_choice("path", keys.path, ("astar", "straight"))
    require_range("subgoal_spacing", keys.subgoal_spacing, 0.05, 100)
    require_range("approach", keys.approach, 0, 100)
    require_range("body_radius", keys.body_radius, 0, 2)
    band = list(keys.body_height) if keys.body_height is not None else []
    if len(band) != 2:
        raise ConfigError(f"body_height: expected [low, high] in metres, got {keys.body_height!r}")
    low = require_range("body_height[0]", band[0], 0, 3)
    require_range("body_height[1]", band[1], low, 3, lo_open=True)


def check_loop(loop: LoopConfig) -> None:
    """The episode loop's numbers (LoopConfig's fields, `loop.*`)."""
    r = require_range
    r("loop.warmup", loop.warmup, 0, 1000, integer=True)
    r("loop.transition", loop.transition, 0, 1000, integer=True, allow_none=True)
    r("loop.reach", loop.reach, 0, 100, lo_open=True, allow_none=True)
    r("loop.reach_fraction", loop.reach_fraction, 0, 10, lo_open=True)
    r("loop.tolerance", loop.tolerance, 0, 100, lo_open=True)
    r("loop.max_episodes", loop.max_episodes, 1, 100000, integer=True)
    r("loop.settle", loop.settle, 0, 1000, integer=True)
    require_fps("loop.out_fps", loop.out_fps)
    require_fps("loop.source_fps", loop.source_fps, allow_none=True)
    r("loop.smooth", loop.smooth, 0, 1000, allow_none=True)
    r("loop.seam_blend", loop.seam_blend, 0, 60, allow_none=True)
    r("loop.solve_smoothness", loop.solve_smoothness, 0, allow_none=True)
    require_choice("loop.solve", loop.solve, SOLVE_METHODS)
    r("loop.seat_offset", loop.seat_offset, -2, 2)
