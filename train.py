"""Train a motiongen model: `python train.py [experiment=demo|paper] [key=value ...]`.

With no arguments it trains the demo setting (tiny model) on the embedded synthetic dataset,
generating the dataset into the cache on first use. See docs/config.md for every key.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from motiongen.cli import user_errors_exit_2
from motiongen.config import register_configs

register_configs()


@hydra.main(config_path="configs", config_name="train", version_base="1.3")
@user_errors_exit_2
def main(cfg: DictConfig) -> None:
    if cfg.get("task", "motion") == "joints2body":
        from motiongen.body.train_mlp import train_from_config
        train_from_config(cfg, Path(HydraConfig.get().runtime.output_dir))
        return
    from motiongen.training.trainer import train
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    last = train(cfg, run_dir)
    if last is not None:
        print(f"checkpoint: {last}\ntensorboard: tensorboard --logdir {run_dir / 'tb'}", flush=True)


if __name__ == "__main__":
    from motiongen.cli import check_hydra_overrides

    # one line and exit 2 for a malformed override or an unknown key, as for every user error
    check_hydra_overrides(config_name="train", config_dir=Path(__file__).parent / "configs")
    main()
