"""The training loop: `train` sets a run up (`motiongen.training.setup`), then steps it, with
logging, validation, figures and checkpoints at their intervals.

The run's log goes through Python logging (Hydra's job logging: the console and
`<run dir>/train.log`): a start line, a progress line at a log interval at most every
`LINE_EVERY_S` seconds (and at the last step), the end. On a terminal the tqdm bar shows
progress between them; with output redirected there is no bar, only those lines."""

from __future__ import annotations

import contextlib
import hashlib
import logging
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterator

import torch
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

from motiongen.cli import Interrupted
from motiongen.diffusion.masks import MaskConfig, loss_mask
from motiongen.errors import ConfigError, MotiongenError
from motiongen.loading.build import (acting_hands, batch_condition, facing_goals, goal_predicted, hand_goal_weights,
                                     known_mask_for_batch, loss_channel_weights, mask_config)
from motiongen.loading.checkpoint import remove_orphan_temps, save_checkpoint
from motiongen.training import distributed as dd
from motiongen.training.body_losses import BodyLosses
from motiongen.training.figures import log_sample_figure
from motiongen.training.rollout import own_transitions
from motiongen.training.setup import Run, rng_state, set_up
from motiongen.training.validate import validation_loss

CKPT_FORMAT = "motiongen-checkpoint"
LINE_EVERY_S = 10.0       # the shortest time between two progress lines in the log

log = logging.getLogger(__name__)


class TrainingDiverged(MotiongenError):
    pass


@dataclass
class _Loop:
    """The loop's own state beside the run: its batches, the fixed inputs of every step, and
    what accumulates on the device between log points (the host syncs only at intervals)."""

    batches: Iterator
    autocast: torch.autocast
    weights: torch.Tensor | None            # per-channel loss weights
    predict_goal: bool
    bar: tqdm | None
    nonfinite: torch.Tensor                 # () bool: a non-finite loss or gradient so far
    body: BodyLosses | None                 # geometry on the prediction (train.w_bone_length, w_planted_feet)
    mask: MaskConfig                        # the training masks' config, read once
    sums: dict[str, torch.Tensor] = field(default_factory=dict)   # loss terms since the last log
    t_log: float = field(default_factory=time.perf_counter)
    n_log: int = 0                          # samples since the last log, all ranks
    t_line: float = field(default_factory=time.perf_counter)     # the last progress line
    saved_step: int | None = None           # the step of this run's last checkpoint


def train(cfg: DictConfig, run_dir: Path) -> Path | None:
    """Train per `cfg` in `run_dir`; returns the last checkpoint's path on rank 0, None elsewhere."""
    run = set_up(cfg, run_dir)
    if run.info.is_main:
        remove_orphan_temps(run_dir / "checkpoints")     # left by a run killed mid-checkpoint
        log.info(f"training in {run_dir}: step {run.step} of {run.tc.max_steps} on {run.device}"
                 f"{f' x {run.info.world} processes' if run.info.enabled else ''}")
    loop = _start_loop(run)
    run.net.train()
    try:
        # Log lines printed above the bar rather than through it.
        with logging_redirect_tqdm() if loop.bar else contextlib.nullcontext():
            while run.step < run.tc.max_steps:
                _train_step(run, loop, next(loop.batches))
                _at_intervals(run, loop)
                if loop.bar:
                    loop.bar.update(1)
    except KeyboardInterrupt:
        raise Interrupted(_resume_note(run, loop)) from None
    finally:
        if loop.bar:
            loop.bar.close()
        if run.writer:
            run.writer.close()
    if run.info.is_main:
        log.info(f"finished at step {run.step}")
    dd.barrier(run.info)
    dd.shutdown(run.info)
    return run_dir / "checkpoints" / "last.pt" if run.info.is_main else None


def _start_loop(run: Run) -> _Loop:
    tc = run.tc
    autocast = torch.autocast(run.device.type, dtype=torch.bfloat16, enabled=run.amp == "bf16")
    weights = loss_channel_weights(tc, run.train_set.layout.channels, run.device)
    predict_goal = goal_predicted(run.cfg)
    batches = iter(run.loader)
    bar = None
    if run.info.is_main and tc.progress and sys.stderr.isatty():
        # A bar only on a terminal: redirected, its redraws would pile up in one line of the file.
        bar = tqdm(total=tc.max_steps, initial=run.step, desc="train", dynamic_ncols=True)
    nonfinite = torch.zeros((), dtype=torch.bool, device=run.device)
    return _Loop(batches, autocast, weights, predict_goal, bar, nonfinite, body_losses(run), mask_config(run.cfg))


def body_losses(run: Run) -> BodyLosses | None:
    """The geometry terms the config asks for, or None (every weight 0)."""
    tc, ws = run.tc, run.train_set
    if max(tc.w_bone_length, tc.w_planted_feet, tc.w_facing, tc.w_foot_height, tc.w_foot_offset, tc.w_pace,
           tc.w_facing_goal) <= 0:
        return None
    if tc.w_facing_goal > 0 and mask_config(run.cfg).p_facing <= 0:
        raise ConfigError(f"train.w_facing_goal={tc.w_facing_goal} needs facing goals (mask.p_facing > 0)")
    weights = run.diffusion.alphas_cumprod if tc.geometry_weighting == "signal" else None   # (T,)
    return BodyLosses(ws.layout, ws.stats, run.ds.joint_set.parents, run.ds.fps / ws.cfg.stride,
                      tc.w_bone_length, tc.w_planted_feet, weights, tc.geometry_start, tc.geometry_ramp,
                      tc.w_facing, tc.w_foot_height, tc.w_foot_offset, tc.w_pace, tc.w_facing_goal,
                      tc.facing_goal_norm)


def _train_step(run: Run, loop: _Loop, batch: dict) -> None:
    """One optimiser step on `batch` (noise, timesteps and masks from this rank's generator);
    its losses and gradient norm go to the loop's sums."""
    device, gen = run.device, run.noise_gen
    x0 = batch["motion"].to(device, non_blocking=True)                        # (B, L, D)
    B = x0.shape[0]
    cond = batch_condition(batch, device, run.tc, gen, train=True)
    known_mask = known_mask_for_batch(run.cfg, x0.shape, run.ds.joint_set.num_joints, device, gen,
                                      acting_hands(loop.mask, batch, run.train_set.layout, run.train_set.stats,
                                                   run.ds.action_names))
    facing = facing_goals(loop.mask, batch, run.train_set.layout, run.train_set.stats, gen)
    if facing is not None:
        cond = replace(cond, facing=facing[0].to(device), facing_given=facing[1].to(device))
    if run.tc.rollout_p > 0 and run.step >= run.tc.rollout_start:
        x0, n_own = own_transitions(run.ema.model, run.diffusion, batch, x0, known_mask, run.train_set.previous,
                                    run.train_set.layout, run.train_set.stats, run.cfg, run.tc.rollout_p,
                                    run.tc.rollout_steps, gen)
        loop.sums["own_transitions"] = loop.sums.get("own_transitions", 0) + torch.tensor(n_own / B, device=device)
    t = torch.randint(0, run.diffusion.num_timesteps, (B,), device=device, generator=gen)
    noise = torch.randn(x0.shape, device=device, generator=gen)
    if loop.body is not None:
        loop.body.step = run.step
        loop.body.facing_given = None if facing is None else facing[1].to(device)
    with loop.autocast:
        losses = run.diffusion.training_losses(run.net, x0, t, cond, known=x0, known_mask=known_mask, noise=noise,
                                               channel_weights=loop.weights,
                                               loss_mask=loss_mask(known_mask, loop.predict_goal),
                                               window_terms=loop.body,
                                               entry_weights=hand_goal_weights(known_mask, loop.mask.goal_hands,
                                                                               run.tc.hand_goal_weight))
    loss = losses["loss"]
    run.opt.zero_grad(set_to_none=True)
    loss.backward()
    clip = run.tc.grad_clip if run.tc.grad_clip > 0 else float("inf")
    gnorm = torch.nn.utils.clip_grad_norm_(run.model.parameters(), clip)
    loop.nonfinite |= ~torch.isfinite(loss.detach()) | ~torch.isfinite(gnorm)
    run.opt.step()
    run.sched.step()
    run.ema.update(run.model)
    run.step += 1
    loop.n_log += B * run.info.world
    for k, v in losses.items():
        loop.sums[k] = loop.sums.get(k, 0) + v.detach().float()
    loop.sums["grad_norm"] = loop.sums.get("grad_norm", 0) + gnorm.detach().float()


def _at_intervals(run: Run, loop: _Loop) -> None:
    """After a step: the divergence check, logging, validation, figures and checkpoints whose
    interval ends at this step (and all of them at the last step)."""
    tc, step, last = run.tc, run.step, run.step == run.tc.max_steps
    at_log = step % tc.log_every == 0 or last
    at_ckpt = step % tc.ckpt_every == 0 or last
    at_val = run.val_set is not None and tc.val_every and (step % tc.val_every == 0 or last)
    if at_log or at_ckpt or at_val:
        # the one host sync: only at intervals
        if bool(dd.all_reduce_mean(loop.nonfinite.float(), run.info) > 0):
            raise TrainingDiverged(
                f"non-finite loss or gradient before step {step}; stopped. The last good checkpoint "
                f"({run.run_dir / 'checkpoints' / 'last.pt'}) is kept — lower train.lr or enable train.grad_clip")
    if at_log:
        _log(run, loop)
    is_best = _validate(run, loop) if at_val else False
    if tc.figure_every and run.info.is_main and (step % tc.figure_every == 0 or last):
        log_sample_figure(run.writer, run.ema.model, run.diffusion, run.val_set or run.train_set, run.cfg,
                          run.device, step)
    if at_ckpt or is_best:
        _checkpoint(run, best=is_best)
        loop.saved_step = step


def _log(run: Run, loop: _Loop) -> None:
    """Mean losses over the steps since the last log (all ranks), learning rate and throughput."""
    tc, step = run.tc, run.step
    n = tc.log_every if step % tc.log_every == 0 else (step % tc.log_every or tc.log_every)
    means = {k: float(dd.all_reduce_mean(v / n, run.info)) for k, v in loop.sums.items()}
    rate = loop.n_log / (time.perf_counter() - loop.t_log)
    if run.writer:
        for k, v in means.items():
            run.writer.add_scalar(f"train/{k}", v, step)
        run.writer.add_scalar("train/lr", run.sched.get_last_lr()[0], step)
        run.writer.add_scalar("train/samples_per_s", rate, step)
    if loop.bar:
        loop.bar.set_postfix(loss=f"{means['loss']:.4f}", rate=f"{rate:.0f}/s")
    now = time.perf_counter()
    if run.info.is_main and (now - loop.t_line >= LINE_EVERY_S or step == tc.max_steps):
        lr = run.sched.get_last_lr()[0]
        log.info(f"step {step}/{tc.max_steps}  loss {means['loss']:.4f}  lr {lr:.3g}  {rate:.0f} samples/s")
        loop.t_line = now
    loop.sums, loop.t_log, loop.n_log = {}, now, 0


def _validate(run: Run, loop: _Loop) -> bool:
    """The EMA model's validation loss (rank 0); True on every rank when it is the best yet."""
    is_best = False
    if run.info.is_main:
        v = validation_loss(run.ema.model, run.diffusion, run.val_set, run.cfg, run.tc, run.device, loop.autocast)
        run.writer.add_scalar("val/loss", v, run.step)
        if v < run.best_val:
            run.best_val, is_best = v, True
    return bool(dd.gather_objects(is_best, run.info)[0])   # _checkpoint() is collective


def _resume_note(run: Run, loop: _Loop) -> str:
    """What a run interrupted at this point leaves to resume from."""
    last = run.run_dir / "checkpoints" / "last.pt"
    if loop.saved_step is not None:
        return f"last checkpoint {last} (step {loop.saved_step}); continue with train.resume=auto"
    if last.is_file():
        return f"last checkpoint {last} (from before this run); continue with train.resume=auto"
    return f"stopped at step {run.step}, before the first checkpoint: nothing to resume from"


def _weights_checksum(model: torch.nn.Module) -> str:
    """A digest of every parameter's bytes: equal iff the weights are bitwise equal."""
    h = hashlib.sha1()
    for p in model.parameters():
        h.update(p.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def _checkpoint(run: Run, best: bool = False) -> Path | None:
    """Save the run (collective: every rank sends its RNG state and weight checksum; rank 0
    writes). Returns the path on rank 0, None elsewhere."""
    info = run.info
    rngs = dd.gather_objects(rng_state(run.noise_gen), info)
    # Every rank must hold the same weights (DDP averages gradients; a rank-dependent code
    # path that skips a parameter would let them drift): compare exact checksums.
    sums = dd.gather_objects(_weights_checksum(run.model), info)
    if len(set(sums)) > 1:
        raise TrainingDiverged(f"model weights differ between DDP ranks at step {run.step} (checksums {sums})")
    if not info.is_main:
        return None
    payload = {
        "format": CKPT_FORMAT, "version": 1, "step": run.step, "best_val": run.best_val,
        "model": run.model.state_dict(), "ema": run.ema.state_dict(), "optimizer": run.opt.state_dict(),
        "scheduler": run.sched.state_dict(), "rng": rngs, "data_position": run.step,
        "config": OmegaConf.to_container(run.cfg, resolve=True), "stats": run.train_set.stats.state_dict(),
        "fps": run.ds.fps, "rank_checksums": sums, **run.meta,
    }
    return save_checkpoint(payload, run.run_dir / "checkpoints", run.step, run.tc.keep_last, best=best)
