"""The keys of `motiongen sample` (sample.py): a structured config registered with Hydra
(motiongen/config.py), so every default lives here once and OmegaConf checks each value's type
as the command line is read. docs/sampling.md explains them."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from motiongen.errors import ConfigError
from motiongen.loading.keys import CheckpointKeys
from motiongen.sampling.settings import LoopConfig, SamplerSettings


@dataclass
class SceneRouteKeys(CheckpointKeys):
    # Scene: a mesh file or folder (voxelised once, cached), synthetic:ID (the embedded
    # synthetic dataset's scene), dataset:PATH:ID, or None (empty floor).
    scene: str | None = None
    scene_up: str = "y"            # up axis of mesh files: y | z
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
    plot: bool = True
    bvh: bool = False
    body: bool = False             # the motion's SMPL-X parameters -> body.npz (AMASS layout)
    verbose: bool = False

    def __post_init__(self):
        super().__post_init__()
        if self.num_samples < 1:
            raise ConfigError(f"num_samples must be >= 1, got {self.num_samples}")
