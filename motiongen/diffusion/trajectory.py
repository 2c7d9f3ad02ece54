"""Trajectory distillation on a student's own step grid: what a teacher's guided DDIM run
passes through at the student's timesteps, the distillation loss, and a student's own states.

A student that samples in n network evaluations visits the n timesteps `spaced_timesteps(T, n)`
(trailing spacing, so the ordinary DDIM scheduler with steps=n visits exactly them). The
teacher runs its own guided DDIM (typically 25 steps) from x_T; `teacher_trajectory` records
the state the teacher's deterministic DDIM path holds at each student timestep and the
teacher's final output x0*. The student is trained so that its x0-prediction at
(x_{t_i}, t_i) is x0* (`distill_loss`): one deterministic DDIM jump per student step then lands
on the teacher's trajectory, and the last one on its output. Classifier-free guidance is
folded in: the target is the guided teacher's output, the student runs with guidance 1.

Like the rest of `diffusion/`, nothing here owns a network: every function takes the model as
a callable `model(x_t (B, L, D), t (B,), cond, known_mask=None) -> (B, L, D)`.
"""

from __future__ import annotations

import torch
from torch import Tensor

from motiongen.diffusion.gaussian import GaussianDiffusion
from motiongen.diffusion.samplers import DDIMScheduler, _chain_start, _predictor, spaced_timesteps
from motiongen.rates import DEFAULT_STEPS


@torch.no_grad()
def teacher_trajectory(diffusion: GaussianDiffusion, model, shape: tuple[int, int, int], cond, student_steps: int,
                       known: Tensor | None = None, known_mask: Tensor | None = None,
                       replace_mask: Tensor | None = None, teacher_steps: int = DEFAULT_STEPS,
                       guidance_scale: float = 1.0, generator: torch.Generator | None = None,
                       device=None) -> tuple[Tensor, Tensor]:
    """(states (B, n, L, D), x0* (B, L, D)) of one guided teacher DDIM run of `teacher_steps`
    steps, exactly as `samplers.sample(..., sampler="ddim", eta=0)` draws it with the same
    generator (x0* is that call's result).

    states[:, i] is the teacher's state at the student's timestep t_i (n = student_steps,
    t_0 = T-1 is x_T): the teacher's own x where its grid visits t_i, else the point its DDIM
    step through t_i passes (the step from t > t_i to t' < t_i, stopped at t_i: x_{t_i} =
    √ᾱ_{t_i}·x̂0 + √(1-ᾱ_{t_i})·ε̂ of the teacher's prediction at t), so no network call is
    added and the teacher's output is unchanged. Known entries are written into every state,
    as the student's sampler writes them before each call.
    """
    device = device if device is not None else (known.device if known is not None else "cpu")
    dtype = known.dtype if known is not None else torch.float32
    scheduler = DDIMScheduler(diffusion, eta=0.0)
    scheduler.set_timesteps(teacher_steps)
    marks = spaced_timesteps(diffusion.num_timesteps, student_steps).tolist()     # (n,) descending
    predict = _predictor(model, cond, guidance_scale, True, known_mask, shape[0], device)
    x = _chain_start(diffusion, shape, known, known_mask, None, generator, device, dtype)
    states: list[Tensor | None] = [None] * len(marks)
    for t in scheduler.timesteps.tolist():
        if known is not None:
            x = torch.where(known_mask, known, x)
        out = predict(x, t)
        t_prev = scheduler.previous_timestep(t)
        for i, s in enumerate(marks):
            if t_prev < s <= t:
                states[i] = x if s == t else _ddim_point(scheduler, out, t, x, s, known, known_mask)
        x = scheduler.step(out, t, x)
    if known is not None:
        x = torch.where(known_mask if replace_mask is None else replace_mask, known, x)
    return torch.stack(states, 1), x


def _ddim_point(scheduler: DDIMScheduler, out: Tensor, t: int, x: Tensor, s: int, known, known_mask) -> Tensor:
    """x_s (B, L, D) on the deterministic DDIM step from x_t with the model output `out`."""
    x0, eps = scheduler._x0_eps(out, t, x)
    ab = float(scheduler.diffusion.alphas_cumprod[s])
    xs = ab**0.5 * x0 + (1 - ab) ** 0.5 * eps
    return xs if known is None else torch.where(known_mask, known, xs)


def student_timesteps(diffusion: GaussianDiffusion, steps: int) -> Tensor:
    """(n,) long, descending: the timesteps a `steps`-step student is trained at and samples at."""
    return spaced_timesteps(diffusion.num_timesteps, steps)


def distill_loss(diffusion: GaussianDiffusion, model, x_t: Tensor, t: Tensor, cond, target: Tensor,
                 known: Tensor | None = None, known_mask: Tensor | None = None,
                 loss_mask: Tensor | None = None, reduce: bool = True) -> Tensor:
    """() mean squared error of the student's x0-prediction at (x_t (B, L, D), t (B,)) against
    the teacher's output `target` (B, L, D), over `loss_mask` (B, L, D) bool (default: the entries
    that are not known). Known entries are written into x_t first, as sampling does. x̂0 is not
    clipped here: a clamped prediction would carry no gradient where the target is at the edge.
    reduce=False: (B,) each window's own mean over its loss entries."""
    if known is not None:
        x_t = torch.where(known_mask, known, x_t)
    out = model(x_t, t, cond, known_mask=known_mask)
    x0, _ = diffusion.predict_x0_eps(out, x_t, t, clip=None)
    err = (x0.float() - target.float()) ** 2                                          # (B, L, D)
    if loss_mask is None:
        loss_mask = ~known_mask if known_mask is not None else torch.ones_like(err, dtype=torch.bool)
    w = loss_mask.float()
    if not reduce:
        return (err * w).sum((1, 2)) / w.sum((1, 2)).clamp_min(1.0)
    return (err * w).sum() / w.sum().clamp_min(1.0)


@torch.no_grad()
def student_states(diffusion: GaussianDiffusion, model, x_T: Tensor, upto: Tensor, steps: int, cond,
                   known: Tensor | None = None, known_mask: Tensor | None = None) -> Tensor:
    """(B, L, D): for each window b, the state the `steps`-step student itself reaches at its
    timestep t_{upto[b]} from x_T (B, L, D), by its own deterministic DDIM steps with known
    entries written before each call (upto (B,) long in 0..n-1; 0 gives x_T back). These are
    the inputs the student really meets at sampling, where its earlier steps are not exact."""
    scheduler = DDIMScheduler(diffusion, eta=0.0)
    scheduler.set_timesteps(steps)
    x = x_T
    for k, t in enumerate(scheduler.timesteps.tolist()[:int(upto.max()) if len(upto) else 0]):
        if known is not None:
            x = torch.where(known_mask, known, x)
        tt = torch.full((x.shape[0],), int(t), device=x.device, dtype=torch.long)
        nxt = scheduler.step(model(x, tt, cond, known_mask=known_mask), t, x)
        x = torch.where((upto > k)[:, None, None], nxt, x)
    return x if known is None else torch.where(known_mask, known, x)
