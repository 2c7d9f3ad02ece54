"""`motiongen train-body-mlp`: train the 3-frame joints -> SMPL-X MLP alone.

    motiongen train-body-mlp out=runs/j2b steps=20000 mlp.width=512 \
        [data.root=DATASET_DIR] [body.model_path=SMPLX_NEUTRAL.npz]

The keys: TrainMLPConfig (motiongen/body/train_mlp.py), through configs/train_body_mlp.yaml.
Writes `out/mlp.pt` and TensorBoard logs under `out/tb`.
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from motiongen.body.train_mlp import train_and_save
from motiongen.commands.hydra_app import hydra_command
from motiongen.output_lock import OutputLock


def run(cfg: DictConfig, run_dir: Path) -> None:
    with OutputLock(cfg.out, "train-body-mlp"):         # one live run per output directory
        train_and_save(OmegaConf.to_object(cfg))


main = hydra_command("train_body_mlp", run)


if __name__ == "__main__":
    main()
