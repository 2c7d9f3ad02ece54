"""Typed configs, registered with Hydra's ConfigStore: every default lives once, in a dataclass.

Groups of `train` (see docs/config.md): `model` (tiny | paper | reference, from
motiongen.models.PRESETS), `diffusion` (default | paper), `data` (synthetic | small | trumans |
dataset), `window`, `mask`, `train` (default), plus `experiment` presets in
configs/experiment/*.yaml. The keys of the other apps: `sample_schema` (SampleConfig),
`serve_schema` (ServeConfig), `evaluate_schema` (EvaluateConfig, which takes the `data` group too), `train_mlp`
(TrainMLPConfig) and `distill_schema` (DistillConfig); configs/<app>.yaml name their schema first in the defaults list and add
Hydra's own settings.
"""

from __future__ import annotations

from hydra.core.config_store import ConfigStore

from motiongen.body.train_mlp import TrainMLPConfig
from motiongen.capture.train_motion_prior import TrainPriorConfig
from motiongen.data.windows import WindowConfig
from motiongen.diffusion import DiffusionConfig, MaskConfig
from motiongen.eval.evaluate_config import EvaluateConfig
from motiongen.importers.sources import DataConfig
from motiongen.models import PRESETS
from motiongen.sampling.sample_config import SampleConfig
from motiongen.serve.serve_config import ServeConfig
from motiongen.training.distill_config import DistillConfig
from motiongen.training.train_config import TrainConfig


_registered = False


def register_configs() -> None:
    """Register the structured configs once per process (idempotent)."""
    global _registered
    if _registered:
        return
    # paper: linear β 1e-4 → 0.02 over 100 steps, ε-prediction (supplement A.2); samplers start
    # from the marginal that schedule really ends at. default: cosine (ends at pure noise), x0.
    diffusion_presets = {"default": DiffusionConfig(),
                         "paper": DiffusionConfig(schedule="linear", beta_start=1e-4, beta_end=0.02,
                                                  prediction="eps")}

    cs = ConfigStore.instance()
    for name, preset in PRESETS.items():
        cs.store(group="model", name=name, node=preset)
    for name, preset in diffusion_presets.items():
        cs.store(group="diffusion", name=name, node=preset)
    cs.store(group="mask", name="default", node=MaskConfig())
    cs.store(group="data", name="synthetic", node=DataConfig(source="synthetic", size="default"))
    cs.store(group="data", name="small", node=DataConfig(source="synthetic", size="small"))
    cs.store(group="data", name="trumans", node=DataConfig(source="trumans"))
    cs.store(group="data", name="dataset", node=DataConfig(source="dataset"))
    cs.store(group="window", name="default", node=WindowConfig())
    # The public code's features: absolute joints, no stance channels.
    cs.store(group="window", name="reference", node=WindowConfig(contact_joints=()))
    cs.store(group="train", name="default", node=TrainConfig())
    cs.store(name="sample_schema", node=SampleConfig)
    cs.store(name="serve_schema", node=ServeConfig)
    cs.store(name="evaluate_schema", node=EvaluateConfig)
    cs.store(name="train_mlp", node=TrainMLPConfig)
    cs.store(name="train_motion_prior_schema", node=TrainPriorConfig)
    cs.store(name="distill_schema", node=DistillConfig)
    _registered = True
