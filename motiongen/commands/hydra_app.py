"""The `main(argv=None)` of a Hydra app: `train`, `sample`, `evaluate` and `train-body-mlp`, each
configured by motiongen/configs/<app>.yaml over the structured configs of motiongen/config.py
(docs/config.md)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from motiongen.cli import CONFIG_DIR, check_hydra_overrides, user_errors_exit_2
from motiongen.config import register_configs


def hydra_command(config_name: str, task: Callable[[DictConfig, Path], object]) -> Callable[[list[str] | None], None]:
    """`main(argv=None)` for the app of configs/<config_name>.yaml: a malformed override, an
    unknown key, a value of the wrong type or a missing group option is one line and exit 2
    (`check_hydra_overrides`), then `task(cfg, run_dir)` runs under `hydra.main` with the
    composed config and Hydra's run directory, a user error again one line and exit 2."""
    register_configs()

    @hydra.main(config_path="pkg://motiongen.configs", config_name=config_name, version_base="1.3")
    @user_errors_exit_2
    def app(cfg: DictConfig) -> None:
        task(cfg, Path(HydraConfig.get().runtime.output_dir))

    def main(argv: list[str] | None = None) -> None:
        # The program name in Hydra's usage line: the script's, or `motiongen <command>`.
        prog = sys.argv[0] if argv is None else f"motiongen {config_name.replace('_', '-')}"
        argv = sys.argv[1:] if argv is None else list(argv)
        check_hydra_overrides(argv, config_name=config_name, config_dir=CONFIG_DIR)
        sys.argv = [prog, *argv]                         # hydra.main reads its overrides from sys.argv
        app()

    return main
