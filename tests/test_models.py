"""Networks: presets, shapes, condition handling (null embeddings, dropout, caching), overfitting."""

from __future__ import annotations

import time
from dataclasses import replace

import pytest
import torch

from motiongen.diffusion import GaussianDiffusion, known_mask, sample
from motiongen.models import (PRESETS, Condition, EncodedCondition, ModelConfig, build_model, count_parameters,
                              drop_conditions, model_config)
from motiongen.models.layers import fast_dropout

J, A, L = 22, 6, 16


def _cond(B: int, seed: int = 0) -> Condition:
    g = torch.Generator().manual_seed(seed)
    return Condition(scene=(torch.rand(B, 32, 32, 32, generator=g) < 0.3).float(),
                     actions=(torch.rand(B, L, A, generator=g) < 0.3).float())


@pytest.fixture
def one_thread():
    """Tiny models are faster on one thread, and on a shared, oversubscribed CPU a second
    OpenMP thread that is descheduled stalls every small op (seconds per step observed)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _tiny(**kw):
    torch.manual_seed(0)
    return build_model(model_config("tiny", **kw), J, A, L).eval()


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_presets_build_and_forward(name):
    torch.manual_seed(0)
    model = build_model(PRESETS[name], J, A, L).eval()
    B = 1 if name != "tiny" else 3
    with torch.no_grad():
        out = model(torch.randn(B, L, J * 3), torch.randint(0, 100, (B,)), _cond(B))
    assert out.shape == (B, L, J * 3)
    assert torch.isfinite(out).all()


def test_preset_sizes():
    counts = {n: count_parameters(build_model(PRESETS[n], J, A, L)) for n in ("tiny",)}
    assert counts["tiny"] < 1_000_000
    paper = PRESETS["paper"]
    assert (paper.width, paper.layers, paper.heads, paper.ff, paper.dropout) == (512, 6, 16, 1024, 0.1)
    assert (paper.scene_layers, paper.scene_heads, paper.action_layers, paper.action_heads) == (6, 16, 6, 16)
    ref = PRESETS["reference"]
    assert (ref.layers, ref.ff, ref.norm_first, ref.scene_patch, ref.scene_ff, ref.scene_width) == \
        (8, 512, False, 8, 2048, 1024)


def test_model_config_is_hydra_structured():
    from omegaconf import OmegaConf

    node = OmegaConf.structured(PRESETS["paper"])
    assert ModelConfig(**OmegaConf.to_container(node)) == PRESETS["paper"]
    with pytest.raises(Exception):
        model_config("tiny", no_such_field=1)


def test_scene_patches_tile_the_ground_plane():
    model = _tiny()
    enc = model.scene_encoder
    assert enc.pos.shape[1] == 16 + 1  # 4x4 patches of 8 + CLS
    assert enc.patch_embed.in_features == 32 * 8 * 8


def test_dropped_conditions_use_null_embeddings():
    model = _tiny()
    B = 2
    x, t, cond = torch.randn(B, L, J * 3), torch.tensor([5, 60]), _cond(B)
    with torch.no_grad():
        full = model(x, t, cond)
        dropped = Condition(cond.scene, cond.actions, torch.tensor([True, False]), torch.tensor([False, False]))
        out = model(x, t, dropped)
        null_scene = model(x, t, Condition(None, cond.actions))
        none = model(x, t, None)
        both = model(x, t, cond.drop_all())
    torch.testing.assert_close(out[0], null_scene[0])  # sample 0: scene replaced by its null
    torch.testing.assert_close(out[1], full[1])        # sample 1 untouched
    assert not torch.allclose(out[0], full[0])
    torch.testing.assert_close(both, none)             # fully unconditional = no condition at all


def test_drop_conditions_rate():
    cond = Condition(scene=torch.zeros(20000, 1, 1, 1), actions=torch.zeros(20000, 1, 1))
    out = drop_conditions(cond, 0.1, 0.3, torch.Generator().manual_seed(0))
    assert float(out.drop_scene.float().mean()) == pytest.approx(0.1, abs=0.01)
    assert float(out.drop_actions.float().mean()) == pytest.approx(0.3, abs=0.015)
    # Independent draws, and existing drops are kept.
    both = float((out.drop_scene & out.drop_actions).float().mean())
    assert both == pytest.approx(0.03, abs=0.006)
    again = drop_conditions(out, 0.0, 0.0)
    assert torch.equal(again.drop_scene, out.drop_scene)


def test_encoded_condition_matches_raw_and_concat():
    model = _tiny(action_per_frame=True)
    B = 2
    x, t, cond = torch.randn(B, L, J * 3), torch.tensor([1, 2]), _cond(B)
    with torch.no_grad():
        enc = model.encode_condition(cond)
        assert isinstance(enc, EncodedCondition) and enc.per_frame.shape == (B, L, model.cfg.width)
        torch.testing.assert_close(model(x, t, enc), model(x, t, cond))
        both = enc.concat(model.encode_condition(cond.drop_all()))
        out2 = model(torch.cat([x, x]), torch.cat([t, t]), both)
        torch.testing.assert_close(out2[B:], model(x, t, cond.drop_all()))
        bc = model.encode_condition(None).concat(model.encode_condition(None))
        assert model(x, t, bc).shape == x.shape


def test_mask_channels_change_the_output():
    model = _tiny(mask_channels=True)
    assert model.input.in_features == 3 * J * 3          # free entries | pinned entries | mask
    x, t, cond = torch.randn(1, L, J * 3), torch.tensor([3]), _cond(1)
    m = known_mask(1, L, J, transition=2, goal_xz=True)
    with torch.no_grad():
        assert not torch.allclose(model(x, t, cond, known_mask=m), model(x, t, cond))
        # pinned values enter through their own columns: zeroing the free-entry columns leaves
        # the output's dependence on a pinned value intact
        model.input.weight[:, : J * 3] = 0
        x2 = x.clone()
        x2[0, -1, 0] += 1.0                                # move the pinned goal
        assert not torch.allclose(model(x, t, cond, known_mask=m), model(x2, t, cond, known_mask=m))


def test_temporal_basis_confines_output_to_low_dct_frequencies():
    """Known answer from scipy's DCT-II (an independent implementation): with temporal_basis=K
    every output channel has no energy beyond its first K orthonormal DCT coefficients, in
    full windows and (same cut-off, round(K l / L) vectors) in shorter ones."""
    from scipy.fft import dct
    model = _tiny(temporal_basis=6)
    x, t, cond = torch.randn(2, L, J * 3), torch.tensor([3, 50]), _cond(2)
    with torch.no_grad():
        out = model(x, t, cond).double().numpy()                  # (B, L, D)
        short = model(x[:, :8], t, cond.__class__(scene=cond.scene, actions=cond.actions[:, :8])).double().numpy()
    coef = dct(out, type=2, norm="ortho", axis=1)
    assert abs(coef[:, 6:]).max() < 1e-5 * abs(coef[:, :6]).max()
    coef = dct(short, type=2, norm="ortho", axis=1)
    assert abs(coef[:, 3:]).max() < 1e-5 * abs(coef[:, :3]).max()
    # K = window length is the identity: same weights, same output as no basis
    full, off = _tiny(temporal_basis=L), _tiny(temporal_basis=0)
    with torch.no_grad():
        torch.testing.assert_close(full(x, t, cond), off(x, t, cond))
    with pytest.raises(ValueError, match="temporal_basis"):
        _tiny(temporal_basis=L + 1)


def test_condition_to_and_concat():
    c = _cond(2).to("cpu")
    cc = c.concat(c.drop_all())
    assert cc.scene.shape[0] == 4 and cc.drop_scene.tolist() == [False, False, True, True]


def test_fast_dropout_rate_and_scale():
    x = torch.ones(200_000)
    y = fast_dropout(x, 0.1, True)
    assert float((y == 0).float().mean()) == pytest.approx(0.1, abs=0.005)
    assert float(y.mean()) == pytest.approx(1.0, abs=0.01)
    assert torch.equal(fast_dropout(x, 0.1, False), x)


def test_sampler_encodes_condition_once(one_thread):
    model = _tiny()
    calls = []
    model.scene_encoder.register_forward_hook(lambda *a: calls.append(1))
    d = GaussianDiffusion()
    x = sample(d, model, (2, L, J * 3), _cond(2), steps=5, guidance_scale=2.0,
                 generator=torch.Generator().manual_seed(0))
    assert x.shape == (2, L, J * 3)
    assert len(calls) == 1  # conditional encode only; the unconditional twin skips the encoder


def test_action_memo_encodes_each_label_window_once_and_forgets_old_weights(one_thread):
    model = _tiny(action_per_frame=True)
    rows = []
    model.action_encoder.register_forward_hook(lambda mod, inp, out: rows.append(inp[0].shape[0]))
    a = torch.zeros(5, L, A)
    a[:, :, 1] = 1
    a[3, L // 2:, 2] = 1                                  # rows 0, 1, 2, 4 share one window
    with torch.no_grad():
        pooled, frames = model._encode_actions(a, None, 5)
        want, want_frames = model.action_encoder(a)
        torch.testing.assert_close(pooled, want)
        torch.testing.assert_close(frames, want_frames)
        assert rows == [2, 5]                             # two distinct windows; then the direct call
        model._encode_actions(a[3:4], None, 1)            # seen before: no encoder call
        assert rows == [2, 5]
        model.action_encoder.embed.bias.add_(0.5)         # new weights in place (an EMA update)
        again, _ = model._encode_actions(a[:1], None, 1)
        torch.testing.assert_close(again, model.action_encoder(a[:1])[0])
        assert rows[2] == 1
    # with autograd on (training, distillation's student) the encoder runs on every call
    model.train()
    model._encode_actions(a, None, 5)
    assert rows[-1] == 5


def test_tiny_overfits_one_batch(one_thread):
    torch.manual_seed(0)
    model = build_model(model_config("tiny", dropout=0.0, scene_dropout=0.0, action_dropout=0.0), J, A, L)
    d = GaussianDiffusion()
    g = torch.Generator().manual_seed(0)
    B = 8
    x0 = torch.rand(B, L, J * 3, generator=g) * 2 - 1
    noise = torch.randn(B, L, J * 3, generator=g)
    t = torch.randint(0, 100, (B,), generator=g)
    mask = known_mask(B, L, J, transition=2, goal_xz=True)
    cond = _cond(B)
    opt = torch.optim.Adam(model.parameters(), lr=4e-3)
    start = time.perf_counter()
    losses = []
    for _ in range(200):
        loss = d.training_losses(model, x0, t, cond, known_mask=mask, noise=noise)["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        if losses[-1] < losses[0] / 10:
            break
    assert losses[-1] < losses[0] / 10, (losses[0], losses[-1])
    assert time.perf_counter() - start < 30


def test_bf16_layers_keep_the_output_within_a_few_percent(one_thread):
    """precision=bf16 (sampling): the transformer layers hold bfloat16 weights, the ends stay
    float32, and the prediction moves by bfloat16's rounding, not more."""
    import copy

    m = _tiny()
    cond, g = _cond(4), torch.Generator().manual_seed(1)
    x, t = torch.randn(4, L, m.channels, generator=g), torch.tensor([10, 200, 500, 900])
    with torch.inference_mode():
        ref = m(x, t, cond)
        half = copy.deepcopy(m).blocks_to(torch.bfloat16)
        out = half(x, t, cond)
    assert {p.dtype for p in half.blocks.parameters()} == {torch.bfloat16}
    assert half.output.weight.dtype == torch.float32 and out.dtype == torch.float32
    err = float((out - ref).norm() / ref.norm())
    assert 1e-4 < err < 0.03, err
    with pytest.raises(RuntimeError, match="for sampling"):
        _tiny().train().blocks_to(torch.bfloat16)


def test_int8_layers_quantize_every_transformer_layer_and_keep_the_output_close(one_thread):
    """precision=int8 (sampling on a CPU): every linear map inside the three transformer stacks
    holds int8 weights, everything outside them stays float32, and the prediction moves by
    8-bit rounding (more than bf16's, far less than a different network's); int8-encoders
    quantizes the two encoders' stacks only."""
    import copy

    from torch.ao.nn.quantized.dynamic import Linear as Int8Linear

    m = _tiny()
    cond, g = _cond(4), torch.Generator().manual_seed(1)
    x, t = torch.randn(4, L, m.channels, generator=g), torch.tensor([10, 200, 500, 900])
    with torch.inference_mode():
        ref = m(x, t, cond)
        q = copy.deepcopy(m).quantize_layers()
        out = q(x, t, cond)
        torch.manual_seed(1)
        other = build_model(model_config("tiny"), J, A, L).eval()(x, t, cond)     # another network
    for stack in (q.blocks, q.scene_encoder.blocks, q.action_encoder.blocks):
        kinds = {type(mod) for mod in stack.modules() if isinstance(mod, (torch.nn.Linear, Int8Linear))}
        assert kinds == {Int8Linear}, kinds
    assert {type(q.input), type(q.output), type(q.scene_encoder.patch_embed)} == {torch.nn.Linear}
    assert out.dtype == torch.float32
    err = float((out - ref).norm() / ref.norm())
    assert 1e-4 < err < 0.05, err
    assert float((other - ref).norm() / ref.norm()) > 10 * err
    # int8-encoders: the denoiser's own layers stay float32, and the prediction moves less
    with torch.inference_mode():
        enc = copy.deepcopy(m).quantize_layers(denoiser=False)
        err_enc = float((enc(x, t, cond) - ref).norm() / ref.norm())
    assert {type(mod) for mod in enc.blocks.modules() if isinstance(mod, torch.nn.Linear)} == {torch.nn.Linear}
    assert {type(mod) for mod in enc.scene_encoder.blocks.modules() if isinstance(mod, Int8Linear)} == {Int8Linear}
    assert 0 < err_enc < err, (err_enc, err)
    with pytest.raises(RuntimeError, match="for sampling"):
        _tiny().train().quantize_layers()


def test_precision_auto_is_bf16_for_paper_size_layers_on_native_bf16_only(monkeypatch):
    from motiongen.errors import ConfigError
    from motiongen.loading import build
    from motiongen.loading.build import resolve_precision

    paper = build_model(model_config("paper"), J, A, L)
    assert isinstance(build.native_bf16(torch.device("cpu")), bool)
    monkeypatch.setattr(build, "native_bf16", lambda device: device.type == "cpu")
    assert resolve_precision(_tiny(), "auto") == "fp32" and resolve_precision(paper, "auto") == "bf16"
    monkeypatch.setattr(build, "native_bf16", lambda device: False)      # an AVX2-only CPU
    assert resolve_precision(paper, "auto") == "fp32"
    assert resolve_precision(paper, "fp32") == "fp32" and resolve_precision(_tiny(), "bf16") == "bf16"
    assert resolve_precision(paper, "int8") == "int8"                   # asked for, never chosen by auto
    with pytest.raises(ConfigError, match="precision: expected one of fp32, bf16, int8, int8-encoders, auto"):
        resolve_precision(paper, "fp16")
    # a torch without dynamic quantization: int8 refused in one line, before the file is read
    monkeypatch.setattr(build, "INT8_AVAILABLE", False)
    with pytest.raises(ConfigError, match="precision=int8-encoders: torch .* has no dynamic quantization"):
        build.load_model("no-such-file.pt", precision="int8-encoders")


def test_skip_coefficients_are_the_best_linear_estimate_and_a_unit_target():
    """EDM's preconditioning for x_t = √ᾱ x0 + √(1-ᾱ) ε, x0 ~ N(0, σ²): c_skip x_t is the
    least-squares estimate of x0 (its residual is uncorrelated with x_t) and the network's
    target (x0 - c_skip x_t) / c_out has unit variance, at every noise level."""
    from motiongen.diffusion import DiffusionConfig
    from motiongen.models.denoiser import skip_coefficients

    sigma = 0.4
    ab = GaussianDiffusion(DiffusionConfig()).alphas_cumprod
    c = skip_coefficients(ab, sigma).double()
    g = torch.Generator().manual_seed(0)
    x0 = sigma * torch.randn(200_000, generator=g, dtype=torch.float64)
    eps = torch.randn(200_000, generator=g, dtype=torch.float64)
    for t in (0, 10, 50, 99):
        x_t = ab[t].sqrt() * x0 + (1 - ab[t]).sqrt() * eps
        resid = x0 - c[t, 0] * x_t
        assert abs(float((resid * x_t).mean())) < 3e-3
        assert abs(float((resid / c[t, 1]).std()) - 1) < 0.01
    assert abs(float(c[0, 0]) - 1) < 1e-2 and float(c[-1, 0]) < 1e-3          # copies at no noise, not at pure noise


def test_skip_output_is_the_input_where_the_network_says_nothing():
    """With the output layer zeroed, the model returns c_skip(t) x_t; at t = 0 nearly x_t."""
    from motiongen.diffusion import DiffusionConfig

    ab = GaussianDiffusion(DiffusionConfig()).alphas_cumprod
    torch.manual_seed(0)
    model = build_model(model_config("tiny", skip_sigma_data=0.4), J, A, L, alphas_cumprod=ab).eval()
    torch.nn.init.zeros_(model.output.weight)
    torch.nn.init.zeros_(model.output.bias)
    x = torch.randn(2, L, 3 * J)
    out = model(x, torch.tensor([0, 50]), _cond(2))
    assert torch.allclose(out, model.skip[[0, 50], 0, None, None] * x, atol=1e-6)
    assert float(model.skip[0, 0]) > 0.99
    with pytest.raises(ValueError, match="schedule"):
        build_model(model_config("tiny", skip_sigma_data=0.4), J, A, L)


def test_facing_goal_reaches_the_last_frame_and_a_sample_without_one_gets_the_null():
    """A model built with a facing goal: a given facing changes the window's output (most at its
    last frame, where it enters), another facing changes it again, and a sample not given one is
    computed exactly as with no facing at all; a model built without one has no such input."""
    torch.manual_seed(0)
    model = build_model(model_config("tiny"), J, A, L, facing_goal=True).eval()
    B = 2
    x, t, base = torch.randn(B, L, J * 3), torch.randint(0, 100, (B,)), _cond(B)
    ahead = torch.tensor([[0.0, 1.0], [0.0, 1.0]])                    # (sin, cos): yaw 0
    left = torch.tensor([[1.0, 0.0], [1.0, 0.0]])                     # yaw 90 degrees
    run = lambda facing, given=None: model(x, t, replace(base, facing=facing, facing_given=given))  # noqa: E731
    with torch.no_grad():
        none, a, b = run(None), run(ahead), run(left)
        mixed = run(left, torch.tensor([True, False]))
    assert (a - none).abs().amax() > 1e-3 and (b - a).abs().amax() > 1e-3
    assert torch.equal(mixed[1], none[1]) and torch.equal(mixed[0], b[0])
    assert build_model(model_config("tiny"), J, A, L).facing_embed is None
    enc = model.encode_condition(replace(base, facing=left)).concat(model.encode_condition(replace(base, facing=ahead)))
    assert enc.last_frame.shape == (2 * B, model.cfg.width)
    with pytest.raises(ValueError, match="one half only"):
        enc.concat(build_model(model_config("tiny"), J, A, L).eval().encode_condition(base))


def test_a_facing_goal_stays_through_guidance_and_batching():
    """Classifier-free guidance's unconditional twin drops the scene and the actions but keeps the
    facing goal (a goal, like the known entries); concatenating two conditions stacks their
    facings and given flags, and one with a facing cannot be stacked with one without."""
    B = 2
    cond = replace(_cond(B), facing=torch.tensor([[1.0, 0.0], [0.0, 1.0]]), facing_given=torch.tensor([True, False]))
    twin = cond.drop_all()
    assert twin.drop_scene.all() and twin.drop_actions.all() and torch.equal(twin.facing, cond.facing)
    both = cond.concat(twin)
    assert both.facing.shape == (2 * B, 2) and both.facing_given.tolist() == [True, False, True, False]
    with pytest.raises(ValueError, match="facing"):
        cond.concat(_cond(B))
    assert Condition(facing=cond.facing).drop_all().drop_scene.shape == (B,)
