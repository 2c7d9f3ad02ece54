"""Generate motion with a trained model: `python sample.py ckpt=PATH [scene=...] [goals=[[x,z],...]] ...`.

Autoregressive sampling towards goal points through a scene (docs/sampling.md). Everything
about the model comes from the checkpoint; configs/sample.yaml lists every key.
The demo: `python sample.py ckpt=runs/demo/.../checkpoints/last.pt scene=synthetic:91`.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from motiongen.cli import user_errors_exit_2


@hydra.main(config_path="configs", config_name="sample", version_base="1.3")
@user_errors_exit_2
def main(cfg: DictConfig) -> None:
    from motiongen.sampling.cli import run

    run(cfg, Path(HydraConfig.get().runtime.output_dir))


if __name__ == "__main__":
    from motiongen.cli import check_hydra_overrides

    # one line and exit 2 for a malformed override or an unknown key, as for every user error
    check_hydra_overrides(config_name="sample", config_dir=Path(__file__).parent / "configs")
    main()
