"""Setting up a training run, step by step: the device and process group, the checkpoint to
resume from, the data, the model with its EMA, optimiser and schedule (restored on resume), the
batch loader and the event writer, gathered in one `Run` that the loop
(`motiongen.training.trainer`) advances.

The order of the steps is part of the result: the model's initial weights come from the global
RNG seeded first, and a resumed run restores every RNG after building, so a run killed and
resumed ends bitwise equal to one that ran through.
"""

from __future__ import annotations

import math
import os
import random
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from torch.nn.parallel import DistributedDataParallel as DDP
from torch.utils.data import DataLoader

from motiongen.data import swing_rise
from motiongen.data.format import MotionDataset
from motiongen.data.windows import NormStats, WindowDataset
from motiongen.diffusion.gaussian import GaussianDiffusion
from motiongen.errors import ConfigError
from motiongen.importers.sources import open_dataset
from motiongen.loading.build import build_from_config, data_config, load_weights, mask_config, window_config
from motiongen.loading.checkpoint import find_resume, load_checkpoint
from motiongen.training import distributed as dd
from motiongen.training.data_order import ResumableBatchSampler
from motiongen.training.ema import EMA
from motiongen.training.train_config import TrainConfig


@dataclass
class Run:
    """One training run: its settings and process, data, model and optimiser state, and the
    loop's position (`step`, `best_val`), which the loop advances."""

    cfg: DictConfig
    tc: TrainConfig
    run_dir: Path
    info: dd.DistInfo
    device: torch.device
    amp: str                                # "bf16" | "none"
    ds: MotionDataset
    train_set: WindowDataset
    val_set: WindowDataset | None           # None: no validation
    model: torch.nn.Module                  # the bare model: weights, EMA, checkpoints
    diffusion: GaussianDiffusion
    meta: dict                              # the model's description, saved with every checkpoint
    ema: EMA
    opt: torch.optim.Optimizer
    sched: torch.optim.lr_scheduler.LambdaLR
    noise_gen: torch.Generator              # this rank's noise, timesteps and condition dropout
    step: int = 0
    best_val: float = float("inf")
    net: torch.nn.Module | None = None      # what the loop calls: the model or its DDP wrapper
    loader: DataLoader | None = None
    writer: object = None                   # SummaryWriter on rank 0, None elsewhere


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


def rng_state(gen: torch.Generator) -> dict:
    """Every RNG the run draws from (global torch, numpy, python, CUDA, and `gen`)."""
    s = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate(),
         "noise": gen.get_state()}
    if torch.cuda.is_available():
        s["cuda"] = torch.cuda.get_rng_state_all()
    return s


def set_rng_state(s: dict, gen: torch.Generator, step: int) -> None:
    torch.set_rng_state(s["torch"])
    np.random.set_state(s["numpy"])
    random.setstate(s["python"])
    try:
        gen.set_state(s["noise"])
    except RuntimeError:
        # A checkpoint written on another kind of device (a CUDA generator's state on a CPU run):
        # its noise cannot continue here, so the noise is reseeded from the step. The run goes
        # on, but is not bitwise the one that would have continued on the first device.
        gen.manual_seed(gen.initial_seed() + step)
        print(f"warning: the checkpoint's noise generator is from another device type; reseeded at step {step} "
              f"(the resumed run is not bitwise the uninterrupted one)", flush=True)
    if "cuda" in s and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(s["cuda"])


def set_up(cfg: DictConfig, run_dir: Path) -> Run:
    """The run `cfg` describes in `run_dir`, resumed from its checkpoint when `train.resume` asks."""
    tc = TrainConfig(**OmegaConf.to_container(cfg.train, resolve=True))
    device, info, amp = _process(tc)
    seed = int(cfg.seed)
    torch.manual_seed(seed)   # same init on every rank (DDP also broadcasts rank 0's weights)
    np.random.seed(seed)
    random.seed(seed)
    ckpt_path, state = _resume_checkpoint(tc, run_dir, info)
    ds, train_set, val_set = _data(cfg, tc, info, state)
    model, diffusion, meta = build_from_config(cfg, ds.joint_set, ds.action_names)
    meta.update(swing_meta(ds, state, train_set.cfg.stance_speed))
    model.to(device)
    ema = EMA(model, tc.ema_decay)
    opt = torch.optim.Adam(model.parameters(), lr=tc.lr, weight_decay=tc.weight_decay, fused=True)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lr_lambda(tc))
    noise_gen = torch.Generator(device=device).manual_seed(seed * 7919 + info.rank)
    run = Run(cfg, tc, run_dir, info, device, amp, ds, train_set, val_set, model, diffusion, meta, ema, opt,
              sched, noise_gen)
    if state:
        _restore(run, state, ckpt_path)
    run.net = DDP(model, device_ids=[device.index] if device.type == "cuda" else None) if info.enabled else model
    sampler = ResumableBatchSampler(len(train_set), tc.batch_size, seed, info.rank, info.world, position=run.step)
    run.loader = DataLoader(train_set, batch_sampler=sampler, num_workers=tc.num_workers,
                            pin_memory=device.type == "cuda", persistent_workers=tc.num_workers > 0,
                            generator=torch.Generator())   # own generator: iterator start must not touch global RNG
    if info.is_main:
        from torch.utils.tensorboard import SummaryWriter  # heavy to import; only rank 0 writes events

        run.writer = SummaryWriter(run_dir / "tb", purge_step=run.step if run.step else None)
        OmegaConf.save(cfg, run_dir / "resolved_config.yaml")
    return run


def _process(tc: TrainConfig) -> tuple[torch.device, dd.DistInfo, str]:
    """This process's device, place in the process group and torch settings; the settings that
    need the device checked. Returns (device, process info, amp "bf16" | "none")."""
    device = resolve_device(tc.device)
    dd.check_batch_split("train.batch_size", tc.batch_size)
    info = dd.init_distributed(device.type)
    if info.enabled and device.type == "cuda":
        device = torch.device("cuda", info.local_rank)
    if tc.threads:
        torch.set_num_threads(tc.threads)
    elif device.type == "cpu":
        # Loader workers need cores too; oversubscribed OpenMP threads spin and stall every op,
        # so each process takes its share of the cores less one per loader worker.
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
    return device, info, amp


def _resume_checkpoint(tc: TrainConfig, run_dir: Path, info: dd.DistInfo) -> tuple[Path | None, dict | None]:
    """The checkpoint `train.resume` names ("auto": the run's last one, if any) and its contents."""
    ckpt_path = None
    if tc.resume == "auto":
        ckpt_path = find_resume(run_dir)
        if ckpt_path is None and info.is_main:
            print(f"train.resume=auto: no checkpoint in {run_dir / 'checkpoints'}; starting fresh", flush=True)
    elif tc.resume:
        ckpt_path = Path(tc.resume).expanduser()
    return ckpt_path, (load_checkpoint(ckpt_path) if ckpt_path else None)


def _data(cfg: DictConfig, tc: TrainConfig, info: dd.DistInfo, state: dict | None):
    """The dataset (opened, or generated or converted, by rank 0 first), its training windows
    (normalised with the checkpoint's statistics on resume) and validation windows (None when
    validation is off or the split is empty)."""
    dcfg, wcfg = data_config(cfg), window_config(cfg)
    if info.is_main:
        ds = open_dataset(dcfg)
    dd.barrier(info)
    if not info.is_main:
        ds = open_dataset(dcfg, verbose=False)
    stats = NormStats.from_state_dict(state["stats"]) if state else None
    # The window the sampler's loop hands its last k frames on from starts L - k frames earlier.
    previous = 0
    if tc.rollout_p > 0:
        k = mask_config(cfg).max_transition
        if not 1 <= k < wcfg.length:
            raise ConfigError(f"train.rollout_p needs transition frames to hand on: mask.max_transition is {k}")
        previous = wcfg.length - k
    train_set = WindowDataset(ds, "train", wcfg, stats, previous)
    if len(train_set) < tc.batch_size:
        raise ConfigError(f"train split has {len(train_set)} windows, fewer than train.batch_size={tc.batch_size}")
    val_set = WindowDataset(ds, "val", wcfg, train_set.stats) if tc.val_every else None
    if val_set is not None and len(val_set) == 0:
        val_set = None
    return ds, train_set, val_set


def swing_meta(ds: MotionDataset, state: dict | None, stance_speed: float = 0.2) -> dict:
    """{"swing_rise": the training split's swing table} for the checkpoint (the sampler's swing
    lift, `data/swing_rise.py`), its plants from the stance labels the network learns
    (`window.stance_speed`); a resumed run keeps its checkpoint's; {} when the data has no
    swing to measure (the sampler then takes the embedded dataset's)."""
    if state is not None:
        return {"swing_rise": state["swing_rise"]} if "swing_rise" in state else {}
    table = swing_rise.measure(ds, "train", stance_speed)
    return {} if table is None else {"swing_rise": table.state_dict()}


def _restore(run: Run, state: dict, ckpt_path: Path) -> None:
    """Weights, EMA, optimiser, schedule, position and this rank's RNGs from a checkpoint."""
    load_weights(run.model, state["model"], ckpt_path, "model", "this run's config")
    load_weights(run.ema.model, state["ema"], ckpt_path, "ema", "this run's config")
    run.opt.load_state_dict(state["optimizer"])
    run.sched.load_state_dict(state["scheduler"])
    run.step, run.best_val = int(state["step"]), float(state.get("best_val", float("inf")))
    info = run.info
    rng = state["rng"][info.rank] if info.rank < len(state["rng"]) else state["rng"][0]
    set_rng_state(rng, run.noise_gen, run.step)
    if info.is_main:
        print(f"resumed from {ckpt_path} at step {run.step}", flush=True)
