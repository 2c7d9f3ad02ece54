"""One episode's denoising: the diffusion sampler run on the network's inputs, the result
denormalised, decoded (`motiongen.data.representation`) and mapped back to the world."""

from __future__ import annotations

import numpy as np
import torch

from motiongen.diffusion.masks import replace_mask
from motiongen.diffusion.samplers import sample
from motiongen.geometry import transform_points
from motiongen.sampling.conditioning import NetworkInputs
from motiongen.sampling.episode import LoopSpec


def denoise(spec: LoopSpec, loaded, inputs: NetworkInputs) -> tuple[np.ndarray, np.ndarray]:
    """(raw (S, L, J, 3) float64 world joints as the network predicts them, stance (S, L, C) bool).
    Only the pinned frames are written into the result; the goal entries too when the
    checkpoint does not predict them (`spec.predict_goal`)."""
    st, s = spec, spec.sampler
    x0 = sample(loaded.diffusion, loaded.model, (st.samples, st.length, st.channels), inputs.cond,
                known=torch.from_numpy(inputs.known).to(st.device), known_mask=inputs.mask,
                replace_mask=replace_mask(inputs.mask, st.predict_goal), sampler=s.sampler, steps=s.steps,
                eta=s.eta, guidance_scale=s.guidance_scale, generator=st.generator)
    local, stance = loaded.layout.decode(loaded.stats.denormalize(x0.float().cpu().numpy()).astype(np.float64))
    return transform_points(inputs.to_world[:, None], local), stance
