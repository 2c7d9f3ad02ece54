"""The keys of `motiongen evaluate` (evaluate.py): the protocol's configuration, the sampler's
settings and the run's own keys, as one structured config registered with Hydra
(motiongen/config.py). docs/evaluation.md explains them."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from motiongen.checks import require_choice, require_range
from motiongen.cli import typed_config
from motiongen.errors import ConfigError
from motiongen.eval.pairs import SETTINGS, ProtocolConfig
from motiongen.importers.sources import DataConfig
from motiongen.loading.keys import CheckpointKeys
from motiongen.sampling.assemble import SOLVE_METHODS
from motiongen.sampling.sample_config import MAX_SAMPLES, check_loop, check_sampler_settings
from motiongen.sampling.settings import CLEANUP_STAGES, LoopConfig, SamplerSettings


# Denoising steps when `steps` is unset (a model trained by `train`): k samples x pairs x scenes x
# 2 settings motions, so fewer steps than `sample` keep the whole protocol to minutes on a CPU
# (paper-faithful: sampler=ddpm steps=100).
EVALUATE_STEPS = 10

# The splits `evaluate` runs on: the training scenes are what the model has seen.
SPLITS = ("val", "test")


@dataclass
class LoopOverrides:
    """The sampler's clean-up (LoopConfig fields), for research comparisons; None = the sampler's
    default, which is what `sample` uses."""

    project: bool | None = None     # false: the network's joints, no body (nor final solve)
    body_scale: bool | None = None  # false: windows projected at the network's size (the body crouches under a smaller one)
    foot_lock: bool | None = None   # false: no foot locking in the final solve
    foot_height: str | None = None  # network | body | free: the height a planted foot is held at
    pin_goal: bool | None = None    # true: write the goal pelvis into the result (the public code)
    smooth: float | None = None     # Gaussian sigma (output frames) before the final solve; 0 = off
    seam_blend: float | None = None  # seconds; 0 = off
    solve_smoothness: float | None = None  # final solve's joint-acceleration weight; None = by the model's frame rate
    solve: str | None = None        # final solve: refined | lbfgs | joint-space (docs/sampling.md)
    swing_clearance: bool | None = None  # false: the final solve may pull a swinging foot below its predicted height
    swing_lift: bool | None = None  # false: a swing stays as low as the network drew it (no data-height arc)
    seat_shift: bool | None = None  # false: seated bodies are not moved onto their seats
    hand_goal_on_arrival: bool | None = None  # false: only the pick-up's own episodes get the hand goal
    facing_goal: bool | None = None  # false: a checkpoint trained with a facing goal is not given one
    facing_on_arrival: bool | None = None  # true: ... and it is given one as it walks onto a pick-up's spot
    reach_fraction: float | None = None  # the look-ahead's reach: this x the training windows' farthest pelvis offset


@dataclass
class EvaluateScope(CheckpointKeys):
    # One checkpoint, or a list of them (one recipe trained with several seeds): the report gives
    # each figure's mean over them and its spread.
    ckpt: Any = None
    # The `data` group: None = the checkpoint's own data config (its dataset's test split); or
    # data=small|synthetic|dataset ... (a DataConfig once chosen; untyped until then, since
    # OmegaConf cannot set `data.root=...` on an empty typed node)
    data: Any = None
    # The split whose scenes are evaluated: `val` to choose settings and defaults, `test` to report
    # a recipe once those are fixed (docs/evaluation.md, "Validation and test").
    split: str = "test"
    scenes: Any = None              # subset of the split's scene ids, e.g. [91,92]; None = all of them
    settings: Any = field(default_factory=lambda: list(SETTINGS))
    # BVH files or folders: a "real mocap" row in the Body table, measured the same way (e.g.
    # mocap=/usr/share/assimp/models/BVH from Debian's assimp-testmodels).
    mocap: Any = None


# The keys in the order `--help` lists them: a dataclass takes the fields of its bases in reverse
# order (EvaluateScope with its CheckpointKeys, ProtocolConfig, SamplerSettings), then its own.
@dataclass
class EvaluateConfig(SamplerSettings, ProtocolConfig, EvaluateScope):
    # None = EVALUATE_STEPS, or a distilled student's own step count (`resolve_sampler`).
    steps: int | None = None
    loop: LoopOverrides = field(default_factory=LoopOverrides)
    # Outputs.
    out: str | None = None          # directory; default: the Hydra run directory
    # Worker processes: each (checkpoint, setting) is evaluated in a process of its own, this
    # many at a time, with one torch thread each unless `threads` is set (the protocol's small
    # batches keep one core busy, not two). 1: everything in this process. The figures are those
    # of jobs=1 at the same `threads`: a pair's noise is seeded by the pair alone.
    jobs: int = 1
    run_dir: str | None = None      # a TensorBoard log directory (e.g. a training run's tb/) to log scalars and figures into
    plots: bool = True
    progress: bool = True           # tqdm progress bar

    def __post_init__(self):
        """Every key's range and the mocap files, checked before the checkpoint is loaded: a
        typo found after the evaluation would throw minutes of work away."""
        super().__post_init__()
        check_sampler_settings(self)
        check_protocol_keys(self)
        require_range("threads", self.threads, 0, integer=True)
        require_range("jobs", self.jobs, 1, 256, integer=True)
        require_choice("split", self.split, SPLITS)
        mocap_paths(self.mocap)


def check_protocol_keys(p: ProtocolConfig) -> None:
    """The protocol's numbers (ProtocolConfig's fields)."""
    r = require_range
    r("k", p.k, 1, MAX_SAMPLES, integer=True)
    r("pairs", p.pairs, 1, 10000, integer=True)
    r("interaction_pairs", p.interaction_pairs, 0, 10000, integer=True)
    r("action_seconds", p.action_seconds, 0, 3600, allow_none=True)
    r("min_distance", p.min_distance, 0, 1000)
    r("body_radius", p.body_radius, 0, 2)
    r("subgoal_spacing", p.subgoal_spacing, 0.05, 100)
    r("approach", p.approach, 0, 100)
    r("max_episodes", p.max_episodes, 1, 100000, integer=True)
    r("seed", p.seed, 0, integer=True)
    r("pskl_frames", p.pskl_frames, 2, 100000, integer=True)
    r("contact_thresh", p.contact_thresh, 0, 1, lo_open=True)
    r("ablation_pairs", p.ablation_pairs, 0, 10000, integer=True)
    for stage in p.ablate:
        require_choice("ablate", stage, tuple(CLEANUP_STAGES))


def mocap_paths(mocap) -> list[Path]:
    """The `mocap` key's BVH files or folders (one or a list), each present: refused up front,
    not when the report is written."""
    if mocap is None:
        return []
    paths = [Path(str(m)) for m in ([mocap] if isinstance(mocap, str) else list(mocap))]
    for p in paths:
        if not p.exists():
            raise ConfigError(f"mocap: {p} does not exist (BVH files or folders of them)")
        if p.is_dir() and not any(p.glob("*.bvh")):
            raise ConfigError(f"mocap: folder {p} holds no .bvh files")
    return paths


def loop_overrides(loop) -> dict:
    """The LoopConfig fields set (non-null) in `loop`: a LoopOverrides, or a mapping of its keys
    typed and checked the same way; numbers must be >= 0."""
    if not isinstance(loop, LoopOverrides):
        loop = typed_config(LoopOverrides, loop if loop is not None else {}, prefix="loop.")
    out = {k: v for k, v in asdict(loop).items() if v is not None}
    if "solve" in out:
        require_choice("loop.solve", out["solve"], SOLVE_METHODS)
    loop_config = LoopConfig(**out)                      # its own checks (loop.foot_height), up front
    for key, value in out.items():
        if isinstance(value, float) and value < 0:
            raise ConfigError(f"loop.{key}: expected a number >= 0, got {value:g}")
    check_loop(loop_config)                              # the ranges `sample` takes (loop.reach_fraction)
    return out


def protocol_config(cfg: EvaluateConfig) -> ProtocolConfig:
    """The protocol's own configuration out of the app's keys (its `loop`: the keys set)."""
    keys = {f: getattr(cfg, f) for f in ProtocolConfig.__dataclass_fields__}
    return ProtocolConfig(**{**keys, "loop": loop_overrides(cfg.loop)})


def dataset_config(data: DataConfig | None, ckpt_config: DictConfig | None) -> DataConfig:
    """The dataset to evaluate on: the `data` group when given, else the checkpoint's own data
    config (the keys DataConfig knows), else the default."""
    if data is not None:
        return data
    node = ckpt_config.get("data") if ckpt_config is not None else None
    if node is None:
        return DataConfig()
    d = OmegaConf.to_container(node, resolve=True) if not isinstance(node, dict) else dict(node)
    return DataConfig(**{k: v for k, v in d.items() if k in DataConfig.__dataclass_fields__})
