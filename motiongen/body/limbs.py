"""Two-bone inverse kinematics for the limbs: put a body's ankles and wrists where a prediction
put them, with the body's own bone lengths.

Following bone directions down the tree (`fit.analytic_init`) keeps every bone's direction but
lets length errors of a predicted skeleton add up towards the end of each chain: a network
whose legs are 5 % too long gets feet 4 cm in the air. The ends of the limbs are what touches
the world (feet on the floor, hands on objects), so they are kept instead: the hip and
shoulder come from the trunk, the ankle and wrist go to the predicted positions (as far as
the limb reaches), the knee and elbow bend in the plane the prediction bends them in.
"""

from __future__ import annotations

import torch
from torch import Tensor

from motiongen.skeleton import BODY_JOINT_NAMES

_I = BODY_JOINT_NAMES.index
# (root, middle, end, leaf after the end or -1): legs then arms.
LIMBS = tuple((_I(f"{s}_{a}"), _I(f"{s}_{b}"), _I(f"{s}_{c}"), _I(f"{s}_{d}") if d else -1)
              for a, b, c, d in (("hip", "knee", "ankle", "foot"), ("shoulder", "elbow", "wrist", None))
              for s in ("left", "right"))


def two_bone(root: Tensor, target: Tensor, pole: Tensor, upper: Tensor, lower: Tensor) -> tuple[Tensor, Tensor]:
    """Middle and end joints (..., 3) of a two-bone chain from `root` towards `target`, bending
    towards `pole` (the predicted middle joint), bone lengths upper, lower (...,). Unreachable
    targets are approached along the line to them (stretched out, or folded in)."""
    d_vec = target - root
    d_len = d_vec.norm(dim=-1).clamp(min=1e-9)
    u = d_vec / d_len[..., None]
    d = d_len.clamp(min=(upper - lower).abs() + 1e-4, max=upper + lower - 1e-4)
    x = (upper ** 2 - lower ** 2 + d ** 2) / (2 * d)                                      # along u to the bend
    h = (upper ** 2 - x ** 2).clamp(min=0).sqrt()                                          # off the line
    p = pole - root
    v = p - (p * u).sum(-1, keepdim=True) * u
    # A straight prediction gives no bending plane: any normal will do, the bend is ~0 there.
    fallback = torch.cross(u, torch.tensor([1.0, 0.0, 0.0], dtype=u.dtype).expand_as(u), dim=-1)
    fallback2 = torch.cross(u, torch.tensor([0.0, 0.0, 1.0], dtype=u.dtype).expand_as(u), dim=-1)
    fallback = torch.where(fallback.norm(dim=-1, keepdim=True) > 1e-3, fallback, fallback2)
    v = torch.where(v.norm(dim=-1, keepdim=True) > 1e-6, v, fallback)
    v = v / v.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    middle = root + x[..., None] * u + h[..., None] * v
    return middle, root + d[..., None] * u


def place_limbs(P: Tensor, X: Tensor, rest: Tensor) -> Tensor:
    """P (..., 22, 3) a rigid pose whose trunk is right, X (..., 22, 3) the prediction, rest
    (..., 22, 3) the body's rest joints -> P with every limb re-placed by two-bone IK so the
    ankles/wrists sit at the predicted positions; the toe keeps its predicted direction from
    the ankle, at the body's foot length. Bone lengths stay the body's."""
    P = P.clone()
    for r, m, e, leaf in LIMBS:
        upper = (rest[..., m, :] - rest[..., r, :]).norm(dim=-1).expand(P.shape[:-2])
        lower = (rest[..., e, :] - rest[..., m, :]).norm(dim=-1).expand(P.shape[:-2])
        P[..., m, :], P[..., e, :] = two_bone(P[..., r, :], X[..., e, :], X[..., m, :], upper, lower)
        if leaf >= 0:
            P[..., leaf, :] = _toe(P[..., e, :], X[..., leaf, :] - X[..., e, :],
                                   (rest[..., leaf, :] - rest[..., e, :]).norm(dim=-1))
    return P


def _toe(ankle: Tensor, d: Tensor, length: Tensor) -> Tensor:
    """The toe (..., 3) at `length` from the ankle, as high above or below it as predicted (d,
    ankle to toe, (..., 3); y is up) and pointing where the prediction points on the ground:
    the height is what puts a foot flat on the floor, so it is what a foot shorter or longer
    than the body's must not change (scaling d instead would sink a long toe into the floor)."""
    length = length.expand(d.shape[:-1])
    dy = d[..., 1].clamp(min=-0.95 * length, max=0.95 * length)
    flat = d.clone()
    flat[..., 1] = 0
    n = flat.norm(dim=-1, keepdim=True)
    flat = torch.where(n > 1e-6, flat / n.clamp(min=1e-9), torch.tensor([0.0, 0.0, 1.0], dtype=d.dtype).expand_as(d))
    out = ankle + flat * (length ** 2 - dy ** 2).sqrt()[..., None]
    out[..., 1] = ankle[..., 1] + dy
    return out
