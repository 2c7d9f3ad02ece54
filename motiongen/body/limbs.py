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

from motiongen.geometry import facing_yaw
from motiongen.skeleton import BODY_JOINT_NAMES

_I = BODY_JOINT_NAMES.index
# (root, middle, end, leaf after the end or -1): legs then arms.
LIMBS = tuple((_I(f"{s}_{a}"), _I(f"{s}_{b}"), _I(f"{s}_{c}"), _I(f"{s}_{d}") if d else -1)
              for a, b, c, d in (("hip", "knee", "ankle", "foot"), ("shoulder", "elbow", "wrist", None))
              for s in ("left", "right"))


def two_bone(root: Tensor, target: Tensor, pole: Tensor, upper: Tensor, lower: Tensor,
             soft: float = 0.0) -> tuple[Tensor, Tensor]:
    """Middle and end joints (..., 3) of a two-bone chain from `root` towards `target`, bending
    towards `pole` (the predicted middle joint), bone lengths upper, lower (...,). Unreachable
    targets are approached along the line to them (stretched out, or folded in).

    soft > 0 (m): soft IK. Within `soft` of full reach the end falls short of the target by an
    exponentially growing margin, so the chain never snaps straight: at full reach the middle
    joint's distance from the line grows like the square root of the slack, and a target that
    comes back within reach bends it from straight in a frame."""
    d_vec = target - root
    d_len = d_vec.norm(dim=-1).clamp(min=1e-9)
    u = d_vec / d_len[..., None]
    if soft > 0:
        start = upper + lower - soft
        d_len = torch.where(d_len > start, start + soft * (1 - torch.exp(-(d_len - start) / soft)), d_len)
    d = d_len.clamp(min=(upper - lower).abs() + 1e-4, max=upper + lower - 1e-4)
    x = (upper ** 2 - lower ** 2 + d ** 2) / (2 * d)                                      # along u to the bend
    h = (upper ** 2 - x ** 2).clamp(min=0).sqrt()                                          # off the line
    p = pole - root
    v = p - (p * u).sum(-1, keepdim=True) * u
    v_len = v.norm(dim=-1, keepdim=True)
    if not bool((v_len > 1e-6).all()):
        # A straight prediction gives no bending plane: any normal will do, the bend is ~0 there.
        fallback = torch.cross(u, torch.tensor([1.0, 0.0, 0.0], dtype=u.dtype).expand_as(u), dim=-1)
        fallback2 = torch.cross(u, torch.tensor([0.0, 0.0, 1.0], dtype=u.dtype).expand_as(u), dim=-1)
        fallback = torch.where(fallback.norm(dim=-1, keepdim=True) > 1e-3, fallback, fallback2)
        v = torch.where(v_len > 1e-6, v, fallback)
        v_len = v.norm(dim=-1, keepdim=True)
    v = v / v_len.clamp(min=1e-9)
    middle = root + x[..., None] * u + h[..., None] * v
    return middle, root + d[..., None] * u


def place_limbs(P: Tensor, X: Tensor, rest: Tensor, bend: Tensor | None = None, soft: float = 0.0) -> Tensor:
    """P (..., 22, 3) a rigid pose whose trunk is right, X (..., 22, 3) the prediction, rest
    (..., 22, 3) the body's rest joints -> P with every limb re-placed by two-bone IK so the
    ankles/wrists sit at the predicted positions; the toe keeps its predicted direction from
    the ankle, at the body's foot length. Bone lengths stay the body's.

    bend (..., 22, 3) or None: joints whose limbs give the bending direction (the knee's or
    elbow's offset from its own hip-ankle or shoulder-wrist line). None: the knee or elbow of X
    itself is the pole. Pass the rigid pose X came from when X's ends were moved without its
    middles (a locked foot): X's own knee may then lie almost on the new hip-ankle line, and
    its side of that line flips from frame to frame. soft: `two_bone`'s soft reach (m) for the
    legs (a foot a little short of a locked spot, not a knee snapping straight); the arms reach
    exactly (a hand goes on an object)."""
    P = P.clone()
    for r, m, e, leaf in LIMBS:
        upper, lower = (b.expand(P.shape[:-2]) for b in _bones(rest, r, m, e))
        pole = X[..., m, :] if bend is None else P[..., r, :] + _bend_direction(bend, r, m, e)
        leg = leaf >= 0
        P[..., m, :], P[..., e, :] = two_bone(P[..., r, :], X[..., e, :], pole, upper, lower, soft if leg else 0.0)
        if leaf >= 0:
            P[..., leaf, :] = _toe(P[..., e, :], X[..., leaf, :] - X[..., e, :],
                                   (rest[..., leaf, :] - rest[..., e, :]).norm(dim=-1))
    return P


# A limb's own bend counts from here; a straighter one bends the way such limbs do (knees
# forward, elbows back): a straight prediction gives no plane, and the side of its line a nearly
# straight (or slightly over-straightened) one falls on flips from frame to frame.
BEND_PRIOR = 0.02        # m


def _bones(rest: Tensor, r: int, m: int, e: int) -> tuple[Tensor, Tensor]:
    """A limb's upper and lower bone lengths (...,) in rest joints (..., 22, 3)."""
    return (rest[..., m, :] - rest[..., r, :]).norm(dim=-1), (rest[..., e, :] - rest[..., m, :]).norm(dim=-1)


def limb_lengths(rest: Tensor) -> Tensor:
    """(..., 4) each limb's full reach, upper plus lower bone, in `LIMBS` order, of rest joints (..., 22, 3)."""
    return torch.stack([sum(_bones(rest, r, m, e)) for r, m, e, _ in LIMBS], -1)


def _bend_direction(bend: Tensor, r: int, m: int, e: int) -> Tensor:
    """The middle joint's offset (..., 3) from the root-end line of its own chain in `bend`
    (..., 22, 3), less any part of it the wrong way, plus BEND_PRIOR the way the limb bends
    (the body's forward for a knee, its back for an elbow; `geometry.facing_yaw`)."""
    root, middle, end = bend[..., r, :], bend[..., m, :], bend[..., e, :]
    line = end - root
    u = line / line.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    p = middle - root
    own = p - (p * u).sum(-1, keepdim=True) * u
    leg = r in (_I("left_hip"), _I("right_hip"))
    yaw = facing_yaw(bend)                                                     # the body's forward
    way = torch.stack([torch.sin(yaw), torch.zeros_like(yaw), torch.cos(yaw)], -1) * (1.0 if leg else -1.0)
    against = (own * way).sum(-1, keepdim=True).clamp(max=0)                   # bent the wrong way
    return own - against * way + BEND_PRIOR * way


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
