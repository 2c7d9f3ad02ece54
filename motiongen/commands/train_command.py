"""`motiongen train` (train.py): train a motion model in the Hydra run directory, or with
task=joints2body the joints-to-SMPL-X MLP. configs/train.yaml and the groups registered in
motiongen/config.py hold the keys (docs/config.md); `torchrun ... train.py` runs it under DDP."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from motiongen.body.train_mlp import TrainMLPConfig, train_and_save
from motiongen.commands.hydra_app import hydra_command
from motiongen.training.trainer import train


def run(cfg: DictConfig, run_dir: Path) -> None:
    if cfg.get("task", "motion") == "joints2body":
        # The MLP's own defaults (`motiongen train-body-mlp` sets every key), written to the run directory.
        train_and_save(TrainMLPConfig(out=str(run_dir), seed=int(cfg.seed)))
        return
    last = train(cfg, run_dir)
    if last is not None:
        print(f"checkpoint: {last}\ntensorboard: tensorboard --logdir {run_dir / 'tb'}", flush=True)


main = hydra_command("train", run)


if __name__ == "__main__":
    main()
