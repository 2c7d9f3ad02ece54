"""What the denoiser sees of a window: the channel layout of its feature vector.

Two pose representations (`WindowConfig.representation`):

* ``absolute`` (default) — the public TRUMANS code: D = 3J, joint j at channels 3j..3j+2,
  every joint in the window frame. Pinning the pelvis would move one joint and leave the body
  behind, which is why goals are predicted rather than pinned (`MaskConfig.predict_goal`).
* ``root`` — the pelvis (joint 0) in the window frame at channels 0..2, every other joint
  *relative to the pelvis* (same axes) at 3j..3j+2. The pelvis channels mean the same in
  both, so goals and masks address them identically; a pelvis the sampler moves carries the
  whole body with it. Measured worse at goals and feet than ``absolute`` (docs/models.md).

Optionally C *stance* channels follow the pose (`contact_joints`, default the two ankles and
the two toes): +1 when the joint is planted — in contact by the dataset's label and moving
slower than `stance_speed` — and −1 otherwise. The sampler reads them back (> 0) to lock planted
feet on the body (`motiongen.body.solve`). They are excluded from min–max statistics (fixed
centre 0, half-range 1): a label is not a measurement.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from motiongen.errors import ConfigError
from motiongen.skeleton import JointSet

REPRESENTATIONS = ("absolute", "root")
DEFAULT_CONTACT_JOINTS = ("left_ankle", "left_foot", "right_ankle", "right_foot")   # = skeleton.FOOT_JOINTS


@dataclass(frozen=True)
class Layout:
    num_joints: int
    representation: str = "absolute"
    contact_joints: tuple[int, ...] = ()          # joint index of each stance channel

    def __post_init__(self):
        if self.representation not in REPRESENTATIONS:
            raise ConfigError(f"window.representation: expected one of {REPRESENTATIONS}, got {self.representation!r}")

    @classmethod
    def for_window(cls, window, joint_set: JointSet) -> "Layout":
        """The layout of a `WindowConfig` (names of contact joints resolved in `joint_set`)."""
        names = tuple(getattr(window, "contact_joints", ()) or ())
        unknown = [n for n in names if n not in joint_set.names]
        if unknown:
            raise ConfigError(f"window.contact_joints: {unknown} not in the joint set ({joint_set.name})")
        return cls(joint_set.num_joints, getattr(window, "representation", "absolute"),
                   tuple(joint_set.index(n) for n in names))

    @property
    def pose_channels(self) -> int:
        return 3 * self.num_joints

    @property
    def num_contacts(self) -> int:
        return len(self.contact_joints)

    @property
    def channels(self) -> int:
        """D: pose channels then stance channels."""
        return self.pose_channels + self.num_contacts

    def encode(self, joints, stance=None):
        """joints (..., L, J, 3) window-frame positions, stance (..., L, C) bool -> (..., L, D)."""
        xp = torch if isinstance(joints, torch.Tensor) else np
        j = joints
        if self.representation == "root":
            rel = j - j[..., :1, :]
            j = xp.concatenate([j[..., :1, :], rel[..., 1:, :]], -2)
        pose = j.reshape(*j.shape[:-2], self.pose_channels)                             # (..., L, 3J)
        if not self.num_contacts:
            return pose.clone() if xp is torch else pose.copy()                         # never a view of the input
        if stance is None:
            raise ValueError("encode: this layout has stance channels; pass stance (..., L, C)")
        s = stance.to(pose.dtype) if xp is torch else np.asarray(stance).astype(pose.dtype)
        return xp.concatenate([pose, 2 * s - 1], -1)

    def decode(self, x):
        """(..., L, D) -> joints (..., L, J, 3) in the window frame, stance (..., L, C) bool."""
        xp = torch if isinstance(x, torch.Tensor) else np
        j = x[..., : self.pose_channels].reshape(*x.shape[:-1], self.num_joints, 3)
        if self.representation == "root":
            j = xp.concatenate([j[..., :1, :], j[..., 1:, :] + j[..., :1, :]], -2)
        return j, x[..., self.pose_channels:] > 0

    def fixed_stats(self) -> tuple[np.ndarray, np.ndarray]:
        """(centre, half-range) of the stance channels: labels in {-1, +1} stay as they are."""
        C = self.num_contacts
        return np.zeros(C, np.float32), np.ones(C, np.float32)


def stance_labels(joints: np.ndarray, contact: np.ndarray, contact_joints, fps: float,
                  stance_speed: float = 0.2) -> np.ndarray:
    """(T, C) bool: joint in contact (dataset label) and slower than `stance_speed` m/s.

    joints (T, J, 3) of one sequence at `fps`, contact (T, J) bool. Contact labels mark a foot
    near a surface, which includes the low part of a swing; locking needs the foot to be still
    as well, so the speed (central differences) gates the label.
    """
    idx = list(contact_joints)
    if not idx:
        return np.zeros((len(joints), 0), bool)
    p = np.asarray(joints, np.float64)[:, idx]                                          # (T, C, 3)
    speed = np.linalg.norm(np.gradient(p, axis=0), axis=-1) * fps if len(p) > 1 else np.zeros(p.shape[:2])
    return np.asarray(contact, bool)[:, idx] & (speed < stance_speed)
