"""The training loop (nanoGPT-style: one readable function, helpers around it)."""

from __future__ import annotations

import math
import os
import random
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from torch.nn.parallel import DistributedDataParallel as DDP
from torch.utils.data import DataLoader

from motiongen.importers.sources import open_dataset
from motiongen.data.windows import NormStats, WindowDataset
from motiongen.diffusion.masks import loss_mask
from motiongen.errors import ConfigError, MotiongenError
from motiongen.training import distributed as dd
from motiongen.loading.build import (batch_condition, build_from_config, data_config, known_mask_for_batch,
                                         goal_predicted, loss_channel_weights, window_config)
from motiongen.loading.checkpoint import find_resume, load_checkpoint, save_checkpoint
from motiongen.training.settings import TrainConfig
from motiongen.training.data_order import ResumableBatchSampler
from motiongen.training.ema import EMA

CKPT_FORMAT = "motiongen-checkpoint"


class TrainingDiverged(MotiongenError):
    pass


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise ConfigError(f"train.device={name!r} is not a device (use auto, cpu, cuda or cuda:N)") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError("train.device=cuda but no CUDA device is available")
    return dev


def lr_lambda(tc: TrainConfig):
    def f(step: int) -> float:
        if tc.warmup_steps and step < tc.warmup_steps:
            return (step + 1) / tc.warmup_steps
        if tc.lr_schedule == "cosine":
            p = min(1.0, (step - tc.warmup_steps) / max(1, tc.max_steps - tc.warmup_steps))
            return tc.min_lr_ratio + (1 - tc.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * p))
        return 1.0
    return f


def _rng_state(gen: torch.Generator) -> dict:
    s = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate(),
         "noise": gen.get_state()}
    if torch.cuda.is_available():
        s["cuda"] = torch.cuda.get_rng_state_all()
    return s


def _set_rng_state(s: dict, gen: torch.Generator) -> None:
    torch.set_rng_state(s["torch"])
    np.random.set_state(s["numpy"])
    random.setstate(s["python"])
    gen.set_state(s["noise"])
    if "cuda" in s and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(s["cuda"])


def _weights_checksum(model: torch.nn.Module) -> str:
    """A digest of every parameter's bytes: equal iff the weights are bitwise equal."""
    import hashlib

    h = hashlib.sha1()
    for p in model.parameters():
        h.update(p.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def train(cfg: DictConfig, run_dir: Path) -> Path | None:
    """Train per `cfg` in `run_dir`; returns the last checkpoint's path on rank 0, None elsewhere."""
    tc = TrainConfig(**OmegaConf.to_container(cfg.train, resolve=True))
    device = resolve_device(tc.device)
    info = dd.init_distributed(device.type)
    if info.enabled and device.type == "cuda":
        device = torch.device("cuda", info.local_rank)
    if tc.threads:
        torch.set_num_threads(tc.threads)
    elif device.type == "cpu":
        # Loader workers need cores too; oversubscribed OpenMP threads spin and stall every op
        # (measured: 2 threads + 2 workers on 2 cores ran >10x slower than 1 thread).
        per_proc = max(1, (os.cpu_count() or 1) // info.world - tc.num_workers)
        torch.set_num_threads(per_proc)
    if tc.deterministic:
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        torch.use_deterministic_algorithms(True, warn_only=True)
    if tc.ckpt_every <= 0 or tc.max_steps <= 0:
        raise ConfigError("train.ckpt_every and train.max_steps must be positive")
    amp = tc.amp if tc.amp != "auto" else ("bf16" if device.type == "cuda" else "none")
    if amp not in ("bf16", "none"):
        raise ConfigError(f"train.amp must be auto, bf16 or none, got {tc.amp!r}")
    seed = int(cfg.seed)
    torch.manual_seed(seed)   # same init on every rank (DDP also broadcasts rank 0's weights)
    np.random.seed(seed)
    random.seed(seed)

    # ---- resume ------------------------------------------------------------------------
    ckpt_path = None
    if tc.resume == "auto":
        ckpt_path = find_resume(run_dir)
        if ckpt_path is None and info.is_main:
            print(f"train.resume=auto: no checkpoint in {run_dir / 'checkpoints'}; starting fresh", flush=True)
    elif tc.resume:
        ckpt_path = Path(tc.resume).expanduser()
    state = load_checkpoint(ckpt_path) if ckpt_path else None

    # ---- data --------------------------------------------------------------------------
    dcfg, wcfg = data_config(cfg), window_config(cfg)
    if info.is_main:
        ds = open_dataset(dcfg)
    dd.barrier(info)
    if not info.is_main:
        ds = open_dataset(dcfg, verbose=False)
    stats = NormStats.from_state_dict(state["stats"]) if state else None
    train_set = WindowDataset(ds, "train", wcfg, stats)
    stats = train_set.stats
    if len(train_set) < tc.batch_size:
        raise ConfigError(f"train split has {len(train_set)} windows, fewer than train.batch_size={tc.batch_size}")
    val_set = WindowDataset(ds, "val", wcfg, stats) if tc.val_every else None
    if val_set is not None and len(val_set) == 0:
        val_set = None

    # ---- model, diffusion, optimiser -----------------------------------------------------
    model, diffusion, meta = build_from_config(cfg, ds.joint_set, ds.action_names)
    model.to(device)
    ema = EMA(model, tc.ema_decay)
    opt = torch.optim.Adam(model.parameters(), lr=tc.lr, weight_decay=tc.weight_decay, fused=True)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lr_lambda(tc))
    noise_gen = torch.Generator(device=device).manual_seed(seed * 7919 + info.rank)
    step = 0
    best_val = float("inf")
    if state:
        model.load_state_dict(state["model"])
        ema.load_state_dict(state["ema"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        step, best_val = int(state["step"]), float(state.get("best_val", float("inf")))
        rng = state["rng"][info.rank] if info.rank < len(state["rng"]) else state["rng"][0]
        _set_rng_state(rng, noise_gen)
        if info.is_main:
            print(f"resumed from {ckpt_path} at step {step}", flush=True)
    net = DDP(model, device_ids=[device.index] if device.type == "cuda" else None) if info.enabled else model

    sampler = ResumableBatchSampler(len(train_set), tc.batch_size, seed, info.rank, info.world, position=step)
    loader = DataLoader(train_set, batch_sampler=sampler, num_workers=tc.num_workers,
                        pin_memory=device.type == "cuda", persistent_workers=tc.num_workers > 0,
                        generator=torch.Generator())   # own generator: iterator start must not touch global RNG
    writer = None
    if info.is_main:
        from torch.utils.tensorboard import SummaryWriter
        writer = SummaryWriter(run_dir / "tb", purge_step=step if step else None)
        OmegaConf.save(cfg, run_dir / "resolved_config.yaml")

    def checkpoint(best: bool = False) -> Path | None:
        rngs = dd.gather_objects(_rng_state(noise_gen), info)
        # Every rank must hold the same weights (DDP averages gradients; a rank-dependent code
        # path that skips a parameter would let them drift): compare exact checksums.
        sums = dd.gather_objects(_weights_checksum(model), info)
        if len(set(sums)) > 1:
            raise TrainingDiverged(f"model weights differ between DDP ranks at step {step} (checksums {sums})")
        if not info.is_main:
            return None
        payload = {
            "format": CKPT_FORMAT, "version": 1, "step": step, "best_val": best_val,
            "model": model.state_dict(), "ema": ema.state_dict(), "optimizer": opt.state_dict(),
            "scheduler": sched.state_dict(), "rng": rngs, "data_position": step,
            "config": OmegaConf.to_container(cfg, resolve=True), "stats": stats.state_dict(), "fps": ds.fps,
            "rank_checksums": sums, **meta,
        }
        return save_checkpoint(payload, run_dir / "checkpoints", step, tc.keep_last, best=best)

    # ---- loop ----------------------------------------------------------------------------
    autocast = torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp == "bf16")
    weights = loss_channel_weights(tc, train_set.layout.channels, device)
    predict_goal = goal_predicted(cfg)
    it = iter(loader)
    bar = None
    if info.is_main and tc.progress:
        from tqdm import tqdm
        bar = tqdm(total=tc.max_steps, initial=step, desc="train", dynamic_ncols=True)
    sums: dict[str, torch.Tensor] = {}
    nonfinite = torch.zeros((), dtype=torch.bool, device=device)
    t_log, n_log, last_path = time.perf_counter(), 0, None
    net.train()
    while step < tc.max_steps:
        batch = next(it)
        x0 = batch["motion"].to(device, non_blocking=True)                        # (B, L, D)
        B = x0.shape[0]
        cond = batch_condition(batch, device, tc, noise_gen, train=True)
        known_mask = known_mask_for_batch(cfg, x0.shape, ds.joint_set.num_joints, device, noise_gen)
        t = torch.randint(0, diffusion.num_timesteps, (B,), device=device, generator=noise_gen)
        noise = torch.randn(x0.shape, device=device, generator=noise_gen)
        with autocast:
            losses = diffusion.training_losses(net, x0, t, cond, known=x0, known_mask=known_mask, noise=noise,
                                               channel_weights=weights, loss_mask=loss_mask(known_mask, predict_goal))
        loss = losses["loss"]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        gnorm = torch.nn.utils.clip_grad_norm_(model.parameters(), tc.grad_clip if tc.grad_clip > 0 else float("inf"))
        nonfinite |= ~torch.isfinite(loss.detach()) | ~torch.isfinite(gnorm)
        opt.step()
        sched.step()
        ema.update(model)
        step += 1
        n_log += B * info.world
        for k, v in losses.items():
            sums[k] = sums.get(k, 0) + v.detach().float()
        sums["grad_norm"] = sums.get("grad_norm", 0) + gnorm.detach().float()

        at_log = step % tc.log_every == 0 or step == tc.max_steps
        at_ckpt = step % tc.ckpt_every == 0 or step == tc.max_steps
        at_val = val_set is not None and tc.val_every and (step % tc.val_every == 0 or step == tc.max_steps)
        if at_log or at_ckpt or at_val:
            # the one host sync: only at intervals
            if bool(dd.all_reduce_mean(nonfinite.float(), info) > 0):
                raise TrainingDiverged(
                    f"non-finite loss or gradient before step {step}; stopped. The last good checkpoint "
                    f"({run_dir / 'checkpoints' / 'last.pt'}) is kept — lower train.lr or enable train.grad_clip")
        if at_log:
            n = tc.log_every if step % tc.log_every == 0 else (step % tc.log_every or tc.log_every)
            means = {k: float(dd.all_reduce_mean(v / n, info)) for k, v in sums.items()}
            rate = n_log / (time.perf_counter() - t_log)
            if writer:
                for k, v in means.items():
                    writer.add_scalar(f"train/{k}", v, step)
                writer.add_scalar("train/lr", sched.get_last_lr()[0], step)
                writer.add_scalar("train/samples_per_s", rate, step)
            if bar:
                bar.set_postfix(loss=f"{means['loss']:.4f}", rate=f"{rate:.0f}/s")
            sums, t_log, n_log = {}, time.perf_counter(), 0
        is_best = False
        if at_val and info.is_main:
            from motiongen.training.validate import validation_loss
            v = validation_loss(ema.model, diffusion, val_set, cfg, tc, device, autocast)
            writer.add_scalar("val/loss", v, step)
            if v < best_val:
                best_val, is_best = v, True
        if at_val:
            is_best = bool(dd.gather_objects(is_best, info)[0])   # checkpoint() is collective
        if tc.figure_every and info.is_main and (step % tc.figure_every == 0 or step == tc.max_steps):
            from motiongen.training.figures import log_sample_figure
            log_sample_figure(writer, ema.model, diffusion, val_set or train_set, cfg, device, step)
        if at_ckpt or is_best:
            last_path = checkpoint(best=is_best) or last_path
        if bar:
            bar.update(1)
    if bar:
        bar.close()
    if writer:
        writer.close()
    dd.barrier(info)
    dd.shutdown(info)
    return run_dir / "checkpoints" / "last.pt" if info.is_main else None
