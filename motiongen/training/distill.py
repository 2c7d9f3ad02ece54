"""`motiongen distill`: a student that samples in 1, 2 or 4 network evaluations per window,
trained from a teacher checkpoint by trajectory distillation on the student's own step grid.

Method (docs/diffusion.md, "Distilled few-step students"). The student's n timesteps are
`spaced_timesteps(T, n)`, the grid the ordinary DDIM scheduler visits with steps=n, so
`motiongen sample` runs a student with no other change. A bank of teacher runs on training
windows (conditions, masks and known entries as training builds them; `distill_bank.py`)
records the teacher's guided DDIM-25 state at each student timestep and its output x0*. The
student, initialised from the teacher's EMA weights (same architecture and parameterisation),
learns x̂0(x_{t_i}, t_i) = x0* on the entries the teacher's loss covers: each of its
deterministic DDIM jumps lands on the teacher's trajectory and the last one on its output,
guidance included (the student samples with guidance 1). For i > 0 a share of the states
(`self_states`) comes from the student's own earlier steps, the inputs it meets at sampling.

Why this method: its targets are fixed regression targets made once by the teacher (a few
minutes of teacher calls on a CPU for the demo), every student step is one forward and backward
pass like a training step, and it needs no second network (consistency or adversarial
distillation), no nested teacher calls per step (progressive distillation's log2(25 / n)
rounds) and no new parameterisation: the student is the teacher's architecture with the
teacher's weights as a start, so its first step already samples like DDIM-n of the teacher.

The run mirrors `motiongen train`: EMA weights, the resumable batch order, every RNG in the
checkpoint (a run killed and resumed with resume=auto continues where it stopped; the bank is
read back from `bank.pt`), atomic checkpoints in `<out>/checkpoints/`, TensorBoard in `<out>/tb/`.
A student checkpoint is a motiongen checkpoint with the teacher's config, statistics and
vocabulary and a `distill` entry (method, steps, timesteps, the teacher's path, step, guidance
and step count) from which `sample`, `evaluate` and `serve` take their defaults.
"""

from __future__ import annotations

import copy
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from omegaconf import OmegaConf
from tqdm import tqdm

from motiongen.cli import Interrupted
from motiongen.diffusion.masks import loss_mask
from motiongen.diffusion.trajectory import distill_loss, student_states, student_timesteps
from motiongen.errors import ConfigError
from motiongen.loading.build import LoadedModel, load_model
from motiongen.loading.checkpoint import find_resume, load_checkpoint, remove_orphan_temps, save_checkpoint
from motiongen.output_lock import refuse_output_over_input
from motiongen.training.data_order import ResumableBatchSampler
from motiongen.training.distill_bank import Bank, load_or_make_bank
from motiongen.training.distill_config import METHOD, DistillConfig
from motiongen.training.ema import EMA
from motiongen.training.setup import lr_lambda, resolve_device, rng_state, set_rng_state
from motiongen.training.trainer import TrainingDiverged

# What a student checkpoint copies from its teacher's: everything that rebuilds the model, and
# the data's swing table its samples are cleaned up with.
TEACHER_KEYS = ("format", "version", "config", "stats", "fps", "joint_names", "action_names", "model_config",
                "diffusion_config", "swing_rise")
LINE_EVERY_S = 10.0


@dataclass
class DistillRun:
    """One distillation run: its settings, teacher, bank, student and optimiser, and the loop's
    position `step`, which `distill_step` advances."""

    dc: DistillConfig
    run_dir: Path
    device: torch.device
    teacher_path: Path
    teacher: LoadedModel
    teacher_state: dict            # the teacher checkpoint's TEACHER_KEYS
    bank: Bank
    student: torch.nn.Module
    ema: EMA
    opt: torch.optim.Optimizer
    sched: torch.optim.lr_scheduler.LambdaLR
    gen: torch.Generator           # student steps, own-state choices (CPU: the same on every device)
    timesteps: torch.Tensor        # (n,) long, descending: the student's grid
    step: int = 0
    writer: object = None


def check_paths(dc: DistillConfig, run_dir: Path) -> Path:
    """The teacher's path, after refusing a missing teacher and an output in the teacher's own
    folder (a student's checkpoints would sit beside or replace the teacher's)."""
    if not dc.ckpt:
        raise ConfigError("ckpt=PATH is required (the teacher: a checkpoint written by `motiongen train`)")
    teacher = Path(dc.ckpt).expanduser()
    if not teacher.is_file():
        raise ConfigError(f"ckpt={dc.ckpt}: teacher checkpoint file does not exist")
    t = teacher.resolve()
    own = {t.parent} | ({t.parent.parent} if t.parent.name == "checkpoints" else set())
    if Path(run_dir).expanduser().resolve() in own:
        raise ConfigError(f"out={run_dir}: that is the teacher's own folder; give the student a folder of its own")
    refuse_output_over_input(Path(run_dir) / "checkpoints", [teacher], "out")
    return teacher


def load_teacher(path: Path, device) -> tuple[LoadedModel, dict]:
    """The teacher (EMA weights, fp32) and the checkpoint entries a student copies from it."""
    teacher = load_model(path, device)
    if teacher.distill is not None:
        raise ConfigError(f"ckpt={path}: is itself a distilled {teacher.distill['steps']}-step student; "
                          "distil from the model it was distilled from")
    if teacher.diffusion.cfg.prediction == "eps":
        raise ConfigError(f"ckpt={path}: an eps-predicting teacher; its x0 at t = T-1 divides by sqrt(alpha_bar) "
                          "~ 0, so a 1-step student cannot be trained on it (train with diffusion.prediction=x0 or v)")
    state = load_checkpoint(path)
    return teacher, {k: state[k] for k in TEACHER_KEYS if k in state}


def distill_entry(run: DistillRun) -> dict:
    """The checkpoint's `distill` entry: what the student is and what it was distilled from."""
    dc = run.dc
    return {"method": METHOD, "steps": dc.steps, "timesteps": run.timesteps.tolist(),
            "teacher": str(run.teacher_path.resolve()), "teacher_step": run.teacher.step,
            "teacher_steps": dc.teacher_steps, "guidance_scale": float(dc.guidance_scale),
            "bank_size": dc.bank_size, "self_states": float(dc.self_states), "seed": dc.seed}


def set_up(dc: DistillConfig, run_dir: Path, log=print) -> DistillRun:
    """The run `dc` describes in `run_dir`: teacher, bank, student (the teacher's EMA weights),
    EMA, optimiser; resumed from the run's checkpoint when `dc.resume` asks."""
    teacher_path = check_paths(dc, run_dir)
    device = resolve_device(dc.device)
    if dc.threads:
        torch.set_num_threads(dc.threads)
    ckpt = find_resume(run_dir) if dc.resume == "auto" else (Path(dc.resume) if dc.resume else None)
    state = load_checkpoint(ckpt) if ckpt else None
    teacher, teacher_state = load_teacher(teacher_path, device)
    if state is not None:                 # refused before the bank is made, not minutes after
        check_resumable(state, ckpt, dc, teacher_path)
    torch.manual_seed(dc.seed)
    bank = load_or_make_bank(run_dir, dc, teacher_path, teacher, device, log)
    student = copy.deepcopy(teacher.model).train(dc.dropout).requires_grad_(True)
    opt = torch.optim.Adam(student.parameters(), lr=dc.lr)
    run = DistillRun(dc, run_dir, device, teacher_path, teacher, teacher_state, bank, student, EMA(student, dc.ema_decay),
                     opt, torch.optim.lr_scheduler.LambdaLR(opt, lr_lambda(dc)),
                     torch.Generator().manual_seed(dc.seed * 7919 + 1), student_timesteps(teacher.diffusion, dc.steps))
    if state is not None:
        _restore(run, state, ckpt, log)
    return run


def check_resumable(state: dict, ckpt: Path, dc: DistillConfig, teacher_path: Path) -> None:
    """Refuse to resume from a checkpoint that is not a student of this same config and teacher
    (its student learnt something else)."""
    theirs = state.get("distill")
    if theirs is None:
        raise ConfigError(f"resume: {ckpt} is not a distilled student's checkpoint")
    mine = {"steps": dc.steps, "teacher": str(teacher_path.resolve()), "teacher_steps": dc.teacher_steps,
            "guidance_scale": float(dc.guidance_scale), "bank_size": dc.bank_size, "seed": dc.seed}
    differ = [k for k, v in mine.items() if theirs.get(k) != v]
    if differ:
        raise ConfigError(f"resume: {ckpt} was distilled with other {', '.join(differ)} "
                          f"({', '.join(f'{k}={theirs.get(k)}' for k in differ)}); give another out= or resume=null")


def _restore(run: DistillRun, state: dict, ckpt: Path, log) -> None:
    """Weights, EMA, optimiser, schedule, position and RNGs from a student checkpoint."""
    run.student.load_state_dict(state["model"])
    run.ema.load_state_dict(state["ema"])
    run.opt.load_state_dict(state["optimizer"])
    run.sched.load_state_dict(state["scheduler"])
    run.step = int(state["step"])
    set_rng_state(state["rng"][0], run.gen, run.step)
    log(f"resumed from {ckpt} at step {run.step}")


def distill_step(run: DistillRun, idx) -> dict:
    """One optimiser step on bank entries `idx`: each window at a student step i drawn at
    random, its state the teacher's (or, for a `self_states` share with i > 0, the student's
    own), its loss the x0 error against the teacher's output. Returns the step's numbers."""
    dc, n, diffusion = run.dc, run.dc.steps, run.teacher.diffusion
    b = run.bank.batch(idx, run.device)
    B = len(idx)
    i = torch.randint(0, n, (B,), generator=run.gen)                                  # (B,) student step
    x_t = b["states"][torch.arange(B, device=run.device), i.to(run.device)]           # (B, L, D)
    own = (torch.rand(B, generator=run.gen) < dc.self_states) & (i > 0)
    if bool(own.any()):
        run.student.eval()                   # the student's own path as it samples: no dropout
        x_own = student_states(diffusion, run.student, b["states"][:, 0], torch.where(own, i, 0).to(run.device),
                               n, b["cond"], b["known"], b["known_mask"])
        run.student.train(dc.dropout)
        x_t = torch.where(own.to(run.device)[:, None, None], x_own, x_t)
    t = run.timesteps[i].to(run.device)
    per_window = distill_loss(diffusion, run.student, x_t, t, b["cond"], b["target"], b["known"], b["known_mask"],
                              loss_mask(b["known_mask"], run.teacher.predict_goal), reduce=False)     # (B,)
    loss = per_window.mean()
    run.opt.zero_grad(set_to_none=True)
    loss.backward()
    gnorm = torch.nn.utils.clip_grad_norm_(run.student.parameters(), dc.grad_clip if dc.grad_clip > 0 else float("inf"))
    if not (torch.isfinite(loss) and torch.isfinite(gnorm)):
        raise TrainingDiverged(f"distill: non-finite loss or gradient at step {run.step}; lower lr= "
                               f"(the last checkpoint in {run.run_dir / 'checkpoints'} is kept)")
    run.opt.step()
    run.sched.step()
    run.ema.update(run.student)
    run.step += 1
    per_step = {f"loss_step{k}": float(per_window.detach()[i == k].mean()) for k in range(n) if bool((i == k).any())}
    return {"loss": float(loss.detach()), "grad_norm": float(gnorm.detach()), **per_step}


def save(run: DistillRun) -> Path:
    """The student checkpoint at this step (atomic; `last.pt` links to it)."""
    payload = {**run.teacher_state, "step": run.step, "model": run.student.state_dict(),
               "ema": run.ema.state_dict(), "optimizer": run.opt.state_dict(), "scheduler": run.sched.state_dict(),
               "rng": [rng_state(run.gen)], "distill": distill_entry(run)}
    return save_checkpoint(payload, run.run_dir / "checkpoints", run.step, run.dc.keep_last)


def distill(dc: DistillConfig, run_dir: Path, log=print) -> Path:
    """Train the student `dc` describes in `run_dir`; returns its last checkpoint."""
    run_dir = Path(run_dir)
    run = set_up(dc, run_dir, log)
    remove_orphan_temps(run_dir / "checkpoints")
    _write_config(dc, run_dir / "distill_config.yaml")
    from torch.utils.tensorboard import SummaryWriter  # heavy to import: only once the run is set up

    run.writer = SummaryWriter(run_dir / "tb", purge_step=run.step if run.step else None)
    log(f"distilling {run.teacher_path} (step {run.teacher.step}) into a {dc.steps}-step student at timesteps "
        f"{run.timesteps.tolist()} in {run_dir}: step {run.step} of {dc.max_steps} on {run.device}")
    try:
        _loop(run, log)
    except KeyboardInterrupt:
        last = run_dir / "checkpoints" / "last.pt"
        raise Interrupted(f"last checkpoint {last}; continue with the same command" if last.is_file()
                          else "stopped before the first checkpoint: nothing to resume from") from None
    finally:
        run.writer.close()
    return run_dir / "checkpoints" / "last.pt"


def _write_config(dc: DistillConfig, path: Path) -> None:
    """The run's keys as YAML (what train's resolved_config.yaml is to a training run), renamed into place."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(OmegaConf.to_yaml(OmegaConf.structured(dc)))
    os.replace(tmp, path)


def _loop(run: DistillRun, log) -> None:
    """Steps to `max_steps` in the resumable batch order, logging and checkpointing at intervals."""
    dc = run.dc
    order = iter(ResumableBatchSampler(len(run.bank), dc.batch_size, dc.seed, position=run.step))
    bar = tqdm(total=dc.max_steps, initial=run.step, desc="distill") if dc.progress and sys.stderr.isatty() else None
    sums, count, t_line, t0 = {}, 0, time.perf_counter(), time.perf_counter()
    while run.step < dc.max_steps:
        numbers = distill_step(run, next(order))
        for k, v in numbers.items():
            sums.setdefault(k, []).append(v)
        count += 1
        last = run.step == dc.max_steps
        if run.step % dc.log_every == 0 or last:
            means = {k: sum(v) / len(v) for k, v in sums.items()}
            for k, v in means.items():
                run.writer.add_scalar(f"distill/{k}", v, run.step)
            run.writer.add_scalar("distill/lr", run.sched.get_last_lr()[0], run.step)
            if time.perf_counter() - t_line >= LINE_EVERY_S or last:
                rate = count * dc.batch_size / (time.perf_counter() - t0)
                log(f"step {run.step}/{dc.max_steps}  loss {means['loss']:.5f}  {rate:.0f} windows/s")
                t_line = time.perf_counter()
            sums, count, t0 = {}, 0, time.perf_counter()
        if run.step % dc.ckpt_every == 0 or last:
            save(run)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
