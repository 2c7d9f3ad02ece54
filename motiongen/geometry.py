"""Ground-plane frames: yaw, canonicalisation, and local <-> world transforms.

Convention (y-up, metres): a body with yaw θ faces (sin θ, 0, cos θ) in the world; yaw 0
faces +z, as the SMPL-X rest pose does (its left hip is at +x). The local → world map of a
frame with yaw θ at ground position (x, z) is  p_world = R_y(θ) p_local + (x, 0, z).
Functions accept numpy arrays or torch tensors and return the same kind.
"""

from __future__ import annotations

import sys

import numpy as np
from scipy.spatial.transform import Rotation

from motiongen.skeleton import LEFT_HIP, PELVIS, RIGHT_HIP


def _lib(a):
    """The array library of `a`: torch for a tensor, else numpy. torch is looked up, not imported:
    a tensor means it is loaded already, and numpy-only callers (the synthetic generator) need
    not pay its ~2 s import."""
    torch = sys.modules.get("torch")
    return torch if torch is not None and isinstance(a, torch.Tensor) else np


def yaw_matrix(yaw):
    """R_y(yaw): (...,) -> (..., 3, 3), rotation about +y by yaw radians."""
    xp = _lib(yaw)
    c, s = xp.cos(yaw), xp.sin(yaw)
    z, o = xp.zeros_like(c), xp.ones_like(c)
    rows = [xp.stack([c, z, s], -1), xp.stack([z, o, z], -1), xp.stack([-s, z, c], -1)]
    return xp.stack(rows, -2)


def facing_yaw(joints):
    """Yaw (...,) of a body from its hips: forward = (left_hip − right_hip) × up.

    joints: (..., J, 3) with SMPL-X body joint order.
    """
    xp = _lib(joints)
    across = joints[..., LEFT_HIP, :] - joints[..., RIGHT_HIP, :]
    # forward = across × (0,1,0) = (-across_z, 0, across_x)
    return xp.arctan2(-across[..., 2], across[..., 0]) if xp is np else xp.atan2(-across[..., 2], across[..., 0])


def local_to_world(yaw, origin_xz):
    """4x4 transforms (..., 4, 4) of frames with yaw (...,) at ground positions (..., 2)."""
    xp = _lib(yaw)
    R = yaw_matrix(yaw)
    shape = R.shape[:-2]
    if xp is np:
        T = np.zeros(shape + (4, 4), dtype=R.dtype)
    else:
        T = xp.zeros(shape + (4, 4), dtype=R.dtype, device=R.device)
    T[..., :3, :3] = R
    T[..., 0, 3] = origin_xz[..., 0]
    T[..., 2, 3] = origin_xz[..., 1]
    T[..., 3, 3] = 1
    return T


def transform_points(T, p):
    """Apply 4x4 transforms T (..., 4, 4) to points p (..., N, 3) -> (..., N, 3)."""
    R, t = T[..., :3, :3], T[..., :3, 3]
    return p @ R.swapaxes(-1, -2) + t[..., None, :] if _lib(p) is np else p @ R.transpose(-1, -2) + t[..., None, :]


def invert_rigid(T):
    """Inverse of rigid 4x4 transforms (..., 4, 4)."""
    xp = _lib(T)
    R, t = T[..., :3, :3], T[..., :3, 3]
    Rt = R.swapaxes(-1, -2) if xp is np else R.transpose(-1, -2)
    out = xp.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ t[..., None])[..., 0]
    out[..., 3, 3] = 1
    return out


def canonical_frame(joints):
    """The local → world transform (..., 4, 4) that canonicalises a pose: pelvis (x, z) to the
    origin and yaw to 0. joints: (..., J, 3) for one frame."""
    yaw = facing_yaw(joints)
    return local_to_world(yaw, joints[..., PELVIS, :][..., [0, 2]])


def up_rotation(up: str) -> np.ndarray:
    """(3, 3) rotation taking the signed axis `up` ('+z', '-x', '+y', ...) onto +y by a 90 or
    180 degree turn, exact (entries 0, ±1). z-up becomes (x, y, z) -> (x, z, -y)."""
    e = np.zeros(3)
    e["xyz".index(up[1])] = 1.0 if up[0] == "+" else -1.0
    target = np.array([0.0, 1.0, 0.0])
    if np.allclose(e, target):
        return np.eye(3)
    if np.allclose(e, -target):
        return np.diag([1.0, -1.0, -1.0])          # 180 degrees about x
    return np.rint(Rotation.from_rotvec(np.cross(e, target) * np.pi / 2).as_matrix()) + 0.0
