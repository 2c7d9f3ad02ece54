"""Validation loss on fixed val batches, fixed timesteps and noise, so curves are comparable."""

from __future__ import annotations

import torch
from torch.utils.data import DataLoader, Subset

from motiongen.diffusion.masks import loss_mask
from motiongen.loading.build import batch_condition, goal_predicted, known_mask_for_batch, loss_channel_weights


@torch.no_grad()
def validation_loss(model, diffusion, val_set, cfg, tc, device, autocast) -> float:
    g = torch.Generator().manual_seed(12345)
    n = min(len(val_set), tc.val_batches * tc.batch_size)
    idx = torch.randperm(len(val_set), generator=g)[:n].tolist()
    loader = DataLoader(Subset(val_set, idx), batch_size=tc.batch_size, num_workers=0)
    gen = torch.Generator(device=device).manual_seed(54321)
    model.eval()
    predict_goal = goal_predicted(cfg)
    total, count = 0.0, 0
    for batch in loader:
        x0 = batch["motion"].to(device)
        cond = batch_condition(batch, device, tc, gen, train=False)
        mask = known_mask_for_batch(cfg, x0.shape, val_set.layout.num_joints, device, gen)
        t = torch.randint(0, diffusion.num_timesteps, (x0.shape[0],), device=device, generator=gen)
        noise = torch.randn(x0.shape, device=device, generator=gen)
        with autocast:
            losses = diffusion.training_losses(model, x0, t, cond, known=x0, known_mask=mask, noise=noise,
                                               channel_weights=loss_channel_weights(tc, x0.shape[-1], device),
                                               loss_mask=loss_mask(mask, predict_goal))
        total += float(losses["loss"]) * x0.shape[0]
        count += x0.shape[0]
    return total / max(count, 1)
