"""DDPM (ancestral) and DDIM samplers with inpainting and classifier-free guidance.

Both share the diffusers-style interface ``set_timesteps(n)`` / ``step(model_output, t, x_t,
generator) -> x_prev`` so they swap freely. ``sample()`` is the loop around them.

Timestep spacing is "trailing" (Lin et al. 2024, Table 2): n steps visit
t_i = round(T - i·T/n) - 1, i = 0..n-1, so the first step is always t = T-1 (where the
schedule is pure noise) and the last lands near t = 0 (t = T/n - 1).
"""

from __future__ import annotations

import torch
from torch import Tensor

from motiongen.diffusion.gaussian import GaussianDiffusion
from motiongen.errors import ConfigError
from motiongen.rates import DEFAULT_STEPS

_FROM_CONFIG = object()


def spaced_timesteps(num_train: int, n: int) -> Tensor:
    """(n,) long, descending, trailing spacing."""
    if not 1 <= n <= num_train:
        raise ConfigError(f"sampling steps: expected 1..{num_train} (the training steps), got {n}")
    i = torch.arange(n, dtype=torch.float64)
    return (torch.round(num_train - i * num_train / n) - 1).long()


def _randn(shape, generator: torch.Generator | None, device, dtype) -> Tensor:
    # Draw on the generator's device so a CPU generator gives the same numbers everywhere.
    gen_device = generator.device if generator is not None else device
    return torch.randn(shape, generator=generator, device=gen_device, dtype=dtype).to(device)


class Scheduler:
    """Shared bookkeeping; subclasses implement ``step``."""

    def __init__(self, diffusion: GaussianDiffusion, clip_x0=_FROM_CONFIG):
        self.diffusion = diffusion
        self.clip_x0 = diffusion.cfg.clip_x0 if clip_x0 is _FROM_CONFIG else clip_x0
        self.set_timesteps(diffusion.num_timesteps)

    def set_timesteps(self, n: int) -> None:
        self.timesteps = spaced_timesteps(self.diffusion.num_timesteps, n)  # (n,) descending
        prev = torch.cat([self.timesteps[1:], torch.tensor([-1])])
        self._prev = {int(a): int(b) for a, b in zip(self.timesteps, prev)}

    def previous_timestep(self, t: int) -> int:
        return self._prev[int(t)]

    def _alpha_bars(self, t: int) -> tuple[float, float]:
        ac = self.diffusion.alphas_cumprod
        t_prev = self.previous_timestep(t)
        return float(ac[int(t)]), (float(ac[t_prev]) if t_prev >= 0 else 1.0)

    def _x0_eps(self, model_output: Tensor, t: int, x_t: Tensor) -> tuple[Tensor, Tensor]:
        tt = torch.full((x_t.shape[0],), int(t), device=x_t.device, dtype=torch.long)
        return self.diffusion.predict_x0_eps(model_output, x_t, tt, clip=self.clip_x0)

    def step(self, model_output: Tensor, t: int, x_t: Tensor,
             generator: torch.Generator | None = None) -> Tensor:
        raise NotImplementedError


class DDPMScheduler(Scheduler):
    """Ancestral sampling from q(x_prev | x_t, x̂0) of the (re-spaced) chain.

    With n < T steps the chain over the visited timesteps has β'_t = 1 - ᾱ_t/ᾱ_prev
    (improved-diffusion's respacing); with n = T this is exactly DDPM.
    """

    def step(self, model_output, t, x_t, generator=None):
        ab_t, ab_prev = self._alpha_bars(t)
        x0, _ = self._x0_eps(model_output, t, x_t)
        beta = 1 - ab_t / ab_prev
        coef1 = ab_prev**0.5 * beta / (1 - ab_t)
        coef2 = (1 - beta) ** 0.5 * (1 - ab_prev) / (1 - ab_t)
        mean = coef1 * x0 + coef2 * x_t
        if self.previous_timestep(t) < 0:
            return mean  # last step: no noise (the mean is x̂0 here since ᾱ_prev = 1)
        var = beta * (1 - ab_prev) / (1 - ab_t)
        return mean + var**0.5 * _randn(x_t.shape, generator, x_t.device, x_t.dtype)


class DDIMScheduler(Scheduler):
    """Song et al. 2021, eq. 12; η = 0 deterministic, η = 1 equals DDPM's posterior variance."""

    def __init__(self, diffusion: GaussianDiffusion, eta: float = 0.0, clip_x0=_FROM_CONFIG):
        super().__init__(diffusion, clip_x0)
        self.eta = eta

    def step(self, model_output, t, x_t, generator=None):
        ab_t, ab_prev = self._alpha_bars(t)
        x0, eps = self._x0_eps(model_output, t, x_t)
        sigma2 = self.eta**2 * (1 - ab_prev) / (1 - ab_t) * (1 - ab_t / ab_prev)
        x_prev = ab_prev**0.5 * x0 + max(1 - ab_prev - sigma2, 0.0) ** 0.5 * eps
        if sigma2 > 0 and self.previous_timestep(t) >= 0:
            x_prev = x_prev + sigma2**0.5 * _randn(x_t.shape, generator, x_t.device, x_t.dtype)
        return x_prev


def make_scheduler(diffusion: GaussianDiffusion, sampler: str, eta: float = 0.0,
                   clip_x0=_FROM_CONFIG) -> Scheduler:
    if sampler == "ddpm":
        return DDPMScheduler(diffusion, clip_x0)
    if sampler == "ddim":
        return DDIMScheduler(diffusion, eta, clip_x0)
    raise ConfigError(f"sampler: expected 'ddpm' or 'ddim', got {sampler!r}")


def _model_device(model) -> torch.device:
    try:
        return next(model.parameters()).device
    except (AttributeError, StopIteration):
        return torch.device("cpu")


@torch.no_grad()
def sample(diffusion: GaussianDiffusion, model, shape: tuple[int, int, int], cond,
           known: Tensor | None = None, known_mask: Tensor | None = None, sampler: str = "ddim",
           steps: int = DEFAULT_STEPS, eta: float = 0.0, guidance_scale: float = 1.0,
           generator: torch.Generator | None = None, progress: bool = False,
           x_prior: Tensor | None = None, cfg_batched: bool = True, clip_x0=_FROM_CONFIG,
           device: torch.device | str | None = None, replace_mask: Tensor | None = None) -> Tensor:
    """Draw x0 of ``shape`` (B, L, D).

    known / known_mask (B, L, D): entries given as clean values; they are written into x before
    every model call (the same input the model saw in training). replace_mask (B, L, D), a
    subset of known_mask (default: all of it), says which of them are also written into the
    result; elsewhere the result is the model's own final prediction (goals the model was
    trained to predict, `masks.replace_mask`). guidance_scale s: out = out_u + s·(out_c - out_u), unconditional = both
    conditions dropped (``cond.drop_all()``); s = 1 runs the conditional pass only.
    The chain starts from the marginal the schedule actually ends at:
    x_T = √ᾱ_T·x_prior + √(1-ᾱ_T)·ε, x_prior = 0 by default (known values where pinned);
    with the default cosine schedule ᾱ_T ≈ 2e-7 and this is N(0, I).
    The caller puts the model in eval mode.
    """
    if device is None:
        device = known.device if known is not None else _model_device(model)
    dtype = known.dtype if known is not None else torch.float32
    if known_mask is not None and known is None:
        raise ValueError("sample: known_mask given without known values")
    if known is not None and known_mask is None:
        raise ValueError("sample: known values given without known_mask")
    scheduler = make_scheduler(diffusion, sampler, eta, clip_x0)
    scheduler.set_timesteps(steps)
    predict = _predictor(model, cond, guidance_scale, cfg_batched, known_mask, shape[0], device)
    x = _chain_start(diffusion, shape, known, known_mask, x_prior, generator, device, dtype)
    timesteps = scheduler.timesteps.tolist()
    if progress:
        timesteps = _with_progress(timesteps, f"{sampler} {steps} steps")
    for t in timesteps:
        if known is not None:
            x = torch.where(known_mask, known, x)
        x = scheduler.step(predict(x, t), t, x, generator)
    if known is not None:
        x = torch.where(known_mask if replace_mask is None else replace_mask, known, x)
    return x


def _predictor(model, cond, guidance_scale: float, cfg_batched: bool, known_mask: Tensor | None, B: int, device):
    """predict(x (B, L, D), t) -> the model's output for x at timestep t, with classifier-free
    guidance unless guidance_scale is 1 (the two passes in one batch when `cfg_batched` and the
    encoded condition can `concat`). Encoders run here, once per call, not per step."""
    encode = getattr(model, "encode_condition", None)
    enc_c = encode(cond) if encode is not None else cond
    guided = guidance_scale != 1.0
    if guided:
        if cond is None or not hasattr(cond, "drop_all"):
            raise ValueError("classifier-free guidance needs a condition with drop_all()")
        uncond = cond.drop_all()
        enc_u = encode(uncond) if encode is not None else uncond
        batched = cfg_batched and hasattr(enc_c, "concat")
        if batched:
            enc_cu = enc_c.concat(enc_u)
            mask2 = None if known_mask is None else torch.cat([known_mask, known_mask], 0)

    def predict(x: Tensor, t: int) -> Tensor:
        tt = torch.full((B,), int(t), device=device, dtype=torch.long)
        if not guided:
            return model(x, tt, enc_c, known_mask=known_mask)
        if batched:
            out = model(torch.cat([x, x], 0), torch.cat([tt, tt], 0), enc_cu, known_mask=mask2)
            out_c, out_u = out.chunk(2, 0)
        else:
            out_c = model(x, tt, enc_c, known_mask=known_mask)
            out_u = model(x, tt, enc_u, known_mask=known_mask)
        return out_u + guidance_scale * (out_c - out_u)

    return predict


def _chain_start(diffusion: GaussianDiffusion, shape: tuple[int, int, int], known: Tensor | None,
                 known_mask: Tensor | None, x_prior: Tensor | None, generator: torch.Generator | None,
                 device, dtype) -> Tensor:
    """x_T (B, L, D) = √ᾱ_T·x_prior + √(1-ᾱ_T)·ε, known values pinned in x_prior."""
    ab_T = float(diffusion.alphas_cumprod[-1])
    prior = torch.zeros(shape, device=device, dtype=dtype) if x_prior is None else x_prior.to(device, dtype)
    if known is not None:
        prior = torch.where(known_mask, known, prior)
    return ab_T**0.5 * prior + (1 - ab_T) ** 0.5 * _randn(shape, generator, device, dtype)


def _with_progress(timesteps: list[int], desc: str):
    """The timesteps behind a progress bar, when tqdm is installed."""
    try:
        from tqdm import tqdm  # optional here: diffusion/ needs only torch; without tqdm, no bar

        return tqdm(timesteps, desc=desc)
    except ImportError:
        return timesteps
