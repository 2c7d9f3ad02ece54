"""The keys of `motiongen distill` (configs/distill.yaml over `DistillConfig`, registered as
`distill_schema`): the teacher, the student's step count, the teacher runs it learns from, and
the optimiser, logging and checkpoint settings, named as the `train` group names them."""

from __future__ import annotations

from dataclasses import dataclass

from motiongen.checks import require_choice, require_range
from motiongen.rates import DEFAULT_STEPS
from motiongen.training.train_config import LR_SCHEDULES

# Network evaluations per window a student may be trained for. 1, 2 and 4 halve the work each
# time and are what the method was measured at (docs/diffusion.md); other counts are refused
# rather than trained untested.
STUDENT_STEPS = (1, 2, 4)
METHOD = "trajectory"             # the `distill.method` entry of a student checkpoint


@dataclass
class DistillConfig:
    ckpt: str | None = None        # required: the teacher, a checkpoint written by `motiongen train`
    out: str | None = None         # the student's run directory; default runs/distill/<time>
    steps: int = 2                 # the student's network evaluations per window: 1, 2 or 4
    teacher_steps: int = DEFAULT_STEPS   # the teacher's DDIM steps (what `sample` runs by default)
    guidance_scale: float = 1.0    # the teacher's classifier-free guidance, folded into the student
    bank_size: int = 4096          # teacher runs (training windows) the student learns from
    bank_batch: int = 256          # windows per teacher call while the bank is made
    # Share of the windows whose state at a student step i > 0 comes from the student's own
    # earlier steps (what it meets at sampling) instead of the teacher's trajectory.
    self_states: float = 0.5
    # The teacher's dropout in the student while it trains; false: off (the target is a
    # deterministic map of the state, not data).
    dropout: bool = True
    max_steps: int = 2000
    batch_size: int = 64
    lr: float = 3e-4
    warmup_steps: int = 50
    lr_schedule: str = "cosine"    # constant | cosine (to min_lr_ratio * lr at max_steps)
    min_lr_ratio: float = 0.1
    grad_clip: float = 1.0         # 0 disables
    ema_decay: float = 0.995
    log_every: int = 50
    ckpt_every: int = 250
    keep_last: int = 2
    resume: str | None = "auto"    # null (start fresh) | auto (the run's last checkpoint, if any) | PATH
    device: str = "auto"           # auto | cpu | cuda | cuda:N
    threads: int = 0               # torch CPU threads (0 = torch's default)
    seed: int = 0
    progress: bool = True          # tqdm bar on a terminal

    def __post_init__(self):
        r = require_range
        require_choice("steps", self.steps, STUDENT_STEPS)
        r("teacher_steps", self.teacher_steps, 1, 10000, integer=True)
        r("guidance_scale", self.guidance_scale, 0, 100)
        r("bank_size", self.bank_size, 1, 10_000_000, integer=True)
        r("bank_batch", self.bank_batch, 1, 100_000, integer=True)
        r("self_states", self.self_states, 0, 1)
        r("max_steps", self.max_steps, 1, integer=True)
        r("batch_size", self.batch_size, 1, integer=True)
        r("lr", self.lr, 0, lo_open=True)
        r("warmup_steps", self.warmup_steps, 0, integer=True)
        require_choice("lr_schedule", self.lr_schedule, LR_SCHEDULES)
        r("min_lr_ratio", self.min_lr_ratio, 0, 1)
        r("grad_clip", self.grad_clip, 0)
        r("ema_decay", self.ema_decay, 0, 1, hi_open=True)
        r("log_every", self.log_every, 1, integer=True)
        r("ckpt_every", self.ckpt_every, 1, integer=True)
        r("keep_last", self.keep_last, 0, integer=True)
        r("threads", self.threads, 0, integer=True)
        r("seed", self.seed, 0, integer=True)
        if self.batch_size > self.bank_size:
            r("batch_size", self.batch_size, 1, self.bank_size, integer=True)

    def bank_key(self) -> dict:
        """What a cached bank of teacher runs depends on, besides the teacher itself."""
        return {"steps": self.steps, "teacher_steps": self.teacher_steps, "guidance_scale": float(self.guidance_scale),
                "bank_size": self.bank_size, "seed": self.seed}
