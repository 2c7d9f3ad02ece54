"""Known-entry masks for inpainting conditioning.

Channel layout (motiongen.data.representation): joint j occupies channels 3j..3j+2 as
(x, y, z); the pelvis is joint 0 (channels 0, 1, 2); D may exceed 3J (stance channels follow
the pose). Transition frames pin every channel; goal entries address pelvis/hand channels. The same builder (``known_mask``) makes sampling-time masks and,
through ``sample_known_mask``, the random training masks, so the model trains on exactly the
patterns it will be asked to complete.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from motiongen.errors import ConfigError


@dataclass
class MaskConfig:
    p_transition: float = 0.9   # probability that a window has pinned transition frames
    max_transition: int = 2     # k ~ U{1..max} when it does (reference: 2)
    p_goal_xz: float = 0.9      # probability of pinning the last-frame pelvis x, z
    p_goal_y: float = 0.5       # probability of also giving pelvis y (given goal x, z): a seat's height
    p_hand: float = 0.0         # probability of pinning a hand joint (all of x, y, z) at the last frame
    hand_joint: int = 21        # SMPL-X right wrist
    # The joints a window's hand goal is drawn from, uniformly per window (e.g. [20, 21]: either
    # wrist, as the sampler gives the hand that reaches for an object); empty: `hand_joint`.
    hand_joints: tuple = ()
    # A hand goal, with this probability, for windows whose last frame carries one of
    # `hand_actions` (the sampler gives one for those actions: `LoopConfig.hand_goal`), on the
    # wrist that moved most relative to the pelvis over the window (the hand that reaches).
    # Random hand goals alone (`p_hand`) mostly fall where a hanging hand would be anyway, and
    # the network learns to ignore them.
    p_hand_action: float = 0.0
    hand_actions: tuple = ("pick up",)
    goal_joint: int = 0         # pelvis
    # Probability that a window is given its last frame's facing (a yaw, not a known entry:
    # `Condition.facing`); > 0 builds the model with that input. The sampler gives it in the
    # episodes of a hand action: facing the object (`LoopConfig.facing_goal`).
    p_facing: float = 0.0
    # True: goal entries condition the model and are part of its loss, and samplers keep the
    # model's own prediction there (only transition frames are written into the result), so
    # the goal distance measures the model. False: goals are pinned like transitions (reference).
    predict_goal: bool = True

    @property
    def hand_goals(self) -> bool:
        """Whether a model trained with this config takes a hand goal (`LoopConfig.hand_goal`)."""
        return self.p_hand > 0 or self.p_hand_action > 0

    @property
    def goal_hands(self) -> tuple[int, ...]:
        """The joints a hand goal may go to: `hand_joints`, else `hand_joint`."""
        return tuple(self.hand_joints) or (self.hand_joint,)


def known_mask(batch: int, window: int, num_joints: int, transition: int | Tensor = 0,
               goal_xz: bool | Tensor = False, goal_y: bool | Tensor = False,
               hand: bool | Tensor = False, hand_joint: int | Tensor = 21, goal_joint: int = 0,
               device: torch.device | str = "cpu", channels: int | None = None) -> Tensor:
    """(B, L, D) bool, D = `channels` (default 3J). Scalars apply to the whole batch; (B,) tensors per sample.

    transition k: first k frames, all channels. goal_xz / goal_y: last frame, ``goal_joint``
    x, z / y. hand: last frame, ``hand_joint`` x, y, z (one joint, or (B,) one per sample).
    """
    B, L, J = batch, window, num_joints
    hand_j = torch.as_tensor(hand_joint, device=device).to(torch.long).expand(B)              # (B,)
    has_hand = torch.as_tensor(hand, device=device).to(torch.bool).expand(B)                  # (B,)
    used = [goal_joint] + [int(j) for j in hand_j[has_hand].unique()]
    for j in used:
        if not 0 <= j < J:
            raise ConfigError(f"mask joint {j} outside 0..{J - 1}")
    as_b = lambda v, dt: torch.as_tensor(v, device=device).to(dt).expand(B)  # noqa: E731
    k = as_b(transition, torch.long)
    if bool((k > L).any()) or bool((k < 0).any()):
        raise ConfigError(f"transition frames must be in 0..{L}")
    frames = torch.arange(L, device=device)
    D = 3 * J if channels is None else int(channels)
    mask = (frames[None, :] < k[:, None])[:, :, None].expand(B, L, D).clone()  # (B, L, D)
    g = 3 * goal_joint
    mask[:, -1, g + 0] |= as_b(goal_xz, torch.bool)
    mask[:, -1, g + 2] |= as_b(goal_xz, torch.bool)
    mask[:, -1, g + 1] |= as_b(goal_y, torch.bool)
    rows = torch.nonzero(has_hand)[:, 0]                                                     # samples with a hand goal
    for c in range(3):
        mask[rows, -1, 3 * hand_j[rows] + c] = True
    return mask


def sample_known_mask(batch: int, window: int, num_joints: int, cfg: MaskConfig | None = None,
                      generator: torch.Generator | None = None,
                      device: torch.device | str = "cpu", channels: int | None = None,
                      action_hand: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """Random training masks (B, L, D) bool drawn per sample from ``cfg``. action_hand: (acting
    (B,) bool, wrist (B,) long) the windows that end in a hand action and their reaching wrist
    (`cfg.p_hand_action`)."""
    cfg = cfg if cfg is not None else MaskConfig()
    if cfg.max_transition >= window:
        raise ConfigError(f"mask.max_transition {cfg.max_transition} must be < window {window}")
    gen_device = generator.device if generator is not None else "cpu"
    u = torch.rand(4, batch, generator=generator, device=gen_device)  # (4, B)
    k = torch.randint(1, cfg.max_transition + 1, (batch,), generator=generator, device=gen_device) \
        if cfg.max_transition > 0 else torch.zeros(batch, dtype=torch.long, device=gen_device)
    k = torch.where(u[0] < cfg.p_transition, k, torch.zeros_like(k))
    goal_xz = u[1] < cfg.p_goal_xz
    goal_y = goal_xz & (u[2] < cfg.p_goal_y)
    hand = u[3] < cfg.p_hand
    hand_joint = torch.full((batch,), cfg.hand_joint, device=gen_device)                    # (B,)
    if len(cfg.hand_joints) > 0:
        # drawn only here: configs without a choice of hands keep the generator's sequence
        pick = torch.randint(0, len(cfg.hand_joints), (batch,), generator=generator, device=gen_device)
        hand_joint = torch.as_tensor(list(cfg.hand_joints), device=gen_device)[pick]
    if cfg.p_hand_action > 0 and action_hand is not None:
        acting, wrist = (a.to(gen_device) for a in action_hand)
        given = acting & (torch.rand(batch, generator=generator, device=gen_device) < cfg.p_hand_action)
        hand, hand_joint = hand | given, torch.where(given, wrist, hand_joint)
    return known_mask(batch, window, num_joints, k.to(device), goal_xz.to(device), goal_y.to(device),
                      hand.to(device), hand_joint.to(device), cfg.goal_joint, device, channels)


def transition_mask(mask: Tensor) -> Tensor:
    """(B, L, D) bool: the entries of whole pinned frames (transitions). These are the past:
    samplers write them into the result. Other known entries (goals) only condition the model,
    which predicts them like any free entry."""
    return mask.all(-1, keepdim=True).expand_as(mask)


def predicts_goal(cfg: MaskConfig | None, prediction: str) -> bool:
    """Goals are predicted only by x0-predicting models: an ε or v target at an entry whose
    input is clean carries no information (the noise never reached it)."""
    return (cfg if cfg is not None else MaskConfig()).predict_goal and prediction == "x0"


def loss_mask(mask: Tensor, predict_goal: bool) -> Tensor:
    """(B, L, D) bool: entries the training loss covers for known-entry mask `mask`: all but the
    transition frames when goals are predicted, else all free entries."""
    return ~transition_mask(mask) if predict_goal else ~mask


def replace_mask(mask: Tensor, predict_goal: bool) -> Tensor:
    """(B, L, D) bool: entries a sampler writes into its result (the complement of what the
    model is trained to predict there)."""
    return transition_mask(mask) if predict_goal else mask
