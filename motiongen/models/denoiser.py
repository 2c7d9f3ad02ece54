"""Transformer denoiser: one token per window frame plus token 0 for the conditioning.

Token 0 = timestep embedding + scene embedding + action embedding (TRUMANS A.2). The
network knows nothing of β or of what its output means (ε, x0 or v): that is the
diffusion object's business.
"""

from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from motiongen.models.action_encoder import ActionEncoder, ActionMemo
from motiongen.models.condition import Condition
from motiongen.models.presets import ModelConfig
from motiongen.models.layers import Dropout, TransformerStack, sinusoidal_embedding
from motiongen.models.scene_encoder import SceneEncoder

try:  # marked deprecated by torch (in favour of torchao): a torch without it still samples in fp32 and bf16
    from torch.ao.quantization import per_channel_dynamic_qconfig, quantize_dynamic
except ImportError:  # pragma: no cover - torch 2.13 has it
    quantize_dynamic = per_channel_dynamic_qconfig = None
INT8_AVAILABLE = quantize_dynamic is not None       # Denoiser.quantize_layers can run


@dataclass
class EncodedCondition:
    """Encoder outputs, computed once per sampling call and reused at every step.

    ``broadcast`` marks an embedding built without any batch information (no condition
    tensors at all): its batch dim is 1 and it applies to every sample.
    """

    token0: Tensor                 # (B, W) scene + action embeddings (nulls where dropped)
    per_frame: Tensor | None       # (B, L, W) per-frame action embeddings, or None
    broadcast: bool = False
    last_frame: Tensor | None = None   # (B, W) the facing goal's embedding, added to the last frame's token

    def drop_all(self) -> "EncodedCondition":
        raise TypeError("drop conditions before encoding: model.encode_condition(cond.drop_all())")

    def concat(self, other: "EncodedCondition") -> "EncodedCondition":
        a, b = self, other
        if a.broadcast and b.broadcast:
            return a
        if a.broadcast:
            a = a._expand(b.token0.shape[0])
        if b.broadcast:
            b = b._expand(a.token0.shape[0])
        if (a.per_frame is None) != (b.per_frame is None) or (a.last_frame is None) != (b.last_frame is None):
            raise ValueError("EncodedCondition.concat: per-frame or last-frame embeddings in one half only")
        both = lambda u, v: None if u is None else torch.cat([u, v], 0)  # noqa: E731
        return EncodedCondition(torch.cat([a.token0, b.token0], 0), both(a.per_frame, b.per_frame),
                                last_frame=both(a.last_frame, b.last_frame))

    def _expand(self, n: int) -> "EncodedCondition":
        frames = None if self.per_frame is None else self.per_frame.expand(n, -1, -1)
        last = None if self.last_frame is None else self.last_frame.expand(n, -1)
        return EncodedCondition(self.token0.expand(n, -1), frames, last_frame=last)


class TimestepEmbedder(nn.Module):
    """Sinusoidal features of t followed by an MLP (as in MDM and the reference)."""

    def __init__(self, width: int):
        super().__init__()
        self.width = width
        self.mlp = nn.Sequential(nn.Linear(width, width), nn.SiLU(), nn.Linear(width, width))

    def forward(self, t: Tensor) -> Tensor:  # (B,) -> (B, W)
        return self.mlp(sinusoidal_embedding(t, self.width))


class Denoiser(nn.Module):
    def __init__(self, cfg: ModelConfig, num_joints: int, num_actions: int, window: int,
                 scene_res: tuple[int, int, int] = (32, 32, 32), channels: int | None = None,
                 alphas_cumprod: Tensor | None = None, facing_goal: bool = False):
        super().__init__()
        W = cfg.width
        self.cfg = cfg
        self.num_joints, self.num_actions, self.window = num_joints, num_actions, window
        self.scene_res = tuple(scene_res)
        D = num_joints * 3 if channels is None else int(channels)   # pose (3J) + stance channels
        self.channels = D
        self.input_scale = math.sqrt(W) if cfg.scale_input else 1.0
        # mask_channels: [free entries, pinned entries, mask] each through their own columns, so a
        # few clean values (the goal: 2 of D channels of the last frame) are not swamped by the
        # noisy entries of the same token (measured: with one shared projection the network
        # ignored the goal entirely).
        self.input = nn.Linear(3 * D if cfg.mask_channels else D, W)
        self.register_buffer("pos", sinusoidal_embedding(torch.arange(window + 1), W), persistent=False)
        self.t_embed = TimestepEmbedder(W)
        self.drop = Dropout(cfg.dropout)
        self.blocks = TransformerStack(W, cfg.layers, cfg.heads, cfg.ff, cfg.dropout, cfg.activation,
                                       cfg.norm_first, cfg.attention_dropout)
        self.output = nn.Linear(W, D)
        if not 0 <= cfg.temporal_basis <= window:
            raise ValueError(f"model.temporal_basis={cfg.temporal_basis}: expected 0 (off) .. window length {window}")
        if cfg.skip_sigma_data > 0:
            if alphas_cumprod is None:
                raise ValueError("model.skip_sigma_data needs the diffusion schedule (alphas_cumprod)")
            # (T, 2) c_skip, c_out per timestep; not saved: rebuilt from the schedule
            self.register_buffer("skip", skip_coefficients(alphas_cumprod, cfg.skip_sigma_data), persistent=False)

        # Null embeddings start small but non-zero so dropping a condition changes the output
        # from the first step (a zero null would make "dropped" look like "absent").
        self.scene_encoder = None
        if cfg.use_scene:
            self.scene_encoder = SceneEncoder(
                self.scene_res, cfg.scene_patch, cfg.scene_width, cfg.scene_layers, cfg.scene_heads,
                cfg.scene_ff, cfg.scene_dropout, cfg.activation, cfg.scene_norm_first, cfg.scene_pool, W,
                cfg.attention_dropout)
            self.scene_null = nn.Parameter(torch.randn(W) * 0.02)
        self.action_encoder = None
        if cfg.use_actions and num_actions > 0:
            self.action_encoder = ActionEncoder(
                num_actions, window, cfg.action_width, cfg.action_layers, cfg.action_heads, cfg.action_ff,
                cfg.action_dropout, cfg.activation, cfg.action_norm_first, W, cfg.action_per_frame,
                cfg.attention_dropout)
            self.action_null = nn.Parameter(torch.randn(W) * 0.02)
            self.action_null_frames = (nn.Parameter(torch.randn(W) * 0.02)
                                       if cfg.action_per_frame else None)
            self._action_memo = ActionMemo()
        # A facing goal (mask.p_facing > 0): the yaw asked for at the last frame, as (sin, cos)
        # through a small MLP onto that frame's token. Given as two hip positions (known entries)
        # it was not followed: a goal placed to a few per cent of the window's range does not fix
        # a facing across a body's 0.18 m width (docs/results.md, "A facing goal on the quality recipe").
        self.facing_embed = self.facing_null = None
        if facing_goal:
            self.facing_embed = nn.Sequential(nn.Linear(2, W), nn.SiLU(), nn.Linear(W, W))
            self.facing_null = nn.Parameter(torch.randn(W) * 0.02)

    _blocks_dtype: torch.dtype | None = None
    # Sampling looks the action encoder's outputs up by label window (`ActionMemo`); False runs
    # the encoder on every call (benchmarks/sample.py measures what the memo saves).
    memoise_actions: bool = True

    def train(self, mode: bool = True) -> "Denoiser":
        # A switch of mode is where weights are swapped in (EMA, a loaded checkpoint): start the
        # action memo afresh there too, beside its own check of the weights' versions.
        if self.action_encoder is not None:
            self._action_memo.clear()
        return super().train(mode)

    def blocks_to(self, dtype: torch.dtype) -> "Denoiser":
        """Hold the transformer layers (nearly all of the per-step compute) in `dtype`, e.g.
        torch.bfloat16 for sampling: half the weight bytes each denoising step reads. The input
        and output projections, the timestep MLP and the encoders stay as they are. Sampling
        only: the optimiser's updates would be lost in bfloat16 weights."""
        if self.training and dtype != torch.float32:
            raise RuntimeError("blocks_to: reduced-precision layers are for sampling (call model.eval() first)")
        self.blocks.to(dtype)
        self._blocks_dtype = dtype
        return self

    def quantize_layers(self, denoiser: bool = True) -> "Denoiser":
        """Sampling on a CPU: the linear maps of the transformer layers with int8 weights, one
        scale per output channel, and their inputs quantized to 8 bits at each call (torch's
        dynamic quantization, fbgemm or qnnpack kernels): the scene and action encoders', and
        with `denoiser` the denoiser's own. At batch 1 those products are bound by the weight
        bytes they read; int8 reads a quarter of float32's and runs on any x86-64 or ARM CPU,
        where bfloat16 needs AVX-512 or AMX. The embeddings, norms and the input and output
        projections stay float32. The encoders run once per window and their output is one
        conditioning token, so their rounding barely moves a motion; the denoiser's, at every
        step and frame, adds jitter (docs/sampling.md)."""
        if self.training:
            raise RuntimeError("quantize_layers: int8 layers are for sampling (call model.eval() first)")
        if next(self.parameters()).device.type != "cpu":
            raise RuntimeError("quantize_layers: int8 layers run on the CPU only")
        if not INT8_AVAILABLE:
            raise RuntimeError(f"quantize_layers: torch {torch.__version__} has no dynamic quantization")
        stacks = [m for m in (self.blocks if denoiser else None, getattr(self.scene_encoder, "blocks", None),
                              getattr(self.action_encoder, "blocks", None)) if m is not None]
        with warnings.catch_warnings():
            # torch marks its eager quantization API as deprecated in favour of torchao, whose
            # int8 layers were 3-30x slower than these on a CPU without torch.compile
            # (docs/results.md, "int8 layers").
            warnings.simplefilter("ignore")
            for stack in stacks:
                quantize_dynamic(stack, {nn.Linear: per_channel_dynamic_qconfig}, dtype=torch.qint8, inplace=True)
        if self.action_encoder is not None:
            self._action_memo.clear()
        self._blocks_dtype = None
        return self

    # -- conditioning -------------------------------------------------------------------
    def encode_condition(self, cond: Condition | None) -> EncodedCondition:
        """Run the scene/action encoders once; the result can be passed to ``forward``."""
        W = self.cfg.width
        cond = cond if cond is not None else Condition()
        B = cond.batch_size
        n = B if B is not None else 1
        ref = next(self.parameters())
        token0 = torch.zeros(n, W, device=ref.device, dtype=ref.dtype)  # (n, W)
        per_frame = None

        if self.scene_encoder is not None:
            token0 = token0 + self._with_null(cond.scene, cond.drop_scene, n,
                                              lambda s: self.scene_encoder(s), self.scene_null)
        if self.action_encoder is not None:
            pooled, frames = self._encode_actions(cond.actions, cond.drop_actions, n)
            token0 = token0 + pooled
            per_frame = frames
        last = self._encode_facing(cond, n) if self.facing_embed is not None else None
        return EncodedCondition(token0, per_frame, broadcast=B is None, last_frame=last)

    def _encode_facing(self, cond: Condition, n: int) -> Tensor:
        """(n, W) the facing goal's embedding, the learned null where a sample has none."""
        if cond.facing is None:
            return self.facing_null.expand(n, -1)
        emb = self.facing_embed(cond.facing.to(self.facing_null.dtype))                    # (n, W)
        given = cond.facing_given if cond.facing_given is not None else torch.ones(n, dtype=torch.bool,
                                                                                      device=emb.device)
        return torch.where(given[:, None], emb, self.facing_null.expand_as(emb))

    def _with_null(self, value: Tensor | None, drop: Tensor | None, n: int, encode, null: Tensor) -> Tensor:
        if value is None:
            return null.expand(n, -1)
        if not self.training and drop is not None and bool(drop.all()):
            return null.expand(n, -1)  # (n, W); inference skips the encoder for fully dropped batches
        emb = encode(value)  # (n, W)
        if drop is None:
            if not self.training:
                return emb
            drop = torch.zeros(n, dtype=torch.bool, device=emb.device)
        # In training the encoder and the null both take part in every step, whatever was
        # dropped (DistributedDataParallel needs a gradient for every parameter on every rank).
        return torch.where(drop[:, None], null.expand_as(emb), emb)

    def _encode_actions(self, actions: Tensor | None, drop: Tensor | None, n: int):
        enc = self.action_encoder
        skip = actions is None or (not self.training and drop is not None and bool(drop.all()))
        if skip:
            frames = None
            if enc.per_frame:
                frames = self.action_null_frames.expand(n, self.window, -1)  # (n, L, W)
            return self.action_null.expand(n, -1), frames
        # sampling (no autograd): each distinct label window once (ActionMemo)
        memo = self.memoise_actions and not self.training and not torch.is_grad_enabled()
        pooled, frames = self._action_memo(enc, actions) if memo else enc(actions)  # (n, W), (n, L, W) | None
        if drop is None and self.training:
            drop = torch.zeros(n, dtype=torch.bool, device=pooled.device)
        if drop is not None:
            pooled = torch.where(drop[:, None], self.action_null.expand_as(pooled), pooled)
            if frames is not None:
                frames = torch.where(drop[:, None, None], self.action_null_frames.expand_as(frames), frames)
        return pooled, frames

    # -- denoising ----------------------------------------------------------------------
    def forward(self, x_t: Tensor, t: Tensor, cond: Condition | EncodedCondition | None = None,
                known_mask: Tensor | None = None) -> Tensor:
        """x_t (B, L, D), t (B,) long, cond raw or pre-encoded, known_mask (B, L, D) bool -> (B, L, D)."""
        B, L, D = x_t.shape
        if D != self.channels:
            raise ValueError(f"denoiser expects {self.channels} channels, got {D}")
        if L > self.window:
            raise ValueError(f"window {L} longer than configured {self.window}")
        enc = cond if isinstance(cond, EncodedCondition) else self.encode_condition(cond)

        inp = x_t
        if self.cfg.mask_channels:
            mask = (known_mask if known_mask is not None else torch.zeros_like(x_t, dtype=torch.bool)).to(x_t.dtype)
            inp = torch.cat([x_t * (1 - mask), x_t * mask, mask], -1)  # (B, L, 3D)
        h = self.input(inp) * self.input_scale  # (B, L, W)
        if enc.per_frame is not None:
            h = h + enc.per_frame[:, :L]
        if enc.last_frame is not None:
            # the goal frame, where the pelvis and hand goals are given too
            h = torch.cat([h[:, :-1], h[:, -1:] + enc.last_frame[:, None]], 1)
        tok0 = self.t_embed(t) + enc.token0  # (B, W); token0 may be (1, W) and broadcast
        h = torch.cat([tok0[:, None], h], 1) + self.pos[: L + 1]  # (B, L+1, W)
        # the layers may hold bfloat16 weights for sampling (blocks_to); the ends stay float32
        h = self.drop(h)
        h = self.blocks(h if self._blocks_dtype is None else h.to(self._blocks_dtype)).to(x_t.dtype)
        out = self.output(h[:, 1:])  # (B, L, D); token 0's output is dropped
        if self.cfg.skip_sigma_data > 0:
            c = self.skip[t].to(out.dtype)                                         # (B, 2)
            out = c[:, 0, None, None] * x_t + c[:, 1, None, None] * out
        if self.cfg.temporal_basis and self.cfg.temporal_basis < self.window:
            # same cut-off frequency for a shorter window: round(K L / window) vectors
            k = max(1, round(self.cfg.temporal_basis * L / self.window))
            out = torch.einsum("st,btd->bsd", lowpass_projection(L, k, out.device, out.dtype), out)
        return out


def skip_coefficients(alphas_cumprod: Tensor, sigma_data: float) -> Tensor:
    """(T, 2) float32 EDM's c_skip, c_out for x_t = √ᾱ x0 + √(1-ᾱ) ε and data of standard
    deviation σ: x̂0 = c_skip x_t + c_out F is the best linear estimate of x0 from x_t plus a
    unit-scaled correction. c_skip → 1 at no noise, → 0 at pure noise (plain x0 there)."""
    ab = alphas_cumprod.double()
    s2 = sigma_data ** 2
    denom = ab * s2 + (1 - ab)
    c_skip = ab.sqrt() * s2 / denom
    c_out = sigma_data * (1 - ab).sqrt() / denom.sqrt()
    return torch.stack([c_skip, c_out], -1).float()


@functools.lru_cache(maxsize=32)
def lowpass_projection(length: int, k: int, device, dtype) -> Tensor:
    """(L, L) orthogonal projection onto the first k orthonormal DCT-II vectors over L frames
    (frequencies 0 .. (k-1)/(2L) cycles per frame)."""
    n = torch.arange(length, dtype=torch.float64)
    basis = torch.cos(math.pi * (n[:, None] + 0.5) * torch.arange(k, dtype=torch.float64)[None] / length)  # (L, k)
    basis = basis / basis.norm(dim=0, keepdim=True)
    return (basis @ basis.T).to(device=device, dtype=dtype)


def build_model(cfg: ModelConfig, num_joints: int, num_actions: int, window: int,
                scene_res: tuple[int, int, int] = (32, 32, 32), channels: int | None = None,
                alphas_cumprod: Tensor | None = None, facing_goal: bool = False) -> Denoiser:
    return Denoiser(cfg, num_joints, num_actions, window, scene_res, channels, alphas_cumprod, facing_goal)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
