"""The keys of every app that runs a trained checkpoint (`sample`, `evaluate`) and the loading
of the model they name."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from motiongen.errors import ConfigError, DataError
from motiongen.loading.build import LoadedModel, load_model


@dataclass
class CheckpointKeys:
    ckpt: str | None = None        # required: a checkpoint written by train.py
    device: str = "cpu"            # cpu | cuda | cuda:N
    threads: int = 0               # torch CPU threads (0 = torch's default)
    # fp32 | bf16 | int8 | int8-encoders | auto: the transformer layers' weights for sampling
    # (int8: every transformer layer, int8-encoders: the encoders' only; CPU only);
    # auto = bf16 for paper-size layers where the device multiplies bfloat16 natively, else fp32
    # (docs/sampling.md).
    precision: str = "auto"
    body_model: str | None = None  # SMPL-X .npz of the motion's body; None = $MOTIONGEN_SMPLX_MODEL, else the procedural model


def checkpoint_path(keys: CheckpointKeys) -> Path:
    """The `ckpt` key, which every such app requires."""
    if not keys.ckpt:
        raise ConfigError("ckpt=PATH is required (a checkpoint written by train.py)")
    return Path(keys.ckpt)


def checkpoint_paths(value) -> list[Path]:
    """The `ckpt` key: one checkpoint, or a list of them (one recipe trained with several seeds)."""
    items = [value] if isinstance(value, (str, Path)) or value is None else list(value)
    if not items or any(v in (None, "") for v in items):
        raise ConfigError("ckpt=PATH is required (a checkpoint written by train.py; ckpt=[a,b,c] for several seeds)")
    paths = [Path(str(v)) for v in items]
    if len(set(map(str, paths))) != len(paths):
        raise ConfigError(f"ckpt: a checkpoint is listed twice ({', '.join(map(str, paths))})")
    return paths


def load_checkpoint_model(keys: CheckpointKeys) -> LoadedModel:
    """The model of `keys.ckpt` on `keys.device` at `keys.precision`, with torch's CPU threads
    set first when `keys.threads` asks for a number."""
    ckpt = checkpoint_path(keys)
    if not ckpt.is_file():
        raise DataError(ckpt, None, "checkpoint file does not exist")
    if keys.threads > 0:
        torch.set_num_threads(keys.threads)
    return load_model(ckpt, keys.device, precision=keys.precision)


def noise_generator(loaded: LoadedModel, seed: int) -> torch.Generator:
    """The diffusion noise's generator, seeded, on the model's device (on the CPU for MPS, which
    has no generator of its own)."""
    return torch.Generator(device=loaded.device if loaded.device.type != "mps" else "cpu").manual_seed(seed)
