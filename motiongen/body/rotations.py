"""Rotation representations: axis-angle, 3x3 matrices, unit quaternions and 6D.

All functions are batched over leading dimensions, differentiable, and work on any device.
Matrices act on column vectors (v' = R v). The 6D representation (Zhou et al., "On the
Continuity of Rotation Representations in Neural Networks") is the first two *columns* of R,
concatenated: (..., 6) = (R[:, 0], R[:, 1]). Quaternions are (w, x, y, z).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

# Below this squared angle the closed forms lose precision; Taylor series take over.
_SMALL_SQ = 1e-6


def axis_angle_to_matrix(aa: torch.Tensor) -> torch.Tensor:
    """Rodrigues: (..., 3) -> (..., 3, 3)."""
    theta_sq = (aa * aa).sum(-1, keepdim=True)[..., None]  # (..., 1, 1)
    small = theta_sq < _SMALL_SQ
    # sqrt of a safe value so the unused branch has finite gradients at aa = 0.
    safe_sq = torch.where(small, torch.ones_like(theta_sq), theta_sq)
    theta = torch.sqrt(safe_sq)
    a = torch.where(small, 1 - theta_sq / 6 + theta_sq ** 2 / 120, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta_sq / 24 + theta_sq ** 2 / 720, (1 - torch.cos(theta)) / safe_sq)
    K = skew(aa)
    eye = torch.eye(3, dtype=aa.dtype, device=aa.device).expand(K.shape)
    return eye + a * K + b * (K @ K)


def skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrices: (..., 3) -> (..., 3, 3) with skew(v) u = v x u."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], -1).reshape(v.shape[:-1] + (3, 3))


def matrix_to_quaternion(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 4) unit quaternions (w, x, y, z) with w >= 0.

    Computes all four candidate forms and keeps the best-conditioned one per matrix
    (Shepperd), so it is accurate near 180 degrees where the trace form breaks down.
    """
    m = R.reshape(R.shape[:-2] + (9,))
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m.unbind(-1)
    # 4 * q_i^2 for i in (w, x, y, z); clamped so sqrt stays differentiable.
    q_abs_sq = torch.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22,
                            1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    q_abs = torch.sqrt(torch.clamp(q_abs_sq, min=1e-12))  # (..., 4) = 2|q_i|
    # Row k: the quaternion computed from the k-th largest-component formula, times 2|q_k|.
    cands = torch.stack([
        torch.stack([q_abs[..., 0] ** 2, m21 - m12, m02 - m20, m10 - m01], -1),
        torch.stack([m21 - m12, q_abs[..., 1] ** 2, m10 + m01, m02 + m20], -1),
        torch.stack([m02 - m20, m10 + m01, q_abs[..., 2] ** 2, m12 + m21], -1),
        torch.stack([m10 - m01, m20 + m02, m21 + m12, q_abs[..., 3] ** 2], -1),
    ], -2)  # (..., 4, 4)
    cands = cands / (2 * q_abs[..., None].clamp(min=0.1))
    best = q_abs.argmax(-1)  # (...,)
    q = torch.gather(cands, -2, best[..., None, None].expand(best.shape + (1, 4)))[..., 0, :]
    q = F.normalize(q, dim=-1)
    return torch.where(q[..., :1] < 0, -q, q)


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) (w, x, y, z), any norm -> (..., 3, 3)."""
    w, x, y, z = F.normalize(q, dim=-1).unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(q.shape[:-1] + (3, 3))


def quaternion_to_axis_angle(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) -> (..., 3), angle in [0, pi]."""
    q = torch.where(q[..., :1] < 0, -q, q)
    xyz = q[..., 1:]
    s_sq = (xyz * xyz).sum(-1, keepdim=True)
    small = s_sq < 1e-12
    s = torch.sqrt(torch.where(small, torch.ones_like(s_sq), s_sq))
    angle = 2 * torch.atan2(s, q[..., :1])
    # angle / sin(angle/2) -> 2 as the angle -> 0
    factor = torch.where(small, 2 / q[..., :1].clamp(min=1e-12), angle / s)
    return xyz * factor


def axis_angle_to_quaternion(aa: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 4)."""
    theta_sq = (aa * aa).sum(-1, keepdim=True)
    small = theta_sq < _SMALL_SQ
    theta = torch.sqrt(torch.where(small, torch.ones_like(theta_sq), theta_sq))
    half_sinc = torch.where(small, 0.5 - theta_sq / 48, torch.sin(theta / 2) / theta)
    w = torch.where(small, 1 - theta_sq / 8, torch.cos(theta / 2))
    return torch.cat([w, aa * half_sinc], -1)


def matrix_to_axis_angle(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 3), angle in [0, pi]."""
    return quaternion_to_axis_angle(matrix_to_quaternion(R))


def matrix_to_rot6d(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 6): first column then second column."""
    return torch.cat([R[..., :, 0], R[..., :, 1]], -1)


def rot6d_to_matrix(d6: torch.Tensor) -> torch.Tensor:
    """(..., 6) -> (..., 3, 3) by Gram-Schmidt; inverse of `matrix_to_rot6d` on rotations."""
    a1, a2 = d6[..., :3], d6[..., 3:]
    b1 = F.normalize(a1, dim=-1)
    b2 = F.normalize(a2 - (b1 * a2).sum(-1, keepdim=True) * b1, dim=-1)
    b3 = torch.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], -1)


def axis_angle_to_rot6d(aa: torch.Tensor) -> torch.Tensor:
    return matrix_to_rot6d(axis_angle_to_matrix(aa))


def rot6d_to_axis_angle(d6: torch.Tensor) -> torch.Tensor:
    return matrix_to_axis_angle(rot6d_to_matrix(d6))


def geodesic_angle(R1: torch.Tensor, R2: torch.Tensor) -> torch.Tensor:
    """Angle (...,) in radians of the relative rotation R1^T R2."""
    tr = (R1 * R2).sum((-1, -2))  # trace(R1^T R2)
    return torch.acos(((tr - 1) / 2).clamp(-1 + 1e-7, 1 - 1e-7))
