"""Model configuration and the size presets.

``ModelConfig`` holds only primitive fields so it registers as a Hydra structured config.
Presets live in ``PRESETS``; ``model_config(name, **overrides)`` copies one.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from motiongen.errors import ConfigError


@dataclass
class ModelConfig:
    name: str = "tiny"
    # Denoiser: one token per window frame plus token 0 (timestep + scene + action).
    width: int = 96
    layers: int = 3
    heads: int = 4
    ff: int = 192
    dropout: float = 0.1
    activation: str = "gelu"
    # Dropout on attention probabilities (all three networks). PyTorch's layer (and so the
    # reference) uses `dropout` there too; 0 keeps CPU attention on the fused SDPA kernel.
    attention_dropout: float = 0.0
    norm_first: bool = False        # False = post-LN as PyTorch's default and the reference
    scale_input: bool = True        # input projection multiplied by sqrt(width) (reference)
    mask_channels: bool = True      # pinned entries through their own input columns + the mask (docs/models.md)
    # Output confined to the lowest `temporal_basis` DCT-II vectors over the window (0 = off,
    # every frame free): windows smooth by construction, no frame-to-frame jitter at the
    # window's Nyquist rate (docs/quality.md). Needs x0 prediction.
    temporal_basis: int = 0
    # x0 through a skip from the input (EDM's preconditioning, Karras et al. 2022): the network's
    # output F becomes x̂0 = c_skip(t) x_t + c_out(t) F with c_skip, c_out for data of this
    # standard deviation (normalised units), so at low noise it refines its input instead of
    # redrawing the window (without it the x0 network's x̂0 at t = 1 is as far from the clean
    # window as at t = T, 4 cm at the pelvis). Tried on the demo and the quality size, not
    # kept: sampled, the windows jitter and the body comes apart (docs/results.md). 0 = off.
    # Needs x0 prediction and the diffusion schedule (`build_model(..., alphas_cumprod=)`).
    skip_sigma_data: float = 0.0
    # Scene encoder: ViT over the local occupancy grid, height slices as channels.
    use_scene: bool = True
    scene_width: int = 64
    scene_layers: int = 1
    scene_heads: int = 4
    scene_ff: int = 128
    scene_patch: int = 8
    scene_pool: str = "cls"         # "cls" | "mean"
    scene_norm_first: bool = True   # ViTs are pre-LN (vit-pytorch, used by the reference)
    scene_dropout: float = 0.1
    # Action encoder: Linear(A -> width) per frame + positions + transformer, mean over frames.
    use_actions: bool = True
    action_width: int = 64
    action_layers: int = 1
    action_heads: int = 4
    action_ff: int = 128
    action_norm_first: bool = False
    action_dropout: float = 0.1
    action_per_frame: bool = False  # also add per-frame action embeddings to the frame tokens


PRESETS: dict[str, ModelConfig] = {
    # TRUMANS supplement A.2. The paper names no activation or LN placement: we use GELU
    # and post-LN (the defaults of the PyTorch encoder that Guo et al.'s code builds on).
    # Encoder FF width is not given either; we use the denoiser's 1024.
    "paper": ModelConfig(
        name="paper", width=512, layers=6, heads=16, ff=1024, dropout=0.1, activation="gelu",
        norm_first=False,
        scene_width=512, scene_layers=6, scene_heads=16, scene_ff=1024, scene_patch=8,
        scene_pool="cls", scene_norm_first=True, scene_dropout=0.1,
        action_width=512, action_layers=6, action_heads=16, action_ff=1024,
        action_norm_first=False, action_dropout=0.1,
    ),
    # The public code: denoiser 8 layers, FF 512, GELU, post-LN; vit-pytorch ViT with
    # dim 1024, mlp 2048, 6 layers, 16 heads, patch 8, CLS pooling, projected to 512;
    # action encoder 512-d, 8 layers, 8 heads (num_heads // 2), FF 512, post-LN.
    "reference": ModelConfig(
        name="reference", width=512, layers=8, heads=16, ff=512, dropout=0.1, activation="gelu",
        norm_first=False, mask_channels=False,
        scene_width=1024, scene_layers=6, scene_heads=16, scene_ff=2048, scene_patch=8,
        scene_pool="cls", scene_norm_first=True, scene_dropout=0.1,
        action_width=512, action_layers=8, action_heads=8, action_ff=512,
        action_norm_first=False, action_dropout=0.1,
    ),
    # For CPU tests and the demo: < 1M parameters in total.
    "tiny": ModelConfig(name="tiny"),
}


def model_config(name: str, **overrides) -> ModelConfig:
    """A copy of preset ``name`` with ``overrides`` applied (unknown keys are errors)."""
    if name not in PRESETS:
        raise ConfigError(f"model preset: expected one of {sorted(PRESETS)}, got {name!r}")
    known = {f.name for f in fields(ModelConfig)}
    unknown = set(overrides) - known
    if unknown:
        raise ConfigError(f"model config: unknown field(s) {sorted(unknown)}")
    return replace(PRESETS[name], **overrides)
