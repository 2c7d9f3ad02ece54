"""The conditioning a denoiser receives, as a typed dataclass (docs/CONTRACTS.md).

The diffusion code never builds a ``Condition`` (it must not import models); for
classifier-free guidance it calls ``cond.drop_all()`` and, for the batched 2B pass,
``cond.concat(other)``. Both also exist on the encoder output (``EncodedCondition`` in
denoiser.py) so a sampler can treat raw and pre-encoded conditions alike.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor


@dataclass
class Condition:
    scene: Tensor | None = None         # (B, Hy, Hx, Hz) float occupancy, height slices first
    actions: Tensor | None = None       # (B, L, A) float multi-hot per frame
    drop_scene: Tensor | None = None    # (B,) bool: True -> learned null scene embedding
    drop_actions: Tensor | None = None  # (B,) bool: True -> learned null action embedding
    # The facing asked for at the window's last frame, a goal like the pelvis and hand goals
    # (models built with a facing goal, mask.p_facing > 0): (B, 2) float (sin, cos) of its yaw in
    # the window frame, and (B,) bool which samples are given one (others: a learned null).
    facing: Tensor | None = None
    facing_given: Tensor | None = None

    @property
    def batch_size(self) -> int | None:
        for value in (self.scene, self.actions, self.drop_scene, self.drop_actions, self.facing):
            if value is not None:
                return int(value.shape[0])
        return None

    def to(self, device: torch.device | str) -> "Condition":
        move = lambda v: None if v is None else v.to(device)  # noqa: E731
        return Condition(move(self.scene), move(self.actions), move(self.drop_scene),
                         move(self.drop_actions), move(self.facing), move(self.facing_given))

    def drop_all(self) -> "Condition":
        """The unconditional twin used by classifier-free guidance: both conditions dropped. The
        facing goal stays, as the pelvis and hand goals (known entries) stay in both passes."""
        B = self.batch_size
        if B is None:
            return self
        device = next(v for v in (self.scene, self.actions, self.drop_scene, self.drop_actions, self.facing)
                      if v is not None).device
        ones = torch.ones(B, dtype=torch.bool, device=device)
        return replace(self, drop_scene=ones, drop_actions=ones.clone())

    def concat(self, other: "Condition") -> "Condition":
        """Stack two conditions along the batch (None fields must be None in both)."""
        def cat(a: Tensor | None, b: Tensor | None, nb: int | None, na: int | None) -> Tensor | None:
            if a is None and b is None:
                return None
            # A missing drop mask means "not dropped"; materialise it so the halves line up.
            if a is None:
                a = torch.zeros(na, dtype=torch.bool, device=b.device)
            if b is None:
                b = torch.zeros(nb, dtype=torch.bool, device=a.device)
            return torch.cat([a, b], 0)

        pairs = [(self.scene, other.scene), (self.actions, other.actions), (self.facing, other.facing)]
        if any((a is None) != (b is None) for a, b in pairs):
            raise ValueError("Condition.concat: scene/actions/facing present in one condition but not the other")
        na, nb = self.batch_size, other.batch_size
        both = lambda a, b: None if a is None else torch.cat([a, b], 0)  # noqa: E731
        return Condition(
            both(self.scene, other.scene), both(self.actions, other.actions),
            cat(self.drop_scene, other.drop_scene, nb, na),
            cat(self.drop_actions, other.drop_actions, nb, na),
            both(self.facing, other.facing), both(self.facing_given, other.facing_given),
        )


def drop_conditions(cond: Condition, p_scene: float, p_action: float,
                    generator: torch.Generator | None = None) -> Condition:
    """Condition dropout for classifier-free guidance training.

    Scene and action drops are drawn independently (so the model also learns scene-only and
    action-only conditioning); already-set drop flags stay set. Random numbers come from
    ``generator`` (on CPU unless the generator lives elsewhere) for reproducibility.
    """
    B = cond.batch_size
    if B is None:
        return cond
    gen_device = generator.device if generator is not None else torch.device("cpu")
    u = torch.rand(2, B, generator=generator, device=gen_device)  # (2, B)
    device = next(v for v in (cond.scene, cond.actions, cond.drop_scene, cond.drop_actions, cond.facing)
                  if v is not None).device
    drop_s = (u[0] < p_scene).to(device)
    drop_a = (u[1] < p_action).to(device)
    if cond.drop_scene is not None:
        drop_s = drop_s | cond.drop_scene
    if cond.drop_actions is not None:
        drop_a = drop_a | cond.drop_actions
    return replace(cond, drop_scene=drop_s, drop_actions=drop_a)
