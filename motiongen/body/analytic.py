"""Analytic pose initialisation from joint positions: *swing correction* down the kinematic
tree (`analytic_init`: each joint rotated by the smallest rotation, Kabsch at the pelvis and
spine3, that points its bones at the target joints, keeping the given twist) and temporal
smoothing of rotations (`smooth_rotations`). Used by the fit, the sampler's body projection
and multi-view fitting."""

from __future__ import annotations

import torch

from motiongen.body.rotations import matrix_to_rot6d, rot6d_to_matrix, skew
from motiongen.skeleton import BODY_PARENTS, NUM_BODY_JOINTS

_CHILDREN = {j: [c for c in range(NUM_BODY_JOINTS) if BODY_PARENTS[c] == j] for j in range(NUM_BODY_JOINTS)}


def _kabsch(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Rotation R (..., 3, 3) minimising Σ‖R a_k − b_k‖² for vectors a, b (..., K, 3)."""
    H = a.transpose(-1, -2) @ b                                   # (..., 3, 3) = Σ a_k b_kᵀ
    U, _, Vh = torch.linalg.svd(H)
    d = torch.sign(torch.det(Vh.transpose(-1, -2) @ U.transpose(-1, -2)))
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    return Vh.transpose(-1, -2) @ D @ U.transpose(-1, -2)


def _min_rotation(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Smallest rotation (..., 3, 3) taking direction a to direction b (..., 3)."""
    a = torch.nn.functional.normalize(a, dim=-1)
    b = torch.nn.functional.normalize(b, dim=-1)
    v = torch.cross(a, b, dim=-1)
    c = (a * b).sum(-1)[..., None, None]
    K = skew(v)
    eye = torch.eye(3, dtype=a.dtype, device=a.device).expand(K.shape)
    R = eye + K + K @ K / (1 + c).clamp(min=1e-6)
    # Opposite directions: the formula divides by ~0; turn half-way round any axis normal to a.
    # (A target can point anywhere: an untrained network's bones do.)
    other = torch.where(a[..., :1].abs() < 0.9, torch.tensor([1.0, 0, 0], dtype=a.dtype, device=a.device),
                        torch.tensor([0, 1.0, 0], dtype=a.dtype, device=a.device))
    n = torch.nn.functional.normalize(torch.cross(a, other, dim=-1), dim=-1)
    half_turn = 2 * n[..., :, None] * n[..., None, :] - eye
    return torch.where(1 + c < 1e-3, half_turn, R)


def analytic_init(joints: torch.Tensor, rest: torch.Tensor, rot_init: torch.Tensor | None = None) -> torch.Tensor:
    """Inverse kinematics by swing correction: joints (T, 22, 3), rest joints (22, 3) (or one
    rest pose per frame, (T, 22, 3)),
    optional local rotations (T, 22, 3, 3) to start from (e.g. the MLP's) -> local rotmats
    (T, 22, 3, 3) whose bone directions match the targets exactly (lengths are the rest ones).

    Going down the tree, each joint's global rotation is rotated by the smallest rotation
    (Kabsch for the pelvis and spine3, which have several children) that points its bones at
    the targets. Twist about a bone is unobservable from its child alone, so it is kept from
    `rot_init` (none without it); leaves keep their initial local rotation.
    """
    T = joints.shape[0]
    eye = torch.eye(3, dtype=joints.dtype, device=joints.device).expand(T, 3, 3)
    G = [None] * NUM_BODY_JOINTS                                   # global rotations (T, 3, 3)
    R = [None] * NUM_BODY_JOINTS
    for j in range(NUM_BODY_JOINTS):
        p = BODY_PARENTS[j]
        Gp = G[p] if p >= 0 else eye
        Gc = Gp @ rot_init[:, j] if rot_init is not None else Gp   # candidate global rotation
        kids = _CHILDREN[j]
        if kids:
            bones = rest[..., kids, :] - rest[..., j:j + 1, :]                         # (K, 3) or (T, K, 3)
            a = bones.expand(T, len(kids), 3) @ Gc.transpose(-1, -2)                # bones (T, K, 3)
            b = joints[:, kids] - joints[:, j:j + 1]                                  # targets (T, K, 3)
            Gc = (_kabsch(a, b) if len(kids) > 1 else _min_rotation(a[:, 0], b[:, 0])) @ Gc
            # Re-orthonormalise: near-opposite directions leave float32 rounding of ~1e-4 in the
            # closed form, which compounds down the chain into stretched bones.
            Gc = rot6d_to_matrix(matrix_to_rot6d(Gc))
        G[j] = Gc
        R[j] = Gp.transpose(-1, -2) @ Gc
    return torch.stack(R, 1)


def smooth_rotations(R: torch.Tensor, sigma: float) -> torch.Tensor:
    """Gaussian smoothing over time of rotations (T, J, 3, 3), in 6D then re-orthonormalised.

    The MLP sees one frame (and two neighbours) at a time, so what joints do not determine
    (leaf-joint and twist rotations) jitters from frame to frame; this removes that before the
    prior anchors refinement to it."""
    T = R.shape[0]
    if sigma <= 0 or T < 3:
        return R
    r = min(int(3 * sigma), T - 1)
    x = torch.arange(-r, r + 1, dtype=R.dtype, device=R.device)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = (k / k.sum())[None, None]                                             # (1, 1, 2r+1)
    d6 = matrix_to_rot6d(R)                                                   # (T, J, 6)
    seq = d6.permute(1, 2, 0).reshape(-1, 1, T)                               # (J*6, 1, T)
    seq = torch.nn.functional.pad(seq, (r, r), mode="replicate")
    out = torch.nn.functional.conv1d(seq, k).reshape(d6.shape[1], 6, T).permute(2, 0, 1)
    return rot6d_to_matrix(out)
