"""Trainer configuration (the `train` group)."""

from __future__ import annotations

from dataclasses import dataclass

from motiongen.checks import require_choice, require_range

LR_SCHEDULES = ("constant", "cosine")
AMP_MODES = ("auto", "bf16", "none")


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
    # Geometry on the network's own prediction (training/body_losses.py), metres: bone lengths
    # against the clean window's, and the speed (m/s) of feet the data flags planted. 0 = off.
    # Loss weight of the wrist a window's hand goal names (`mask.p_hand`, `mask.p_hand_action`),
    # its x, y, z over the window's last quarter, relative to the other entries (1 = plain): the
    # hand goal is 3 of the window's L*D entries, and with a plain mean the network learnt to
    # ignore it (docs/results.md).
    hand_goal_weight: float = 1.0
    w_bone_length: float = 0.0
    # Weight of the facing term: how far (m) the prediction's left-to-right hip and shoulder
    # vectors are from the clean window's, per frame (training/body_losses.py). 0 = off.
    w_facing: float = 0.0
    # Weight of the same term on the windows given a facing goal (mask.p_facing), over their
    # last quarter of frames: the goal followed (training/body_losses.py). 0 = off.
    w_facing_goal: float = 0.0
    # How that term measures the miss: l1 |â − a| (m), or squared |â − a|² (m²), whose best
    # prediction is the mean the diffusion loss asks for (training/body_losses.py).
    facing_goal_norm: str = "l1"
    # Weight of the foot-height term: how far (m) the prediction's ankles and toes are from the
    # clean window's in height, per frame (training/body_losses.py). 0 = off.
    w_foot_height: float = 0.0
    # Weight of the foot-offset term: how far (m) the prediction's ankles and toes are from the
    # clean window's along the floor, each measured from its own pelvis (training/body_losses.py).
    w_foot_offset: float = 0.0
    # Weight of the pace term: how far (m/s) the prediction's pelvis steps along the floor are
    # from the clean window's, frame to frame (training/body_losses.py). 0 = off.
    w_pace: float = 0.0
    w_planted_feet: float = 0.0
    geometry_weighting: str = "uniform"   # uniform | signal: each window by its share of signal ᾱ_t (body_losses.py)
    geometry_start: int = 0          # the step the geometry terms start at (0 before it) ...
    geometry_ramp: int = 0           # ... and the steps over which they grow linearly to full weight
    # Training on the network's own transition frames (training/rollout.py): from step
    # `rollout_start`, this share of the windows with transition frames gets them from the EMA
    # network's `rollout_steps`-step DDIM sample of the window before (as the sampler's loop
    # hands them on), the data's continuation as the target. 0 = off.
    rollout_p: float = 0.0
    rollout_start: int = 0
    rollout_steps: int = 4
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

    def __post_init__(self):
        """Every key's range, checked once as the run is set up, before any work (the split of
        the batch over torchrun's processes: `distributed.check_batch_split`)."""
        r = require_range
        for key in ("max_steps", "batch_size", "log_every", "ckpt_every", "val_batches"):
            r(f"train.{key}", getattr(self, key), 1, integer=True)
        r("train.rollout_steps", self.rollout_steps, 1, integer=True)
        for key in ("warmup_steps", "geometry_start", "geometry_ramp", "rollout_start", "val_every", "figure_every", "keep_last", "num_workers", "threads"):
            r(f"train.{key}", getattr(self, key), 0, integer=True)
        r("train.lr", self.lr, 0, lo_open=True)   # no ceiling: lr=1e20 is how a diverging run is reproduced
        for key in ("weight_decay", "grad_clip", "pelvis_loss_weight", "hand_goal_weight", "w_bone_length",
                    "w_planted_feet", "w_facing", "w_foot_height", "w_foot_offset", "w_pace", "w_facing_goal"):
            r(f"train.{key}", getattr(self, key), 0)
        for key in ("min_lr_ratio", "cond_drop_scene", "cond_drop_actions", "rollout_p"):
            r(f"train.{key}", getattr(self, key), 0, 1)
        require_choice("train.geometry_weighting", self.geometry_weighting, ("uniform", "signal"))
        require_choice("train.facing_goal_norm", self.facing_goal_norm, ("l1", "squared"))
        # 1 or more makes the EMA weights grow without bound (1.5 reached 4.7e22).
        r("train.ema_decay", self.ema_decay, 0, 1, hi_open=True)
        require_choice("train.lr_schedule", self.lr_schedule, LR_SCHEDULES)
        require_choice("train.amp", self.amp, AMP_MODES)
