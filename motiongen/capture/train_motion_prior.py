"""Train a LEMO motion prior (`motiongen train-motion-prior kind=smooth|infill`).

    smooth   reconstruction of clean marker windows + w_smooth x the latent's smoothness
             (mean ||z_{t+1} - z_t||^2): the autoencoder whose latent the fit keeps smooth.
    infill   the full markers from masked ones: the lower-body markers
             (`markers.markers_of_joints(bm, LOWER_BODY_JOINTS)`) removed over random blocks of
             mask_block_min_s..mask_block_max_s seconds (about mask_frac of the frames), plus, in
             a mask_extra_prob share of the windows, random single entries at mask_extra_rate.
             The loss is the mean over the *missing* entries plus w_visible x the mean over the
             observed ones: `infill` returns observed entries as given, so only the missing ones
             matter at use; the small visible weight keeps the network's output coherent with its
             input (an easy, dense signal early in training) without spending capacity on it.

Both: windows of `window` frames drawn from the train split by a torch.Generator seeded by
(seed, step), mirrored left/right with probability mirror_prob, each in its own canonical frame
(`motion_prior.canonical_frames`) and normalised by per-(marker, coordinate) statistics of the
training data; losses in normalised units. Adam at `lr`. Every ckpt_every steps
`out/checkpoints/last.pt` (model, optimizer, step, RNG state, the config) is written atomically;
`resume=auto` continues from it, and a resumed run ends bitwise equal to one that ran through.
TensorBoard scalars go to `out/tb`; at the end `out/prior.pt` (`motion_prior.save_prior`).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from motiongen.body._threads import torch_threads
from motiongen.capture.markers import LOWER_BODY_JOINTS, MIRROR, NUM_MARKERS, markers_of_joints
from motiongen.capture.motion_prior import (KINDS, MIN_STD, MotionPrior, PriorNetConfig, canonical_frames,
                                            count_parameters, save_prior, _batch_to_canonical)
from motiongen.capture.prior_data import mirror_pairs, prior_data
from motiongen.checks import require_choice, require_range
from motiongen.cli import Interrupted
from motiongen.errors import ConfigError, DataError

CKPT_FORMAT = "motiongen-motion-prior-training"

# The default recipe per kind (keys left null): measured to finish, data preparation included,
# in <= 15 minutes on 2 CPU cores with the paper's channels (docs in the module's report).
RECIPES = {
    "smooth": {"steps": 1200, "batch_size": 4, "window": 32, "lr": 3e-4},
    "infill": {"steps": 1400, "batch_size": 8, "window": 64, "lr": 3e-4},
}
# What a resumed run must share with the checkpoint's run (the rest: steps, logging, threads).
RESUME_KEYS = ("kind", "data", "seed", "batch_size", "window", "lr", "lr_schedule", "lr_min_frac", "warmup_steps",
               "grad_clip", "w_smooth", "w_visible", "mirror_prob",
               "mask_frac", "mask_block_min_s", "mask_block_max_s", "mask_extra_prob", "mask_extra_rate",
               "norm_windows", "body_model", "fit_mlp", "net")


@dataclass
class TrainPriorConfig:
    kind: str = "smooth"              # smooth | infill
    data: str = "synthetic"           # synthetic | PATH of a motiongen dataset directory
    out: str = "runs/motion_prior"
    seed: int = 0
    steps: int | None = None          # null: the kind's recipe (RECIPES)
    batch_size: int | None = None     # windows per step; null: the kind's recipe
    window: int | None = None         # frames per window; null: the kind's recipe
    lr: float | None = None           # Adam; null: the kind's recipe (the paper: 1e-4 over 150/900 epochs)
    lr_schedule: str = "cosine"       # cosine (to lr_min_frac x lr at the last step) | constant; after warmup
    lr_min_frac: float = 0.1
    warmup_steps: int = 50            # linear warm-up from 0
    grad_clip: float = 1.0            # gradient norm clip; 0: none
    log_every: int = 25
    val_every: int = 100
    ckpt_every: int = 100
    resume: Any = "auto"              # auto (continue out/checkpoints/last.pt if there) | true | false
    threads: int = 0                  # torch intra-op threads; 0: leave unchanged
    w_smooth: float = 1.0             # smooth: weight of the latent smoothness loss
    w_visible: float = 0.1            # infill: weight of the observed entries' loss (missing ones: 1)
    mirror_prob: float = 0.5          # left/right mirroring augmentation
    mask_frac: float = 0.3            # infill: expected share of frames with the lower body missing
    mask_block_min_s: float = 0.5     # infill: missing blocks last this long ...
    mask_block_max_s: float = 2.0     # ... up to this (seconds, clipped to the window)
    mask_extra_prob: float = 0.5      # infill: share of windows with random extra missing entries
    mask_extra_rate: float = 0.05     # infill: their rate per (frame, marker)
    val_windows: int = 32             # fixed windows of the val split for val loss
    norm_windows: int = 1024          # training windows the normalisation statistics come from
    body_model: str | None = None     # SMPL-X .npz; null: $MOTIONGEN_SMPLX_MODEL, else the procedural body
    fit_mlp: str = "auto"             # joints-only data: fit_joints' initialiser (auto | none | PATH)
    net: PriorNetConfig = field(default_factory=PriorNetConfig)

    def __post_init__(self):
        r = require_range
        require_choice("kind", self.kind, KINDS)
        if isinstance(self.net, dict):
            self.net = PriorNetConfig(**self.net)
        if self.net.kind != self.kind:
            raise ConfigError(f"net.kind: {self.net.kind!r} differs from kind={self.kind}; leave net.kind out "
                              "(it follows kind)")
        recipe = RECIPES[self.kind]
        for key, value in recipe.items():
            if getattr(self, key) is None:
                setattr(self, key, value)
        if self.data in (None, ""):
            raise ConfigError("data: expected synthetic or the path of a motiongen dataset directory")
        self.data = str(self.data)
        r("seed", self.seed, 0, integer=True)
        r("steps", self.steps, 1, 1 << 30, integer=True)
        r("batch_size", self.batch_size, 1, 4096, integer=True)
        r("window", self.window, 2, 1 << 16, integer=True)
        r("lr", self.lr, 0, 1, lo_open=True)
        require_choice("lr_schedule", self.lr_schedule, ("cosine", "constant"))
        r("lr_min_frac", self.lr_min_frac, 0, 1)
        r("warmup_steps", self.warmup_steps, 0, integer=True)
        r("grad_clip", self.grad_clip, 0)
        for key in ("log_every", "val_every", "ckpt_every"):
            r(key, getattr(self, key), 1, integer=True)
        r("threads", self.threads, 0, 1024, integer=True)
        for key in ("w_smooth", "w_visible"):
            r(key, getattr(self, key), 0)
        for key in ("mirror_prob", "mask_frac", "mask_extra_prob", "mask_extra_rate"):
            r(key, getattr(self, key), 0, 1)
        r("mask_block_min_s", self.mask_block_min_s, 0, lo_open=True)
        r("mask_block_max_s", self.mask_block_max_s, self.mask_block_min_s)
        r("val_windows", self.val_windows, 0, 1 << 16, integer=True)
        r("norm_windows", self.norm_windows, 1, 1 << 20, integer=True)
        if isinstance(self.resume, str) and self.resume.lower() in ("true", "false", "yes", "no"):
            self.resume = self.resume.lower() in ("true", "yes")
        if self.resume not in (True, False, "auto"):
            raise ConfigError(f"resume: expected auto, true or false, got {self.resume!r}")
        self.net.channels = self.net.resolved_channels()
        self.steps, self.batch_size, self.window = int(self.steps), int(self.batch_size), int(self.window)
        self.lr = float(self.lr)


def _plain(cfg: TrainPriorConfig) -> dict:
    d = asdict(cfg)
    d["net"] = dict(d["net"])
    return d


# ---- batches ---------------------------------------------------------------------------------

def step_generator(seed: int, step: int) -> torch.Generator:
    """The generator of training step `step` (windows, mirroring, masks): a function of (seed,
    step) alone, so a resumed run draws exactly what a straight one does."""
    return torch.Generator().manual_seed((seed * 1_000_003 + step) % (1 << 62) + 1)


class WindowSampler:
    """Windows of W frames inside single sequences of a split (each valid start equally likely)."""

    def __init__(self, frames: np.ndarray, lengths: np.ndarray, window: int, what: str):
        self.frames = torch.as_tensor(np.ascontiguousarray(frames), dtype=torch.float32)
        starts, pos = [], 0
        for n in np.asarray(lengths, np.int64):
            if n >= window:
                starts.append(np.arange(pos, pos + n - window + 1))
            pos += int(n)
        if not starts:
            raise ConfigError(f"window={window} is longer than every {what} sequence (longest "
                              f"{int(np.max(lengths)) if len(lengths) else 0} frames); choose a smaller window")
        self.starts = torch.as_tensor(np.concatenate(starts))
        self.window = window
        self.skipped = int(sum(1 for n in lengths if n < window))

    def draw(self, n: int, g: torch.Generator) -> torch.Tensor:
        i = self.starts[torch.randint(len(self.starts), (n,), generator=g)]
        return self.frames[i[:, None] + torch.arange(self.window)]                # (n, W, M, 3)


def mirror(x: torch.Tensor, perm: torch.Tensor, flip: torch.Tensor) -> torch.Tensor:
    """Left/right mirror the items `flip` (B,) bool of x (B, T, M, 3): x -> -x and each marker
    swapped with its twin (`perm`, markers.MIRROR)."""
    m = x[:, :, perm] * torch.tensor([-1.0, 1.0, 1.0], dtype=x.dtype)
    return torch.where(flip[:, None, None, None], m, x)


def infill_masks(cfg: TrainPriorConfig, B: int, T: int, M: int, lower: torch.Tensor, fps: float,
                 g: torch.Generator) -> torch.Tensor:
    """observed (B, T, M) bool: the `lower` markers missing over random blocks (each slot of
    ceil(T / mean block) carries one block with probability mask_frac, so about mask_frac of the
    frames), and in a mask_extra_prob share of the windows single entries at mask_extra_rate."""
    lo = max(1, int(round(cfg.mask_block_min_s * fps)))
    hi = max(lo, int(round(cfg.mask_block_max_s * fps)))
    lo, hi = min(lo, T), min(hi, T)
    slots = max(1, math.ceil(T / ((lo + hi) / 2)))
    on = torch.rand(B, slots, generator=g) < cfg.mask_frac
    length = torch.randint(lo, hi + 1, (B, slots), generator=g)
    start = (torch.rand(B, slots, generator=g) * (T - length + 1)).long()
    t = torch.arange(T)
    blocks = on[..., None] & (t >= start[..., None]) & (t < (start + length)[..., None])   # (B, slots, T)
    frames_missing = blocks.any(1)                                                         # (B, T)
    missing = frames_missing[..., None] & lower                                            # (B, T, M)
    extra = (torch.rand(B, 1, 1, generator=g) < cfg.mask_extra_prob) & \
            (torch.rand(B, T, M, generator=g) < cfg.mask_extra_rate)
    return ~(missing | extra)


@dataclass
class Batch:
    canon: torch.Tensor                 # (B, T, M, 3) canonical markers (all of them: the targets)
    observed: torch.Tensor | None       # (B, T, M) bool (infill)


def make_batch(cfg: TrainPriorConfig, sampler: WindowSampler, n: int, g: torch.Generator, perm: torch.Tensor,
               left, right, lower: torch.Tensor | None, fps: float, augment: bool = True) -> Batch:
    x = sampler.draw(n, g)
    flip = torch.rand(n, generator=g) < (cfg.mirror_prob if augment else 0.0)
    x = mirror(x, perm, flip)
    obs = None
    if cfg.kind == "infill":
        obs = infill_masks(cfg, n, x.shape[1], x.shape[2], lower, fps, g)
    origin, rot = canonical_frames(x, left, right, obs)
    return Batch(_batch_to_canonical(x, origin, rot), obs)


def losses(prior: MotionPrior, cfg: TrainPriorConfig, b: Batch) -> dict[str, torch.Tensor]:
    """{"loss": total, its parts, "err_cm": mean marker error (missing entries for infill)}."""
    if prior.kind == "smooth":
        img = prior.normalise(b.canon)
        out, z = prior.net(img)
        rec = (out - img).square().mean()
        smooth = (z[:, :, 1:] - z[:, :, :-1]).square().mean()
        with torch.no_grad():
            err = (prior.denormalise(out) - b.canon).norm(dim=-1).mean() * 100
        return {"loss": rec + cfg.w_smooth * smooth, "rec": rec, "smooth": smooth, "err_cm": err}
    full = prior.predict(b.canon, b.observed)                               # (B, T, M, 3) canonical
    sq = ((full - b.canon) / prior.std).square().sum(-1)                    # (B, T, M), normalised units
    miss = (~b.observed).to(sq.dtype)
    vis = 1.0 - miss
    l_miss = (sq * miss).sum() / miss.sum().clamp_min(1)
    l_vis = (sq * vis).sum() / vis.sum().clamp_min(1)
    with torch.no_grad():
        d = (full - b.canon).norm(dim=-1)
        err = (d * miss).sum() / miss.sum().clamp_min(1) * 100
    return {"loss": l_miss + cfg.w_visible * l_vis, "missing": l_miss, "visible": l_vis, "err_cm": err}


def normalisation(cfg: TrainPriorConfig, sampler: WindowSampler, perm, left, right) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-(marker, coordinate) mean and std of canonical training windows (clean, mirrored like
    training)."""
    g = torch.Generator().manual_seed(cfg.seed * 7919 + 17)
    acc, acc2, n = 0.0, 0.0, 0
    for s in range(0, cfg.norm_windows, 256):
        k = min(256, cfg.norm_windows - s)
        x = sampler.draw(k, g)
        x = mirror(x, perm, torch.rand(k, generator=g) < cfg.mirror_prob)
        origin, rot = canonical_frames(x, left, right)
        c = _batch_to_canonical(x, origin, rot).double()
        acc = acc + c.sum((0, 1))
        acc2 = acc2 + c.square().sum((0, 1))
        n += c.shape[0] * c.shape[1]
    mean = acc / n
    std = (acc2 / n - mean.square()).clamp_min(0).sqrt().clamp_min(MIN_STD)
    return mean.float(), std.float()


def lr_at(cfg: TrainPriorConfig, step: int) -> float:
    """The learning rate of step `step` (1-based): linear warm-up, then cosine or constant."""
    if cfg.warmup_steps and step <= cfg.warmup_steps:
        return cfg.lr * step / cfg.warmup_steps
    if cfg.lr_schedule == "constant":
        return cfg.lr
    span = max(1, cfg.steps - cfg.warmup_steps)
    frac = min(1.0, (step - cfg.warmup_steps) / span)
    return cfg.lr * (cfg.lr_min_frac + (1 - cfg.lr_min_frac) * 0.5 * (1 + math.cos(math.pi * frac)))


def smoothness_check(prior: MotionPrior, canon: torch.Tensor, seed: int = 0, noise_m: float = 0.02) -> dict[str, float]:
    """E_smooth (mean ||z_{t+1} - z_t||^2) of canonical windows, clean and with Gaussian noise of
    `noise_m` metres per coordinate: a working prior scores the noisy ones clearly higher."""
    g = torch.Generator().manual_seed(seed + 12345)
    noisy = canon + noise_m * torch.randn(canon.shape, generator=g)
    out = {}
    with torch.no_grad():
        for name, x in (("e_smooth_clean", canon), (f"e_smooth_noise{round(noise_m * 100)}cm", noisy)):
            z = torch.cat([prior.encode(x[s:s + 8]) for s in range(0, x.shape[0], 8)])
            out[name] = (z[:, :, 1:] - z[:, :, :-1]).square().mean().item()
    return out


# ---- checkpoints ----------------------------------------------------------------------------

def _save_atomic(obj, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _load_training_checkpoint(path: Path, cfg: TrainPriorConfig) -> dict:
    try:
        ck = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:
        raise DataError(path, None, f"unreadable training checkpoint ({type(e).__name__}); remove it or use "
                                    "resume=false") from None
    if not isinstance(ck, dict) or ck.get("format") != CKPT_FORMAT:
        raise DataError(path, None, "not a motion-prior training checkpoint; remove it or use resume=false")
    mine, theirs = _plain(cfg), ck.get("config", {})
    for key in RESUME_KEYS:
        if mine.get(key) != theirs.get(key):
            raise ConfigError(f"resume: {path} was trained with {key}={theirs.get(key)!r}, this run has "
                              f"{key}={mine.get(key)!r}; use the same value, resume=false or another out=")
    return ck


# ---- training -------------------------------------------------------------------------------

def train(cfg: TrainPriorConfig, verbose: bool = True, bm=None) -> tuple[MotionPrior, dict]:
    """Train (or resume) per `cfg`; returns the prior and the meta `save_prior` stores."""
    with torch_threads(cfg.threads):
        return _train(cfg, verbose, bm)


# One training run in order: resume check, data, normalisation, the loop with its logging,
# long: validation and checkpoints, then the meta, sharing the state its closures read.
def _train(cfg: TrainPriorConfig, verbose: bool, bm) -> tuple[MotionPrior, dict]:
    t_start = time.time()
    out = Path(cfg.out)
    ckpt_path = out / "checkpoints" / "last.pt"
    resume_from = None
    if cfg.resume is True and not ckpt_path.is_file():
        raise ConfigError(f"resume=true: no checkpoint {ckpt_path} to resume from (resume=auto starts fresh)")
    if cfg.resume in (True, "auto") and ckpt_path.is_file():
        resume_from = _load_training_checkpoint(ckpt_path, cfg)          # checked before the data work

    data, ds, bm = prior_data(cfg.data, ("train", "val"), cfg.body_model, cfg.fit_mlp, verbose=verbose, bm=bm)
    t_data = time.time() - t_start
    fps = data["train"].fps
    left, right = mirror_pairs()
    perm = torch.as_tensor(np.asarray(MIRROR), dtype=torch.long)
    lower = torch.as_tensor(markers_of_joints(bm, LOWER_BODY_JOINTS))
    sampler = WindowSampler(data["train"].frames, data["train"].lengths, cfg.window, "train")
    if verbose and sampler.skipped:
        print(f"note: {sampler.skipped} train sequences are shorter than window={cfg.window} and are not used", flush=True)
    val_batch = None
    if "val" in data and cfg.val_windows > 0:
        try:
            vs = WindowSampler(data["val"].frames, data["val"].lengths, cfg.window, "val")
            val_batch = make_batch(cfg, vs, cfg.val_windows, torch.Generator().manual_seed(cfg.seed * 31 + 5),
                                   perm, left, right, lower, fps, augment=False)
        except ConfigError as e:
            if verbose:
                print(f"note: no val loss ({e})", flush=True)

    torch.manual_seed(cfg.seed)
    reference = (~lower).nonzero().flatten().tolist() if cfg.kind == "infill" else None
    prior = MotionPrior(cfg.net, NUM_MARKERS, left, right, window=cfg.window, reference=reference)
    opt = torch.optim.Adam(prior.net.parameters(), lr=cfg.lr)
    start = 0
    if resume_from is not None:
        try:
            prior.load_state_dict(resume_from["model"])
            opt.load_state_dict(resume_from["optim"])
        except (KeyError, RuntimeError, ValueError) as e:
            raise DataError(ckpt_path, None, f"does not match this version's network ({str(e).splitlines()[0]}); "
                                             "use resume=false or another out=") from None
        torch.set_rng_state(resume_from["rng"])
        start = int(resume_from["step"])
        if verbose:
            print(f"resuming from {ckpt_path} at step {start}", flush=True)
    else:
        mean, std = normalisation(cfg, sampler, perm, left, right)
        prior.set_normalisation(mean, std)

    from torch.utils.tensorboard import SummaryWriter  # TensorBoard pulls in its own stack: only here

    writer = SummaryWriter(str(out / "tb"), purge_step=start + 1 if start else None)
    if verbose:
        print(f"train-motion-prior: kind={cfg.kind}, {count_parameters(prior)} parameters, channels "
              f"{cfg.net.channels}, window {cfg.window}, batch {cfg.batch_size}, steps {start}->{cfg.steps}; "
              f"{data['train'].num_frames} train frames ({len(data['train'].lengths)} sequences)", flush=True)

    def save_ckpt(step: int) -> None:
        _save_atomic({"format": CKPT_FORMAT, "step": step, "config": _plain(cfg), "model": prior.state_dict(),
                      "optim": opt.state_dict(), "rng": torch.get_rng_state()}, ckpt_path)

    def validate() -> dict[str, float]:
        if val_batch is None:
            return {}
        prior.eval()
        with torch.no_grad():
            parts = [losses(prior, cfg, Batch(val_batch.canon[s:s + cfg.batch_size],
                                              None if val_batch.observed is None else val_batch.observed[s:s + cfg.batch_size]))
                     for s in range(0, val_batch.canon.shape[0], cfg.batch_size)]
        prior.train()
        w = [min(cfg.batch_size, val_batch.canon.shape[0] - s) for s in range(0, val_batch.canon.shape[0], cfg.batch_size)]
        return {k: sum(p[k].item() * n for p, n in zip(parts, w)) / sum(w) for k in parts[0]}

    last_train, last_val = {}, {}
    t_loop, t_log, step = time.time(), time.time(), start
    prior.train()
    try:
        for step in range(start + 1, cfg.steps + 1):
            g = step_generator(cfg.seed, step)
            b = make_batch(cfg, sampler, cfg.batch_size, g, perm, left, right, lower, fps)
            for group in opt.param_groups:
                group["lr"] = lr_at(cfg, step)
            parts = losses(prior, cfg, b)
            opt.zero_grad(set_to_none=True)
            parts["loss"].backward()
            if cfg.grad_clip:
                torch.nn.utils.clip_grad_norm_(prior.net.parameters(), cfg.grad_clip)
            opt.step()
            if step % cfg.log_every == 0 or step == cfg.steps:
                sec = (time.time() - t_log) / (step - max(start, step - cfg.log_every) or 1)
                t_log = time.time()
                last_train = {k: v.item() for k, v in parts.items()}
                for k, v in last_train.items():
                    writer.add_scalar(f"train/{k}", v, step)
                writer.add_scalar("time/sec_per_step", sec, step)
                writer.add_scalar("train/lr", lr_at(cfg, step), step)
                if verbose:
                    detail = ", ".join(f"{k} {v:.4g}" for k, v in last_train.items() if k != "loss")
                    print(f"step {step}/{cfg.steps} loss {last_train['loss']:.4g} ({detail}) {sec:.2f} s/step",
                          flush=True)
            if val_batch is not None and (step % cfg.val_every == 0 or step == cfg.steps):
                last_val = validate()
                for k, v in last_val.items():
                    writer.add_scalar(f"val/{k}", v, step)
                if verbose:
                    print(f"  val loss {last_val['loss']:.4g}, err {last_val['err_cm']:.2f} cm", flush=True)
            if step % cfg.ckpt_every == 0 or step == cfg.steps:
                save_ckpt(step)
    except KeyboardInterrupt:
        writer.close()
        if ckpt_path.is_file():
            raise Interrupted(f"{ckpt_path} holds the last checkpoint; rerun the same command to resume") from None
        raise
    writer.close()
    if start >= cfg.steps and not last_val:
        last_val = validate()
    prior.eval()
    if prior.kind == "smooth" and val_batch is not None:
        last_val.update(smoothness_check(prior, val_batch.canon, cfg.seed))
        if verbose:
            print(f"  val E_smooth: clean {last_val['e_smooth_clean']:.4g}, with 2 cm noise "
                  f"{last_val['e_smooth_noise2cm']:.4g}", flush=True)
    t_total = time.time() - t_start
    meta = {"train_config": _plain(cfg), "steps": cfg.steps, "data_root": str(ds.root), "fps": fps,
            "train_frames": data["train"].num_frames, "final_train": last_train, "final_val": last_val,
            "masked_markers": lower.nonzero().flatten().tolist(), "seconds_data": t_data,
            "seconds_total": t_total, "seconds_per_step": (time.time() - t_loop) / max(1, cfg.steps - start)}
    return prior, meta


def train_and_save(cfg: TrainPriorConfig, verbose: bool = True) -> Path:
    """Train with TensorBoard logs in `cfg.out/tb`, save `cfg.out/prior.pt` and say where."""
    prior, meta = train(cfg, verbose=verbose)
    path = save_prior(Path(cfg.out) / "prior.pt", prior, meta)
    if verbose:
        print(f"saved {path} ({meta['seconds_total']:.0f} s, data {meta['seconds_data']:.0f} s)", flush=True)
    return path
