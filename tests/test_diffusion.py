"""Diffusion: schedules vs closed forms, conversions, loss masking, samplers (dummy models)."""

from __future__ import annotations

import math

import pytest
import torch

from motiongen.diffusion import (DDIMScheduler, DDPMScheduler, DiffusionConfig, GaussianDiffusion, MaskConfig,
                                 known_mask, sample, sample_known_mask, spaced_timesteps)
from motiongen.errors import ConfigError

D64 = torch.float64


def _diff(**kw) -> GaussianDiffusion:
    return GaussianDiffusion(DiffusionConfig(**kw))


class ZeroEps:
    """Dummy denoiser predicting a constant zero target."""

    def __call__(self, x, t, cond, known_mask=None):
        return torch.zeros_like(x)


class LinearModel:
    """out = a·x_t + b·t (a deterministic function of its inputs, for golden values)."""

    def __init__(self, a=0.5, b=0.01):
        self.a, self.b = a, b

    def __call__(self, x, t, cond, known_mask=None):
        return self.a * x + self.b * t.to(x.dtype).view(-1, 1, 1)


class CondModel:
    """Output depends on whether conditions are dropped: lets CFG be checked exactly."""

    def __call__(self, x, t, cond, known_mask=None):
        drop = cond.drop_scene.to(x.dtype).view(-1, 1, 1) if cond.drop_scene is not None else 0.0
        return 0.3 * x + 0.2 * (1 - drop) - 0.1 * drop


# -- schedules -----------------------------------------------------------------------------
def test_default_schedule_ends_at_pure_noise():
    d = GaussianDiffusion()
    assert d.cfg.schedule == "cosine" and d.num_timesteps == 100
    assert d.terminal_alpha_bar < 1e-4
    # The paper's linear schedule does not (the documented flaw).
    assert _diff(schedule="linear").terminal_alpha_bar == pytest.approx(0.3636, abs=1e-3)


def test_linear_schedule_closed_form():
    d = _diff(schedule="linear", steps=10, beta_start=1e-3, beta_end=0.1)
    betas = torch.tensor([1e-3 + i * (0.1 - 1e-3) / 9 for i in range(10)], dtype=D64)
    torch.testing.assert_close(d.betas, betas)
    ab = torch.tensor([math.prod(1 - float(b) for b in betas[: i + 1]) for i in range(10)], dtype=D64)
    torch.testing.assert_close(d.alphas_cumprod, ab)


def test_cosine_schedule_closed_form():
    T, s = 50, 0.008
    d = _diff(steps=T)
    f = lambda t: math.cos((t / T + s) / (1 + s) * math.pi / 2) ** 2  # noqa: E731
    expect = torch.tensor([f(t + 1) / f(0) for t in range(T - 1)], dtype=D64)
    torch.testing.assert_close(d.alphas_cumprod[:-1], expect)  # last β is capped at 0.999


def test_zero_terminal_snr():
    d = _diff(schedule="linear", zero_terminal_snr=True, prediction="v")
    assert d.terminal_alpha_bar == pytest.approx(0.0, abs=1e-12)
    ref = _diff(schedule="linear")
    assert float(d.alphas_cumprod[0]) == pytest.approx(float(ref.alphas_cumprod[0]))
    with pytest.raises(ConfigError):
        _diff(zero_terminal_snr=True, prediction="eps")


def test_posterior_closed_form():
    d = _diff(schedule="linear", steps=20)
    t = torch.tensor([0, 5, 19])
    x0, xt = torch.randn(3, 4, 6, dtype=D64), torch.randn(3, 4, 6, dtype=D64)
    mean, var = d.q_posterior_mean_variance(x0, xt, t)
    for i, ti in enumerate(t.tolist()):
        ab = float(d.alphas_cumprod[ti])
        ab_prev = float(d.alphas_cumprod[ti - 1]) if ti > 0 else 1.0
        beta = float(d.betas[ti])
        m = math.sqrt(ab_prev) * beta / (1 - ab) * x0[i] + math.sqrt(1 - beta) * (1 - ab_prev) / (1 - ab) * xt[i]
        torch.testing.assert_close(mean[i], m)
        assert float(var[i]) == pytest.approx(beta * (1 - ab_prev) / (1 - ab))


def test_q_sample_statistics():
    d = GaussianDiffusion()
    g = torch.Generator().manual_seed(0)
    t = torch.full((200_000,), 30)
    x0 = torch.full((200_000, 1, 1), 0.7)
    xt = d.q_sample(x0, t, torch.randn(x0.shape, generator=g))
    ab = float(d.alphas_cumprod[30])
    assert float(xt.mean()) == pytest.approx(math.sqrt(ab) * 0.7, abs=5e-3)
    assert float(xt.var()) == pytest.approx(1 - ab, rel=2e-2)


@pytest.mark.parametrize("prediction", ["eps", "x0", "v"])
def test_prediction_conversions_round_trip(prediction):
    d = _diff(prediction=prediction)
    g = torch.Generator().manual_seed(1)
    x0, eps = torch.randn(4, 3, 6, generator=g, dtype=D64), torch.randn(4, 3, 6, generator=g, dtype=D64)
    t = torch.tensor([0, 10, 50, 90])
    xt = d.q_sample(x0, t, eps)
    x0_hat, eps_hat = d.predict_x0_eps(d.target(x0, eps, t), xt, t)
    torch.testing.assert_close(x0_hat, x0)
    torch.testing.assert_close(eps_hat, eps)
    v = d.v_from_x0_eps(x0, eps, t)
    torch.testing.assert_close(d.x0_from_v(xt, v, t), x0)
    torch.testing.assert_close(d.eps_from_v(xt, v, t), eps)


# -- training loss ------------------------------------------------------------------------
def test_training_loss_shows_clean_known_entries_and_ignores_them():
    d = _diff(prediction="eps")
    seen = {}

    def model(x, t, cond, known_mask=None):
        seen["x"] = x.clone()
        out = torch.zeros_like(x)
        return torch.where(known_mask, torch.full_like(x, 1e3), out)  # huge error on pinned entries only

    g = torch.Generator().manual_seed(0)
    x0 = torch.randn(3, 8, 6)
    mask = known_mask(3, 8, 2, transition=2, goal_xz=True)
    noise = torch.randn(x0.shape, generator=g)
    t = torch.tensor([99, 50, 3])
    out = d.training_losses(model, x0, t, None, known_mask=mask, noise=noise)
    assert torch.equal(seen["x"][mask], x0[mask])  # exactly the clean values, as sampling writes them
    expect = torch.nn.functional.huber_loss(torch.zeros_like(noise), noise, reduction="none")[~mask].mean()
    torch.testing.assert_close(out["loss"], expect)
    assert set(out) >= {"loss", "huber_eps", "mse_eps"}
    mse = _diff(loss="mse", prediction="eps").training_losses(model, x0, t, None, known_mask=mask, noise=noise)["loss"]
    torch.testing.assert_close(mse, (noise[~mask] ** 2).mean())


def test_velocity_loss_known_answers():
    """x0 prediction: a constant offset has no velocity error; a ±e zig-zag has |Δ| = 2e on every
    free frame pair; a pinned frame counts with its pinned value (the seam), whatever the model
    predicted there, and pairs of two pinned frames are left out."""
    x0 = torch.randn(2, 6, 4, dtype=D64)
    t = torch.tensor([10, 60])
    noise = torch.zeros_like(x0)
    zig = 0.1 * (-1.0) ** torch.arange(6, dtype=D64)[None, :, None]          # (1, L, 1)

    def model_for(offset):
        return lambda x, t, cond, known_mask=None: x0 + offset

    d = _diff(loss="mse", velocity_weight=2.0)
    flat = d.training_losses(model_for(0.3), x0, t, None, noise=noise)
    assert float(flat["velocity"]) == pytest.approx(0.0, abs=1e-12)
    torch.testing.assert_close(flat["loss"], torch.tensor(0.09, dtype=D64))     # main loss only
    z = d.training_losses(model_for(zig), x0, t, None, noise=noise)
    assert float(z["velocity"]) == pytest.approx(0.04)                          # (2 · 0.1)^2
    torch.testing.assert_close(z["loss"], torch.tensor(0.01 + 2.0 * 0.04, dtype=D64))
    mask = torch.zeros(2, 6, 4, dtype=torch.bool)
    mask[:, :2] = True                                                          # two transition frames
    wild = model_for(torch.where(mask, 5.0, 0.0).to(D64))                       # wrong only where pinned
    assert float(d.training_losses(wild, x0, t, None, known_mask=mask, noise=noise)["velocity"]) == 0.0
    # right everywhere but offset by c on the free frames: only the seam pair (frame 1 -> 2)
    # differs, by c, in each of the 4 channels; 3 free pairs + the seam = 4 pairs counted
    shifted = model_for(torch.where(mask, 0.0, 0.3).to(D64))
    v = d.training_losses(shifted, x0, t, None, known_mask=mask, noise=noise)["velocity"]
    assert float(v) == pytest.approx(0.09 / 4)
    assert "velocity" not in _diff().training_losses(model_for(zig), x0, t, None, noise=noise)


def test_acceleration_loss_known_answers():
    """Second differences: a linear drift has a velocity error but no acceleration error; a ±e
    zig-zag has |Δ²| = 4e; an offset c on the free frames after two pinned ones shows at the two
    triples that straddle the seam (+c, -c) and nowhere else, all four triples counted."""
    x0 = torch.randn(2, 6, 4, dtype=D64)
    t = torch.tensor([10, 60])
    noise = torch.zeros_like(x0)
    k = torch.arange(6, dtype=D64)[None, :, None]                                # (1, L, 1)

    def model_for(offset):
        return lambda x, t, cond, known_mask=None: x0 + offset

    d = _diff(loss="mse", velocity_weight=1.0, acceleration_weight=3.0)
    ramp = d.training_losses(model_for(0.05 * k), x0, t, None, noise=noise)
    assert float(ramp["velocity"]) == pytest.approx(0.0025)                     # 0.05^2
    assert float(ramp["acceleration"]) == pytest.approx(0.0, abs=1e-12)
    z = d.training_losses(model_for(0.1 * (-1.0) ** k), x0, t, None, noise=noise)
    assert float(z["acceleration"]) == pytest.approx(0.16)                      # (4 · 0.1)^2
    torch.testing.assert_close(z["loss"], torch.tensor(0.01 + 0.04 + 3.0 * 0.16, dtype=D64))
    mask = torch.zeros(2, 6, 4, dtype=torch.bool)
    mask[:, :2] = True
    shifted = model_for(torch.where(mask, 0.0, 0.3).to(D64))
    a = d.training_losses(shifted, x0, t, None, known_mask=mask, noise=noise)["acceleration"]
    assert float(a) == pytest.approx(2 * 0.09 / 4)
    assert "acceleration" not in _diff(velocity_weight=1.0).training_losses(model_for(k), x0, t, None, noise=noise)
    with pytest.raises(ConfigError, match="diffusion.acceleration_weight"):
        _diff(acceleration_weight=-1.0)


# -- masks ------------------------------------------------------------------------------------
def test_known_mask_layout():
    m = known_mask(2, 6, 22, transition=torch.tensor([0, 2]), goal_xz=True, goal_y=torch.tensor([False, True]),
                   hand=True, hand_joint=21)
    assert m.shape == (2, 6, 66)
    assert not m[0, :5].any() and m[1, :2].all() and not m[1, 2:5].any()
    assert m[0, -1].nonzero().flatten().tolist() == [0, 2, 63, 64, 65]
    assert m[1, -1].nonzero().flatten().tolist() == [0, 1, 2, 63, 64, 65]


def test_sample_known_mask_rates():
    cfg = MaskConfig(p_transition=0.5, max_transition=2, p_goal_xz=0.8, p_goal_y=0.5, p_hand=0.0)
    m = sample_known_mask(4000, 16, 22, cfg, torch.Generator().manual_seed(0))
    k = m[:, :, 3].sum(1)  # frames with a pinned non-pelvis channel: transition frames
    assert set(k.unique().tolist()) == {0, 1, 2}
    assert float((k > 0).float().mean()) == pytest.approx(0.5, abs=0.03)
    goal = m[:, -1, 0]
    assert float(goal.float().mean()) == pytest.approx(0.8, abs=0.03)
    assert float(m[:, -1, 1][goal].float().mean()) == pytest.approx(0.5, abs=0.04)
    assert not m[:, 2:-1].any()


# -- samplers ---------------------------------------------------------------------------------
def test_trailing_timesteps():
    assert spaced_timesteps(100, 4).tolist() == [99, 74, 49, 24]
    assert spaced_timesteps(10, 10).tolist() == list(range(9, -1, -1))
    with pytest.raises(ConfigError):
        spaced_timesteps(100, 101)


def test_ddpm_golden_three_steps():
    """DDPM with a linear dummy model on a 3-step schedule, against a hand computation."""
    d = _diff(schedule="linear", steps=3, beta_start=0.1, beta_end=0.3, clip_x0=None, prediction="eps")
    model = LinearModel(0.5, 0.01)
    g = torch.Generator().manual_seed(7)
    x = sample(d, model, (1, 1, 1), None, sampler="ddpm", steps=3, generator=torch.Generator().manual_seed(7))

    betas = [0.1, 0.2, 0.3]
    ab = [0.9, 0.9 * 0.8, 0.9 * 0.8 * 0.7]
    z = torch.randn((1, 1, 1), generator=g, dtype=torch.float32)
    xh = math.sqrt(ab[2]) * 0.0 + math.sqrt(1 - ab[2]) * float(z)
    for t in (2, 1, 0):
        eps = 0.5 * xh + 0.01 * t
        ab_prev = ab[t - 1] if t > 0 else 1.0
        mean = (xh - betas[t] / math.sqrt(1 - ab[t]) * eps) / math.sqrt(1 - betas[t])  # DDPM eq. 11
        if t > 0:
            var = betas[t] * (1 - ab_prev) / (1 - ab[t])
            xh = mean + math.sqrt(var) * float(torch.randn((1, 1, 1), generator=g))
        else:
            xh = mean
    assert float(x) == pytest.approx(xh, rel=1e-5, abs=1e-6)


def test_ddpm_full_steps_matches_posterior_tables():
    d = _diff(schedule="linear", steps=10, clip_x0=None)
    s = DDPMScheduler(d)
    s.set_timesteps(10)
    g = torch.Generator().manual_seed(0)
    xt, out = torch.randn(2, 3, 6, generator=g), torch.randn(2, 3, 6, generator=g)
    t = 6
    x0, _ = d.predict_x0_eps(out, xt, torch.full((2,), t))
    mean, var = d.q_posterior_mean_variance(x0, xt, torch.full((2,), t))
    z = torch.randn(xt.shape, generator=torch.Generator().manual_seed(3))
    got = s.step(out, t, xt, torch.Generator().manual_seed(3))
    torch.testing.assert_close(got, mean + var.sqrt() * z, rtol=1e-5, atol=1e-5)


def test_ddim_eta1_equals_ddpm_and_eta0_deterministic():
    d = _diff(clip_x0=None)
    model = LinearModel()
    a = sample(d, model, (2, 4, 6), None, sampler="ddim", eta=1.0, steps=10, generator=torch.Generator().manual_seed(5))
    b = sample(d, model, (2, 4, 6), None, sampler="ddpm", steps=10, generator=torch.Generator().manual_seed(5))
    torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-4)
    c1 = sample(d, model, (2, 4, 6), None, steps=10, generator=torch.Generator().manual_seed(1))
    c2 = sample(d, model, (2, 4, 6), None, steps=10, generator=torch.Generator().manual_seed(1))
    assert torch.equal(c1, c2)
    # η = 0: only the initial noise is random; given the same x_T the steps are deterministic.
    s = DDIMScheduler(d, eta=0.0)
    s.set_timesteps(10)
    xt = torch.randn(2, 4, 6)
    out = torch.randn(2, 4, 6)
    assert torch.equal(s.step(out, 99, xt, torch.Generator().manual_seed(1)),
                       s.step(out, 99, xt, torch.Generator().manual_seed(2)))


@pytest.mark.parametrize("sampler", ["ddim", "ddpm"])
def test_known_entries_are_exact_and_seen_by_the_model(sampler):
    d = GaussianDiffusion()
    known = torch.randn(2, 8, 6)
    mask = known_mask(2, 8, 2, transition=2, goal_xz=True)
    seen = []

    def model(x, t, cond, known_mask=None):
        seen.append(bool(torch.equal(x[mask], known[mask])) and known_mask is mask)
        return torch.randn_like(x)

    x = sample(d, model, known.shape, None, known, mask, sampler=sampler, steps=7,
               generator=torch.Generator().manual_seed(0))
    assert torch.equal(x[mask], known[mask])
    assert len(seen) == 7 and all(seen)


def test_cfg_scale_one_equals_conditional_and_combines_linearly():
    from motiongen.models import Condition

    d = GaussianDiffusion()
    cond = Condition(drop_scene=torch.zeros(2, dtype=torch.bool), drop_actions=torch.zeros(2, dtype=torch.bool))
    kw = dict(steps=5, sampler="ddim")
    base = sample(d, CondModel(), (2, 3, 6), cond, generator=torch.Generator().manual_seed(0), **kw)
    s1 = sample(d, CondModel(), (2, 3, 6), cond, guidance_scale=1.0, generator=torch.Generator().manual_seed(0), **kw)
    assert torch.equal(base, s1)

    # s = 3 equals a model whose output is out_u + 3 (out_c - out_u), batched or not.
    class Guided:
        def __call__(self, x, t, c, known_mask=None):
            return 0.3 * x - 0.1 + 3 * 0.3

    ref = sample(d, Guided(), (2, 3, 6), cond, generator=torch.Generator().manual_seed(0), **kw)
    for batched in (True, False):
        got = sample(d, CondModel(), (2, 3, 6), cond, guidance_scale=3.0, cfg_batched=batched,
                     generator=torch.Generator().manual_seed(0), **kw)
        torch.testing.assert_close(got, ref)


def test_start_matches_schedule_marginal():
    """With ᾱ_T ≈ 0.36 (paper linear) the chain starts from √ᾱ_T·prior + √(1-ᾱ_T)·ε, not N(0, I)."""
    d = _diff(schedule="linear")
    starts = []

    def model(x, t, cond, known_mask=None):
        if not starts:
            starts.append(x.clone())
        return torch.zeros_like(x)

    prior = torch.full((4000, 1, 6), 0.5)
    sample(d, model, prior.shape, None, steps=2, x_prior=prior, generator=torch.Generator().manual_seed(0))
    ab = d.terminal_alpha_bar
    assert float(starts[0].mean()) == pytest.approx(math.sqrt(ab) * 0.5, abs=0.02)
    assert float(starts[0].var()) == pytest.approx(1 - ab, rel=0.05)


def test_channel_weights_give_a_weighted_mean_over_free_entries():
    d = _diff(loss="mse", prediction="x0")
    x0 = torch.zeros(2, 4, 6)
    model = lambda x, t, cond, known_mask=None: torch.arange(6.0).expand(2, 4, 6)  # noqa: E731  error = channel index
    mask = known_mask(2, 4, 2, transition=1)                       # first frame pinned
    w = torch.tensor([10.0, 10.0, 10.0, 1.0, 1.0, 1.0])
    out = d.training_losses(model, x0, torch.tensor([5, 9]), None, known_mask=mask, channel_weights=w)
    sq = torch.arange(6.0) ** 2
    torch.testing.assert_close(out["loss"], (sq * w).sum() / w.sum())       # same for every free frame
    torch.testing.assert_close(out["mse_x0"], sq.mean())                    # logged MSE stays unweighted


def test_entry_weights_weigh_single_entries_of_the_mean():
    """Entry weights (B, L, D) multiply the channel weights entry by entry; weights of 1 give the plain mean."""
    d = _diff(loss="mse", prediction="x0")
    x0 = torch.zeros(2, 4, 6)
    model = lambda x, t, cond, known_mask=None: torch.arange(6.0).expand(2, 4, 6)  # noqa: E731  error = channel index
    mask = known_mask(2, 4, 2, transition=1)
    t = torch.tensor([5, 9])
    plain = d.training_losses(model, x0, t, None, known_mask=mask)["loss"]
    torch.testing.assert_close(d.training_losses(model, x0, t, None, known_mask=mask,
                                                 entry_weights=torch.ones(2, 4, 6))["loss"], plain)
    e = torch.ones(2, 4, 6)
    e[0, -1, 5] = 7.0                                              # one entry of sample 0, error 5
    out = d.training_losses(model, x0, t, None, known_mask=mask, entry_weights=e)["loss"]
    sq = torch.arange(6.0) ** 2                                    # 6 free frames (3 per sample) of these errors
    torch.testing.assert_close(out, (6 * sq.sum() + 6 * sq[5]) / (6 * 6 + 6))


def test_hand_goal_per_sample():
    """A hand goal per sample: each row pins its own wrist's x, y, z at the last frame only."""
    m = known_mask(3, 5, 22, goal_xz=True, hand=torch.tensor([True, False, True]), hand_joint=torch.tensor([20, 21, 21]))
    assert m[0, -1].nonzero().flatten().tolist() == [0, 2, 60, 61, 62]
    assert m[1, -1].nonzero().flatten().tolist() == [0, 2]
    assert m[2, -1].nonzero().flatten().tolist() == [0, 2, 63, 64, 65]
    assert not m[:, :-1].any()
    with pytest.raises(ConfigError, match="mask joint 22"):
        known_mask(1, 5, 22, hand=True, hand_joint=22)


def test_sample_known_mask_draws_either_hand():
    cfg = MaskConfig(p_hand=0.5, hand_joints=(20, 21))
    m = sample_known_mask(4000, 16, 22, cfg, torch.Generator().manual_seed(0))
    left, right = m[:, -1, 60], m[:, -1, 63]
    assert not (left & right).any()
    assert float(left.float().mean()) == pytest.approx(0.25, abs=0.03)
    assert float(right.float().mean()) == pytest.approx(0.25, abs=0.03)
    # without a choice of hands the draws are those of before (the same generator sequence)
    plain = sample_known_mask(64, 16, 22, MaskConfig(), torch.Generator().manual_seed(3))
    again = sample_known_mask(64, 16, 22, MaskConfig(hand_joints=()), torch.Generator().manual_seed(3))
    assert torch.equal(plain, again)


def test_windows_that_end_in_a_hand_action_get_their_reaching_wrist_as_goal():
    """mask.p_hand_action = 1: every acting window gets a goal on the wrist it names, the others
    only the random hand goals of p_hand (0 here)."""
    acting = torch.tensor([True, False, True, False])
    wrist = torch.tensor([20, 21, 21, 20])
    cfg = MaskConfig(p_hand=0.0, p_hand_action=1.0, hand_joints=(20, 21))
    m = sample_known_mask(4, 8, 22, cfg, torch.Generator().manual_seed(0), action_hand=(acting, wrist))
    assert m[0, -1, 60:63].all() and not m[0, -1, 63:66].any()
    assert m[2, -1, 63:66].all() and not m[2, -1, 60:63].any()
    assert not m[[1, 3], -1, 60:66].any()
