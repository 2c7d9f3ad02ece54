"""Evaluate a trained model: `python evaluate.py ckpt=PATH [scenes=[91,92]] [k=5] [steps=10] ...`.

The TRUMANS static/dynamic protocol on the test scenes of the checkpoint's dataset, with the
dataset's own motion as a reference row: report.json, report.md and plots/ in `out`
(docs/evaluation.md). configs/evaluate.yaml lists every key.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from motiongen.cli import user_errors_exit_2
from motiongen.config import register_configs

register_configs()


@hydra.main(config_path="configs", config_name="evaluate", version_base="1.3")
@user_errors_exit_2
def main(cfg: DictConfig) -> None:
    from motiongen.eval.report import run

    run(cfg, Path(HydraConfig.get().runtime.output_dir))


if __name__ == "__main__":
    from motiongen.cli import check_hydra_overrides

    # one line and exit 2 for a malformed override or an unknown key, as for every user error
    check_hydra_overrides(config_name="evaluate", config_dir=Path(__file__).parent / "configs")
    main()
