"""Gaussian diffusion: forward process, posteriors, prediction targets and the training loss.

Owns no network. Functions take ``model(x_t, t, cond, known_mask=...)`` as a callable.
All per-timestep tables are float64 internally (closed forms stay exact) and are gathered
and cast to the data dtype on use.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from motiongen.diffusion.schedule import DiffusionConfig, make_betas
from motiongen.errors import ConfigError

PREDICTIONS = ("eps", "x0", "v")
LOSSES = ("huber", "mse")


def _gather(table: Tensor, t: Tensor, like: Tensor) -> Tensor:
    """table (T,) at t (B,) -> (B, 1, ..., 1) broadcastable to ``like``, in like's dtype."""
    out = table.to(t.device)[t].to(like.dtype)
    return out.view(-1, *([1] * (like.dim() - 1)))


class GaussianDiffusion:
    def __init__(self, cfg: DiffusionConfig | None = None):
        cfg = cfg if cfg is not None else DiffusionConfig()
        if cfg.prediction not in PREDICTIONS:
            raise ConfigError(f"diffusion.prediction: expected one of {PREDICTIONS}, got {cfg.prediction!r}")
        if cfg.loss not in LOSSES:
            raise ConfigError(f"diffusion.loss: expected one of {LOSSES}, got {cfg.loss!r}")
        for key in ("velocity_weight", "acceleration_weight"):
            if not getattr(cfg, key) >= 0:
                raise ConfigError(f"diffusion.{key}: expected a weight >= 0, got {getattr(cfg, key)!r}")
        self.cfg = cfg
        self.num_timesteps = cfg.steps
        self.betas = make_betas(cfg)  # (T,) float64
        self.alphas = 1 - self.betas
        self.alphas_cumprod = torch.cumprod(self.alphas, 0)  # ᾱ_t
        self.alphas_cumprod_prev = torch.cat([torch.ones(1, dtype=torch.float64), self.alphas_cumprod[:-1]])
        self.sqrt_alphas_cumprod = self.alphas_cumprod.sqrt()
        self.sqrt_one_minus_alphas_cumprod = (1 - self.alphas_cumprod).sqrt()
        # q(x_{t-1} | x_t, x0) for the full T-step chain (β̃_t and the mean coefficients).
        self.posterior_variance = self.betas * (1 - self.alphas_cumprod_prev) / (1 - self.alphas_cumprod)
        self.posterior_mean_coef1 = self.betas * self.alphas_cumprod_prev.sqrt() / (1 - self.alphas_cumprod)
        self.posterior_mean_coef2 = (1 - self.alphas_cumprod_prev) * self.alphas.sqrt() / (1 - self.alphas_cumprod)

    @property
    def terminal_alpha_bar(self) -> float:
        return float(self.alphas_cumprod[-1])

    # -- forward process ------------------------------------------------------------------
    def q_sample(self, x0: Tensor, t: Tensor, noise: Tensor) -> Tensor:
        """x_t = √ᾱ_t x0 + √(1-ᾱ_t) ε."""
        return _gather(self.sqrt_alphas_cumprod, t, x0) * x0 + _gather(self.sqrt_one_minus_alphas_cumprod, t, x0) * noise

    def q_posterior_mean_variance(self, x0: Tensor, x_t: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
        """Mean and variance of q(x_{t-1} | x_t, x0) (DDPM eq. 6-7); variance (B, 1, ...)."""
        mean = _gather(self.posterior_mean_coef1, t, x_t) * x0 + _gather(self.posterior_mean_coef2, t, x_t) * x_t
        return mean, _gather(self.posterior_variance, t, x_t)

    # -- prediction targets -----------------------------------------------------------------
    def target(self, x0: Tensor, noise: Tensor, t: Tensor) -> Tensor:
        p = self.cfg.prediction
        if p == "eps":
            return noise
        if p == "x0":
            return x0
        return self.v_from_x0_eps(x0, noise, t)

    def v_from_x0_eps(self, x0: Tensor, eps: Tensor, t: Tensor) -> Tensor:
        """v = √ᾱ ε - √(1-ᾱ) x0 (Salimans & Ho 2022)."""
        return _gather(self.sqrt_alphas_cumprod, t, x0) * eps - _gather(self.sqrt_one_minus_alphas_cumprod, t, x0) * x0

    def x0_from_eps(self, x_t: Tensor, eps: Tensor, t: Tensor) -> Tensor:
        return (x_t - _gather(self.sqrt_one_minus_alphas_cumprod, t, x_t) * eps) / _gather(self.sqrt_alphas_cumprod, t, x_t)

    def eps_from_x0(self, x_t: Tensor, x0: Tensor, t: Tensor) -> Tensor:
        return (x_t - _gather(self.sqrt_alphas_cumprod, t, x_t) * x0) / _gather(self.sqrt_one_minus_alphas_cumprod, t, x_t)

    def x0_from_v(self, x_t: Tensor, v: Tensor, t: Tensor) -> Tensor:
        return _gather(self.sqrt_alphas_cumprod, t, x_t) * x_t - _gather(self.sqrt_one_minus_alphas_cumprod, t, x_t) * v

    def eps_from_v(self, x_t: Tensor, v: Tensor, t: Tensor) -> Tensor:
        return _gather(self.sqrt_one_minus_alphas_cumprod, t, x_t) * x_t + _gather(self.sqrt_alphas_cumprod, t, x_t) * v

    def predict_x0_eps(self, model_output: Tensor, x_t: Tensor, t: Tensor,
                       clip: float | None = None) -> tuple[Tensor, Tensor]:
        """(x̂0, ε̂) from the network output, whatever the configured target.

        With ``clip`` the x0 estimate is clamped and ε̂ recomputed from it so the two stay
        consistent (improved-diffusion); this keeps the first steps of an ε-model stable where
        1/√ᾱ is huge.
        """
        p = self.cfg.prediction
        if p == "eps":
            eps = model_output
            x0 = self.x0_from_eps(x_t, eps, t)
        elif p == "x0":
            x0 = model_output
            eps = self.eps_from_x0(x_t, x0, t)
        else:
            x0 = self.x0_from_v(x_t, model_output, t)
            eps = self.eps_from_v(x_t, model_output, t)
        if clip is not None:
            x0 = x0.clamp(-clip, clip)
            eps = self.eps_from_x0(x_t, x0, t)
        return x0, eps

    # -- training ------------------------------------------------------------------------------
    def sample_timesteps(self, batch: int, generator: torch.Generator | None = None,
                         device: torch.device | str = "cpu") -> Tensor:
        gen_device = generator.device if generator is not None else "cpu"
        return torch.randint(0, self.num_timesteps, (batch,), generator=generator, device=gen_device).to(device)

    def training_losses(self, model, x0: Tensor, t: Tensor, cond, known: Tensor | None = None,
                        known_mask: Tensor | None = None, noise: Tensor | None = None,
                        generator: torch.Generator | None = None,
                        channel_weights: Tensor | None = None, loss_mask: Tensor | None = None,
                        window_terms=None, entry_weights: Tensor | None = None) -> dict[str, Tensor]:
        """Loss on the configured target over the free (not known) entries, or over `loss_mask`
        (B, L, D) bool when given (e.g. free entries plus goal entries the model must predict).

        channel_weights (D,): optional per-channel weights of the loss (a weighted mean over the
        free entries), e.g. to make the root trajectory count as much as the pose.
        entry_weights (B, L, D): optional weights of single entries in that mean (e.g. the wrist
        that a window's hand goal names, `loading.build.hand_goal_weights`).

        x0 (B, L, D) clean; t (B,) long; known_mask (B, L, D) bool marks entries the caller
        pins. Those entries of x_t hold the clean values (``known``, default x0) — exactly what
        the samplers write there — so training and sampling show the model the same input.
        window_terms: optional callable (window, x0, free, t) -> {name: (weight, term)}, losses on
        the window as sampling assembles it (e.g. `training.body_losses.BodyLosses`).
        Returns ``loss`` (to backprop) plus named terms for logging.
        """
        if noise is None:
            gen_device = generator.device if generator is not None else x0.device
            noise = torch.randn(x0.shape, generator=generator, device=gen_device, dtype=x0.dtype).to(x0.device)
        x_t = self.q_sample(x0, t, noise)
        if known_mask is not None:
            x_t = torch.where(known_mask, x0 if known is None else known, x_t)
        out = model(x_t, t, cond, known_mask=known_mask)  # (B, L, D)
        target = self.target(x0, noise, t)
        per_entry = self._per_entry(out, target)
        sq = (out.detach() - target) ** 2
        if loss_mask is not None:
            free = loss_mask.to(out.dtype)                                                    # (B, L, D)
        else:
            free = torch.ones_like(out) if known_mask is None else (~known_mask).to(out.dtype)
        n = free.sum().clamp(min=1)
        mse, free_fraction = (sq * free).sum() / n, free.mean()
        if channel_weights is None and entry_weights is None:
            main = (per_entry * free).sum() / n
        else:
            w = free if channel_weights is None else free * channel_weights.to(out.dtype)        # (B, L, D)
            w = w if entry_weights is None else w * entry_weights.to(out.dtype)
            main = (per_entry * w).sum() / w.sum().clamp(min=1e-8)
        name = f"{self.cfg.loss}_{self.cfg.prediction}"
        terms = {"loss": main, name: main.detach(), f"mse_{self.cfg.prediction}": mse,
                 "free_fraction": free_fraction}
        diffs = [(order, key, weight) for order, key, weight in ((1, "velocity", self.cfg.velocity_weight),
                                                                 (2, "acceleration", self.cfg.acceleration_weight))
                 if weight > 0]
        if diffs or window_terms is not None:
            # the window as sampling assembles it: x̂0 on free entries, the pinned values (x_t holds them) elsewhere
            window = torch.where(free > 0, self.predict_x0_eps(out, x_t, t)[0], x_t)         # (B, L, D)
            weighted = [(key, weight, self._difference_loss(window, x0, free, channel_weights, order))
                        for order, key, weight in diffs]
            if window_terms is not None:
                weighted += [(key, weight, term) for key, (weight, term) in window_terms(window, x0, free, t).items()]
            for key, weight, term in weighted:
                terms["loss"] = terms["loss"] + weight * term
                terms[key] = term.detach()
        return terms

    def _per_entry(self, out: Tensor, target: Tensor) -> Tensor:
        """The configured loss (huber or mse) per entry, unreduced."""
        if self.cfg.loss == "huber":
            return F.huber_loss(out, target, reduction="none", delta=self.cfg.huber_delta)
        return F.mse_loss(out, target, reduction="none")

    def _difference_loss(self, window: Tensor, x0: Tensor, free: Tensor, channel_weights: Tensor | None,
                         order: int) -> Tensor:
        """Loss between `order`-th frame differences (B, L-order, D) of the assembled window
        (B, L, D) and of x0, over every pair (order 1) or triple (order 2) with at least one
        free frame. Those reaching from the last transition frame into the free ones are the
        seam between episodes: measured, the models that skipped them jumped there by ~10x the
        data's acceleration (docs/quality.md)."""
        d_hat, d = torch.diff(window, n=order, dim=1), torch.diff(x0, n=order, dim=1)          # (B, L-order, D)
        per = self._per_entry(d_hat, d)
        w = free.unfold(1, order + 1, 1).amax(-1)                                              # (B, L-order, D)
        if channel_weights is not None:
            w = w * channel_weights.to(window.dtype)
        return (per * w).sum() / w.sum().clamp(min=1e-8)
