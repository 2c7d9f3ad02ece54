"""`motiongen distill`: a 1-, 2- or 4-step student of a trained model in the Hydra run
directory (`out=`), by trajectory distillation (motiongen/training/distill.py, docs/diffusion.md).
configs/distill.yaml over DistillConfig holds the keys. `motiongen distill info=STUDENT.pt`
prints what a student checkpoint is and what it was distilled from."""

from __future__ import annotations

import sys
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from motiongen.cli import user_errors_exit_2
from motiongen.commands.hydra_app import hydra_command
from motiongen.errors import ConfigError
from motiongen.loading.checkpoint import student_info
from motiongen.output_lock import OutputLock
from motiongen.training.distill import distill


def run(cfg: DictConfig, run_dir: Path) -> None:
    dc = OmegaConf.to_object(cfg)
    with OutputLock(run_dir, "distill"):        # one live run per directory, as for train
        last = distill(dc, run_dir, log=lambda m: print(m, flush=True))
    print(f"checkpoint: {last}\ntensorboard: tensorboard --logdir {run_dir / 'tb'}\n"
          f"sample with: motiongen sample ckpt={last}", flush=True)


@user_errors_exit_2
def info(args: list[str]) -> None:
    """`info=PATH` alone: the student's `distill` entry, one key a line."""
    if len(args) != 1:
        raise ConfigError("info=PATH takes no other keys")
    path = args[0].split("=", 1)[1]
    if not path:
        raise ConfigError("info= is empty: give a student checkpoint")
    for key, value in student_info(path).items():
        print(f"{key}: {value}")


_hydra_main = hydra_command("distill", run)


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else list(argv)
    if any(a.startswith("info=") for a in args):
        info(args)
        return
    _hydra_main(argv)


if __name__ == "__main__":
    main()
