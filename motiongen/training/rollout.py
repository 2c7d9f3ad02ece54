"""Training on the network's own transition frames (`train.rollout_p`).

In the sampler's loop every window after the first starts from the last k frames of the window
before, as the network made them; in training they are the data's. Here a share of the
training windows gets its transition frames the way the loop makes them: the EMA network
samples the window that starts L - k frames earlier (its own first k frames and its goal from
the data, a few DDIM steps), and its frames that fall on this window's first k become the given
frames, moved rigidly onto the data's first pose (position and heading, as the loop
canonicalises every window at its first transition frame). The target stays the data's
continuation, so the network learns to go on from its own frames to the data's gait: the
scheduled training of DART (Zhao et al. 2024), without its latent space.

Built to test whether the network glides in the loop because it continues its own frames;
measured, it changes nothing on the demo or the quality size, and chained on its own frames
the network lifts its feet as on the data's (docs/results.md, "The network does not start where
its pinned frames end"). Off by default.
"""

from __future__ import annotations

import torch
from torch import Tensor

from motiongen.data.representation import Layout
from motiongen.data.windows import NormStats, canonicalize
from motiongen.diffusion.masks import transition_mask
from motiongen.loading.build import sample_windows


@torch.no_grad()
def own_transitions(model, diffusion, batch: dict, x0: Tensor, known_mask: Tensor, offset: int, layout: Layout,
                    stats: NormStats, cfg, p: float, steps: int, generator: torch.Generator) -> tuple[Tensor, int]:
    """x0 (B, L, D) normalised clean windows with the pinned transition frames of known_mask
    (B, L, D) replaced, in a share p of the windows that have them and a previous window
    (`batch["has_prev"]`, starting `offset` frames earlier), by the network's own (`model`, in
    eval mode). Returns the windows (a new tensor, or x0 itself when none is drawn) and how
    many were changed."""
    device = x0.device
    pinned = transition_mask(known_mask)[:, :, 0]                                   # (B, L) bool
    u = torch.rand(x0.shape[0], generator=generator, device=generator.device).to(device)
    rows = (batch["has_prev"].to(device) & pinned[:, 0] & (u < p)).nonzero()[:, 0]   # (n,)
    if len(rows) == 0:
        return x0, 0
    pick = rows.cpu()
    prev = {key: batch[f"prev_{key}"][pick] for key in ("motion", "actions", "scene") if f"prev_{key}" in batch}
    sampled = sample_windows(model, diffusion, prev, cfg, device, generator, steps).float()   # (n, L, D)
    joints, stance = layout.decode(stats.denormalize(sampled))                    # (n, L, J, 3), (n, L, C)
    # Frame offset + j of the previous window falls on this window's frame j; the loop
    # canonicalises at frame 0, which no rigid turn about the vertical changes: no need to go
    # through the world frame.
    n_own = x0.shape[1] - offset
    own, _ = canonicalize(joints[:, offset:].double())                            # (n, L - offset, J, 3)
    feats = stats.normalize(layout.encode(own, stance[:, offset:]).to(x0.dtype))  # (n, L - offset, D)
    out = x0.clone()
    keep = pinned[rows, :n_own, None]                                              # (n, L - offset, 1)
    out[rows, :n_own] = torch.where(keep, feats, x0[rows, :n_own])
    return out, len(rows)
