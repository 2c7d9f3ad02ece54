"""β schedules and the diffusion configuration.

Timesteps are 0-indexed: t = 0 .. T-1, ᾱ_t = Π_{s<=t} (1 - β_s). ``ᾱ_{-1}`` = 1 is the clean
data. The default schedule (cosine) ends at ᾱ_{T-1} ≈ 2e-7, i.e. pure noise, so sampling
from N(0, I) is the right start; for schedules that do not (the paper's linear 1e-4 → 0.02
at T = 100 ends at ᾱ ≈ 0.36) samplers start from the actual marginal, see docs/diffusion.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from motiongen.errors import ConfigError


@dataclass
class DiffusionConfig:
    steps: int = 100                 # training timesteps T (reference: 100)
    schedule: str = "cosine"         # "cosine" (Nichol & Dhariwal) | "linear" (paper)
    beta_start: float = 1e-4         # linear only
    beta_end: float = 0.02           # linear only
    cosine_s: float = 0.008          # cosine offset
    zero_terminal_snr: bool = False  # Lin et al. 2024 rescaling: ᾱ_{T-1} = 0 exactly (needs v or x0)
    # x0 by default: with eps, x̂0 = (x_t - √(1-ᾱ)ε̂)/√ᾱ amplifies errors ~2000x near ᾱ_T ≈ 0, and
    # the demo model's DDIM-25 windows fell apart (1.1 m joint error, 1.2 m thighs) where x0
    # prediction gives consistent bones and DDIM-25 == DDPM-100 (docs/diffusion.md).
    prediction: str = "x0"           # "x0" | "eps" (paper) | "v"
    loss: str = "huber"              # "huber" (paper) | "mse"
    huber_delta: float = 1.0
    # Weight of a loss on the frame-to-frame differences of the predicted clean window against
    # the data's (MDM's velocity loss), added to the main loss; 0 = off (the public code).
    # Penalises the frame-level jitter a small model's windows carry (docs/quality.md).
    velocity_weight: float = 0.0
    # The same on second differences (acceleration), every triple with a free frame. Per-frame
    # independent errors weigh 6x their square here and smooth ones ~0: it targets the 3-8 Hz
    # excess of the network's windows (docs/quality.md); 0 = off.
    acceleration_weight: float = 0.0
    clip_x0: float | None = 1.0      # clamp predicted x0 to ±clip while sampling (data is in [-1, 1]); None = off


def linear_betas(steps: int, beta_start: float, beta_end: float) -> Tensor:
    return torch.linspace(beta_start, beta_end, steps, dtype=torch.float64)


def cosine_betas(steps: int, s: float = 0.008, max_beta: float = 0.999) -> Tensor:
    """Nichol & Dhariwal 2021: ᾱ(t) = cos²(((t/T + s)/(1 + s))·π/2), β capped at ``max_beta``."""
    t = torch.arange(steps + 1, dtype=torch.float64) / steps
    f = torch.cos((t + s) / (1 + s) * math.pi / 2) ** 2  # (T+1,)
    betas = 1 - f[1:] / f[:-1]
    return betas.clamp(max=max_beta)


def rescale_zero_terminal_snr(betas: Tensor) -> Tensor:
    """Lin et al. 2024 ("Common diffusion noise schedules and sample steps are flawed"), Alg. 1.

    Shift and scale √ᾱ so that its last value is 0 and its first is unchanged.
    """
    sqrt_ab = torch.cumprod(1 - betas, 0).sqrt()
    first, last = sqrt_ab[0].clone(), sqrt_ab[-1].clone()
    sqrt_ab = (sqrt_ab - last) * first / (first - last)
    ab = sqrt_ab**2
    alphas = torch.cat([ab[:1], ab[1:] / ab[:-1]])
    return 1 - alphas


def make_betas(cfg: DiffusionConfig) -> Tensor:
    """(T,) float64 β for ``cfg``; validates the combination of options."""
    if cfg.steps < 1:
        raise ConfigError(f"diffusion.steps: expected >= 1, got {cfg.steps}")
    if cfg.schedule == "linear":
        betas = linear_betas(cfg.steps, cfg.beta_start, cfg.beta_end)
    elif cfg.schedule == "cosine":
        betas = cosine_betas(cfg.steps, cfg.cosine_s)
    else:
        raise ConfigError(f"diffusion.schedule: expected 'linear' or 'cosine', got {cfg.schedule!r}")
    if cfg.zero_terminal_snr:
        if cfg.prediction == "eps":
            # At ᾱ = 0, x_T is pure noise: predicting ε carries no information about x0
            # (x0 = (x_t - √(1-ᾱ)ε)/√ᾱ divides by zero). Lin et al. use v-prediction.
            raise ConfigError("diffusion.zero_terminal_snr needs prediction 'v' or 'x0', not 'eps'")
        betas = rescale_zero_terminal_snr(betas)
    return betas
