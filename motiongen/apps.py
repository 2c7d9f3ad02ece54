"""The Hydra applications: `train`, `sample` and `evaluate`, configured by
motiongen/configs/*.yaml (docs/config.md). `python train.py ...` and `motiongen train ...` both
run these; `check_hydra_overrides` first turns a malformed override or an unknown key into one
line and exit status 2, as for every user error."""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from motiongen.cli import CONFIG_DIR, check_hydra_overrides, user_errors_exit_2
from motiongen.config import register_configs

register_configs()


@hydra.main(config_path="configs", config_name="train", version_base="1.3")
@user_errors_exit_2
def _train(cfg: DictConfig) -> None:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    if cfg.get("task", "motion") == "joints2body":
        from motiongen.body.train_mlp import train_from_config
        train_from_config(cfg, run_dir)
        return
    from motiongen.training.trainer import train
    last = train(cfg, run_dir)
    if last is not None:
        print(f"checkpoint: {last}\ntensorboard: tensorboard --logdir {run_dir / 'tb'}", flush=True)


@hydra.main(config_path="configs", config_name="sample", version_base="1.3")
@user_errors_exit_2
def _sample(cfg: DictConfig) -> None:
    from motiongen.sampling.cli import run

    run(cfg, Path(HydraConfig.get().runtime.output_dir))


@hydra.main(config_path="configs", config_name="evaluate", version_base="1.3")
@user_errors_exit_2
def _evaluate(cfg: DictConfig) -> None:
    from motiongen.eval.report import run

    run(cfg, Path(HydraConfig.get().runtime.output_dir))


APPS = {"train": _train, "sample": _sample, "evaluate": _evaluate}


def run_app(name: str) -> None:
    """Run one app on sys.argv[1:] (Hydra reads the overrides from there)."""
    check_hydra_overrides(config_name=name, config_dir=CONFIG_DIR)
    APPS[name]()
