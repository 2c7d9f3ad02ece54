"""The foot-contact velocity term of LEMO (its supplement, Eq. 14), for `fit.refine`.

    E_foot = Σ_{k,t : z_k^t ≤ z_thres} d(v_k^t, a),   d(v, a) = v − a if v ≥ a else 0

v_k^t is the speed (m/s, all three axes) of foot joint k at frame t, z_k^t its height above
the floor; LEMO sets z_thres = 10 cm and a = 10 cm/s. LEMO's heuristic selects the
frames by height; its learned variant (and ours with `mask="contact"`) by contact labels —
from force sensors (`motiongen.capture.sensor_contact`) or annotation.

Choices here: v_k^t is the forward difference ‖J_{t+1} − J_t‖·fps (frames 0..T−2); the sum is
divided by (T−1)·K, so the weight does not grow with the clip's length (like every other term
of the refinement, which are means over frames); the height mask is taken from the *target*
joints, which the fit follows closely, so the set of penalised frames stays fixed while L-BFGS
searches along a line. `fit.fit_joints` adds the term in a second refinement pass, started
from the joint fit (the hinge is a poor start for L-BFGS from the initialisation).
"""

from __future__ import annotations

import torch

from motiongen.errors import ConfigError

MASKS = ("height", "contact")


def check_mask(mask: str, contact: torch.Tensor | None, T: int, K: int) -> None:
    """The term's frame selection: "height", or "contact" with flags (T, K) for the K foot joints."""
    if mask not in MASKS:
        raise ConfigError(f"foot velocity mask: expected one of {', '.join(MASKS)}, got {mask!r}")
    if mask == "contact" and (contact is None or tuple(contact.shape) != (T, K)):
        raise ConfigError(f"the foot velocity term with mask 'contact' needs contact flags of shape ({T}, {K}), "
                          f"got {None if contact is None else tuple(contact.shape)}")


def foot_velocity_mask(target: torch.Tensor, joints, floor_y: float, z_thres: float) -> torch.Tensor:
    """(T, K) bool: foot joint `joints[k]` of target (T, J, 3) within z_thres of the floor (y up)."""
    return target[:, list(joints), 1] - floor_y <= z_thres


def foot_velocity_loss(J: torch.Tensor, mask: torch.Tensor, joints, fps: float, a: float) -> torch.Tensor:
    """Σ over masked (frame t, foot joint k) of max(0, ‖J_{t+1,k} − J_{t,k}‖·fps − a), divided by
    (T−1)·K. J (T, J, 3) metres; mask (T, K) bool (only frames 0..T−2 are used); a in m/s."""
    P = J[:, list(joints)]                                                     # (T, K, 3)
    if P.shape[0] < 2:
        return P.sum() * 0
    step = P[1:] - P[:-1]                                                      # (T-1, K, 3)
    # sqrt has an infinite slope at 0; a still foot is below `a` and contributes nothing anyway.
    speed = (step.square().sum(-1) + 1e-12).sqrt() * fps                        # (T-1, K) m/s
    excess = (speed - a).clamp(min=0) * mask[:-1].to(J.dtype)
    return excess.sum() / excess.numel()
