"""Transformer over per-frame multi-hot action labels."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from motiongen.models.layers import Dropout, TransformerStack, sinusoidal_embedding


class ActionEncoder(nn.Module):
    """(B, L, A) -> pooled (B, out_dim) and, with ``per_frame``, (B, L, out_dim).

    Mean pooling over frames as in the reference; the per-frame outputs let the denoiser
    add frame-aligned action information to its frame tokens (the reference's variant).
    """

    def __init__(self, num_actions: int, window: int, width: int, layers: int, heads: int, ff: int,
                 dropout: float, act: str, norm_first: bool, out_dim: int, per_frame: bool,
                 attention_dropout: float = 0.0):
        super().__init__()
        self.per_frame = per_frame
        self.embed = nn.Linear(num_actions, width)
        self.register_buffer("pos", sinusoidal_embedding(torch.arange(window), width), persistent=False)
        self.drop = Dropout(dropout)
        self.blocks = TransformerStack(width, layers, heads, ff, dropout, act, norm_first, attention_dropout)
        self.out = nn.Identity() if width == out_dim else nn.Linear(width, out_dim)
        self.out_frames = nn.Linear(width, out_dim) if per_frame else None

    def forward(self, actions: Tensor) -> tuple[Tensor, Tensor | None]:
        B, L, A = actions.shape
        if L > self.pos.shape[0]:
            raise ValueError(f"action window {L} longer than configured {self.pos.shape[0]}")
        h = self.blocks(self.drop(self.embed(actions) + self.pos[:L]))  # (B, L, W)
        pooled = self.out(h.mean(1))  # (B, out_dim)
        frames = self.out_frames(h) if self.out_frames is not None else None  # (B, L, out_dim)
        return pooled, frames
