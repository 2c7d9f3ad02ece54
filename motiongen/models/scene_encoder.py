"""ViT over the local occupancy grid.

The grid (B, Hy, Hx, Hz) is read as an image whose channels are the Hy height slices and
whose pixels are the ground plane (x, z); patches tile the ground plane (patch 8 on a 32x32
plane -> 16 patches of 32*8*8 = 2048 values each).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from motiongen.errors import ConfigError
from motiongen.models.layers import Dropout, TransformerStack


class SceneEncoder(nn.Module):
    def __init__(self, scene_res: tuple[int, int, int], patch: int, width: int, layers: int,
                 heads: int, ff: int, dropout: float, act: str, norm_first: bool, pool: str,
                 out_dim: int, attention_dropout: float = 0.0):
        super().__init__()
        Hy, Hx, Hz = scene_res
        if Hx % patch or Hz % patch:
            raise ConfigError(f"scene encoder: ground-plane size {Hx}x{Hz} is not divisible by patch {patch}")
        if pool not in ("cls", "mean"):
            raise ConfigError(f"scene encoder pool: expected 'cls' or 'mean', got {pool!r}")
        self.scene_res = (Hy, Hx, Hz)
        self.patch = patch
        self.pool = pool
        num_patches = (Hx // patch) * (Hz // patch)
        self.patch_embed = nn.Linear(Hy * patch * patch, width)
        self.cls = nn.Parameter(torch.randn(1, 1, width) * 0.02) if pool == "cls" else None
        self.pos = nn.Parameter(torch.randn(1, num_patches + (pool == "cls"), width) * 0.02)
        self.drop = Dropout(dropout)
        self.blocks = TransformerStack(width, layers, heads, ff, dropout, act, norm_first, attention_dropout)
        self.head = nn.Sequential(nn.LayerNorm(width), nn.Linear(width, out_dim))

    def forward(self, occ: Tensor) -> Tensor:  # (B, Hy, Hx, Hz) -> (B, out_dim)
        B, Hy, Hx, Hz = occ.shape
        if (Hy, Hx, Hz) != self.scene_res:
            raise ValueError(f"scene grid {(Hy, Hx, Hz)} != configured {self.scene_res}")
        p = self.patch
        patches = (occ.reshape(B, Hy, Hx // p, p, Hz // p, p)
                   .permute(0, 2, 4, 1, 3, 5)
                   .reshape(B, (Hx // p) * (Hz // p), Hy * p * p))  # (B, N, Hy*p*p)
        h = self.patch_embed(patches)  # (B, N, W)
        if self.cls is not None:
            h = torch.cat([self.cls.expand(B, -1, -1), h], 1)  # (B, N+1, W)
        h = self.blocks(self.drop(h + self.pos))
        pooled = h[:, 0] if self.pool == "cls" else h.mean(1)  # (B, W)
        return self.head(pooled)
