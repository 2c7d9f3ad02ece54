"""The keys of `motiongen evaluate` (evaluate.py): the protocol's configuration, the sampler's
settings and the run's own keys, as one structured config registered with Hydra
(motiongen/config.py). docs/evaluation.md explains them."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from omegaconf import DictConfig, OmegaConf

from motiongen.cli import typed_config
from motiongen.errors import ConfigError
from motiongen.eval.pairs import SETTINGS, ProtocolConfig
from motiongen.importers.sources import DataConfig
from motiongen.loading.keys import CheckpointKeys
from motiongen.sampling.settings import SamplerSettings


@dataclass
class LoopOverrides:
    """The sampler's clean-up (LoopConfig fields), for research comparisons; None = the sampler's
    default, which is what `sample` uses."""

    project: bool | None = None     # false: the network's joints, no body (nor final solve)
    foot_lock: bool | None = None   # false: no foot locking in the final solve
    pin_goal: bool | None = None    # true: write the goal pelvis into the result (the public code)
    smooth: float | None = None     # Gaussian sigma (output frames) before the final solve; 0 = off
    seam_blend: float | None = None  # seconds; 0 = off
    solve_smoothness: float | None = None  # final solve's joint-acceleration weight; None = by the model's frame rate


@dataclass
class EvaluateScope(CheckpointKeys):
    # The `data` group: None = the checkpoint's own data config (its dataset's test split); or
    # data=small|synthetic|dataset ... (a DataConfig once chosen; untyped until then, since
    # OmegaConf cannot set `data.root=...` on an empty typed node)
    data: Any = None
    scenes: Any = None              # subset of the test scene ids, e.g. [91,92]; None = all test scenes
    settings: Any = field(default_factory=lambda: list(SETTINGS))
    # BVH files or folders: a "real mocap" row in the Body table, measured the same way (e.g.
    # mocap=/usr/share/assimp/models/BVH from Debian's assimp-testmodels).
    mocap: Any = None


# The keys in the order `--help` lists them: a dataclass takes the fields of its bases in reverse
# order (EvaluateScope with its CheckpointKeys, ProtocolConfig, SamplerSettings), then its own.
@dataclass
class EvaluateConfig(SamplerSettings, ProtocolConfig, EvaluateScope):
    # k samples x pairs x scenes x 2 settings motions: fewer denoising steps than `sample` keep
    # the whole protocol to minutes on a CPU (paper-faithful: sampler=ddpm steps=100).
    steps: int = 10
    loop: LoopOverrides = field(default_factory=LoopOverrides)
    # Outputs.
    out: str | None = None          # directory; default: the Hydra run directory
    run_dir: str | None = None      # a TensorBoard log directory (e.g. a training run's tb/) to log scalars and figures into
    plots: bool = True
    progress: bool = True           # tqdm progress bar

    def __post_init__(self):
        super().__post_init__()
        if self.k < 1 or self.pairs < 1:
            raise ConfigError(f"k and pairs must be >= 1, got k={self.k}, pairs={self.pairs}")


def loop_overrides(loop) -> dict:
    """The LoopConfig fields set (non-null) in `loop`: a LoopOverrides, or a mapping of its keys
    typed and checked the same way; numbers must be >= 0."""
    if not isinstance(loop, LoopOverrides):
        loop = typed_config(LoopOverrides, loop if loop is not None else {}, prefix="loop.")
    out = {k: v for k, v in asdict(loop).items() if v is not None}
    for key, value in out.items():
        if isinstance(value, float) and value < 0:
            raise ConfigError(f"loop.{key}: expected a number >= 0, got {value:g}")
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
