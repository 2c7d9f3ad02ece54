"""Trainer configuration (the `train` group)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class TrainConfig:
    max_steps: int = 3000
    batch_size: int = 64             # global batch: split evenly over DDP processes
    lr: float = 1e-4
    weight_decay: float = 0.0
    warmup_steps: int = 0
    lr_schedule: str = "constant"    # constant | cosine (to min_lr_ratio * lr at max_steps)
    min_lr_ratio: float = 0.1
    grad_clip: float = 1.0           # 0 disables
    ema_decay: float = 0.999
    cond_drop_scene: float = 0.1     # classifier-free guidance: drop each condition independently
    cond_drop_actions: float = 0.1
    # Loss weight of the pelvis channels relative to the other joints' (1 = plain mean): extra
    # emphasis on the root trajectory, 3 of J*3 channels. Plain by default: a heavier weight did
    # not improve goal following on the demo, the input path of pinned entries did (docs/models.md).
    pelvis_loss_weight: float = 1.0
    log_every: int = 50
    val_every: int = 500             # 0 disables validation
    val_batches: int = 4
    figure_every: int = 1000         # 0 disables figures
    ckpt_every: int = 500
    keep_last: int = 3
    resume: str | None = None        # null | auto | PATH
    device: str = "auto"             # auto | cpu | cuda | cuda:N
    amp: str = "auto"                # auto (bf16 on CUDA) | bf16 | none
    num_workers: int = 2
    deterministic: bool = True       # deterministic kernels (bitwise resume on CPU)
    threads: int = 0                 # torch intra-op threads; 0 = auto (CPU: cores/processes - workers)
    progress: bool = True
