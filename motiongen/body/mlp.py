"""The 3-frame joints → SMPL-X parameters MLP (TRUMANS supplement A.2).

Input: joints of frames t-1, t, t+1, made relative to frame t's pelvis and rotated by minus
frame t's facing yaw (`motiongen.geometry`), so the network never has to learn position or
heading. Output for frame t: global orientation in that canonical frame and the 21 body-joint
rotations, all 6D (Zhou et al.), plus optionally β. The first and last frames use a copy of
the middle frame as the missing neighbour.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from motiongen.body.rotations import rot6d_to_matrix
from motiongen.geometry import facing_yaw, yaw_matrix
from motiongen.skeleton import NUM_BODY_JOINTS, PELVIS

NUM_ROT = NUM_BODY_JOINTS  # root + 21 body joints


@dataclass
class MLPConfig:
    width: int = 512
    layers: int = 4           # linear layers, input and output included
    num_betas: int = 10       # 0: do not predict β
    dropout: float = 0.0


def triplets(joints: torch.Tensor) -> torch.Tensor:
    """(..., T, J, 3) -> (..., T, 3, J, 3): frames (t-1, t, t+1), edges padded with frame t."""
    prev = torch.cat([joints[..., :1, :, :], joints[..., :-1, :, :]], -3)
    nxt = torch.cat([joints[..., 1:, :, :], joints[..., -1:, :, :]], -3)
    return torch.stack([prev, joints, nxt], -3)


def canonicalise(trip: torch.Tensor):
    """Triplets (..., 3, J, 3) -> (features (..., 3*J*3), yaw (...,)) of the middle frame."""
    mid = trip[..., 1, :, :]                                   # (..., J, 3)
    yaw = facing_yaw(mid)                                      # (...,)
    R_inv = yaw_matrix(-yaw)                                   # (..., 3, 3)
    rel = trip - mid[..., None, PELVIS:PELVIS + 1, :]          # (..., 3, J, 3)
    local = rel @ R_inv[..., None, :, :].transpose(-1, -2)     # rotate every point by -yaw
    return local.flatten(-3), yaw


class JointsToBodyMLP(nn.Module):
    """features (B, 3*22*3) -> rot6d (B, 22, 6) [canonical root first], betas (B, nβ) | None."""

    def __init__(self, cfg: MLPConfig = MLPConfig()):
        super().__init__()
        self.cfg = cfg
        d_in = 3 * NUM_BODY_JOINTS * 3
        d_out = NUM_ROT * 6 + cfg.num_betas
        dims = [d_in] + [cfg.width] * (cfg.layers - 1) + [d_out]
        mods: list[nn.Module] = []
        for i in range(len(dims) - 1):
            mods.append(nn.Linear(dims[i], dims[i + 1]))
            if i < len(dims) - 2:
                mods += [nn.LayerNorm(dims[i + 1]), nn.GELU()]
                if cfg.dropout:
                    mods.append(nn.Dropout(cfg.dropout))
        self.net = nn.Sequential(*mods)
        # Start at the identity rotation so early training is stable: 6D (1,0,0, 0,1,0).
        with torch.no_grad():
            last = self.net[-1]
            last.weight.mul_(0.01)
            last.bias.zero_()
            last.bias[: NUM_ROT * 6].copy_(torch.tensor([1.0, 0, 0, 0, 1, 0]).repeat(NUM_ROT))

    def forward(self, feats: torch.Tensor):
        out = self.net(feats)
        rot6d = out[..., : NUM_ROT * 6].reshape(out.shape[:-1] + (NUM_ROT, 6))
        betas = out[..., NUM_ROT * 6:] if self.cfg.num_betas else None
        return rot6d, betas

    @torch.no_grad()
    def predict(self, joints: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per-frame parameters of a sequence of joints (T, 22, 3) (any T >= 1).

        Returns rotmats (T, 22, 3, 3) in the world frame (root = global orientation) and
        betas (nβ,) (the per-frame predictions averaged) or None.
        """
        was = self.training
        self.eval()
        p = next(self.parameters())
        joints = joints.to(device=p.device, dtype=p.dtype)
        feats, yaw = canonicalise(triplets(joints))           # (T, 198), (T,)
        rot6d, betas = self(feats)
        R = rot6d_to_matrix(rot6d)                            # (T, 22, 3, 3)
        R = torch.cat([yaw_matrix(yaw)[:, None] @ R[:, :1], R[:, 1:]], 1)
        self.train(was)
        return {"rotmats": R, "betas": betas.mean(0) if betas is not None else None}

    def checkpoint(self, extra: dict | None = None) -> dict:
        return {"kind": "joints_to_body_mlp", "mlp": asdict(self.cfg), "state_dict": self.state_dict(),
                **(extra or {})}

    @classmethod
    def from_checkpoint(cls, ckpt: dict) -> "JointsToBodyMLP":
        m = cls(MLPConfig(**ckpt["mlp"]))
        m.load_state_dict(ckpt["state_dict"])
        return m
