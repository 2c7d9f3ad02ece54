"""A denoiser with a closed form, for the loop's tests: the oracle predicts the noise of a clean
window that walks the last pinned pose in a straight line to the pinned goal — what a perfect
model would do — so that the loop's mechanics (frames, pinning, goals, seams, batching, live
control) are tested independently of how well a model trained."""

import types

import numpy as np
import torch
from torch import nn

from motiongen.data.representation import Layout
from motiongen.data.windows import NormStats, WindowConfig
from motiongen.diffusion import DiffusionConfig, GaussianDiffusion, MaskConfig
from motiongen.skeleton import BODY
from tests.helpers import REST

J, L = 22, 16


class Oracle(nn.Module):
    def __init__(self, diffusion, stats):
        super().__init__()
        self.p = nn.Parameter(torch.zeros(1))
        self.diffusion, self.stats = diffusion, stats
        self.scene_encoder = None
        self.conditions = []

    def pinned(self, x_t, known_mask):
        """The window in world units (B, L, J, 3), its known entries, the number k of pinned
        transition frames and the last pinned pose (the rest pose when none)."""
        B = x_t.shape[0]
        x = self.stats.denormalize(x_t.detach().double()).reshape(B, L, J, 3)
        m = known_mask.reshape(B, L, J, 3)
        k = int(m[0, :, 1:].all(-1).all(-1).sum())                    # pinned transition frames
        last = x[:, k - 1] if k else torch.as_tensor(REST, dtype=x.dtype).expand(B, J, 3)
        return x, m, k, last

    def forward(self, x_t, t, cond, known_mask=None):
        B = x_t.shape[0]
        x, m, k, last = self.pinned(x_t, known_mask)
        goal = x[:, -1, 0, [0, 2]]                                     # (B, 2) pinned pelvis x, z
        step = (goal - last[:, 0, [0, 2]]) / (L - max(k, 1))           # per frame
        i = torch.arange(L, dtype=x.dtype) - max(k - 1, 0)             # frames after the last pinned one
        x0 = last[:, None].repeat(1, L, 1, 1)
        x0[..., 0] += (i[None, :, None] * step[:, None, None, 0])
        x0[..., 2] += (i[None, :, None] * step[:, None, None, 1])
        x0 = torch.where(m, x, x0)
        x0n = self.stats.normalize(x0.reshape(B, L, J * 3)).to(x_t.dtype)
        return self.diffusion.eps_from_x0(x_t, x0n, t)


def oracle_loaded(model_cls=None, predict_goal=False):
    # the oracle returns ε; no clipping: world offsets leave [-1, 1]
    diffusion = GaussianDiffusion(DiffusionConfig(clip_x0=1e6, prediction="eps"))
    stats = NormStats(np.zeros(J * 3, np.float32), np.full(J * 3, 2.0, np.float32))
    window = WindowConfig(representation="absolute", contact_joints=())
    return types.SimpleNamespace(model=(model_cls or Oracle)(diffusion, stats).eval(), diffusion=diffusion,
                                 stats=stats, joint_set=BODY, action_names=["walk", "sit"], window=window,
                                 layout=Layout.for_window(window, BODY), predict_goal=predict_goal, fps=30.0,
                                 model_fps=30.0 / window.stride,
                                 mask=MaskConfig(max_transition=2), device=torch.device("cpu"), swing_rise=None)
