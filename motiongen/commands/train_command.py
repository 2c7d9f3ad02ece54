"""`motiongen train` (train.py): train a motion model in the Hydra run directory, or with
task=joints2body the joints-to-SMPL-X MLP. configs/train.yaml and the groups registered in
motiongen/config.py hold the keys (docs/config.md); `torchrun ... train.py` runs it under DDP."""

from __future__ import annotations

import os
from contextlib import nullcontext
from pathlib import Path

from omegaconf import DictConfig

from motiongen.body.train_mlp import TrainMLPConfig, train_and_save
from motiongen.commands.hydra_app import hydra_command
from motiongen.output_lock import OutputLock
from motiongen.training.trainer import train


def run(cfg: DictConfig, run_dir: Path) -> None:
    # One live run per run directory (a second one would mix its checkpoints with the first's);
    # under torchrun rank 0 holds the lock for the ranks that share the directory with it.
    main_rank = int(os.environ.get("RANK", "0")) == 0
    with OutputLock(run_dir, "train") if main_rank else nullcontext():
        _train(cfg, run_dir)


def _train(cfg: DictConfig, run_dir: Path) -> None:
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
