"""A procedural body: SMPL-X-like proportions scaled by stature, and the 22 body joints of a
pose given by end-effector controls (pelvis frame, spine bend, ankle and wrist targets).

Bodies are built by rigid offsets plus analytic two-bone IK, so every bone keeps its length
exactly in every frame whatever the controls ask for (unreachable targets are clamped).
Body frame: x left, y up, z forward (yaw 0 faces +z, as in motiongen.geometry).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from motiongen.skeleton import BODY

REF_HEIGHT = 1.71  # stature of the reference offsets below (about the SMPL-X neutral body)
# Rest offsets (m) of the reference body, parent -> child, body frame, left side (+x).
_HIP = (0.06, -0.085, -0.015)
_SPINE = ((0.0, 0.11, -0.025), (0.0, 0.135, 0.0), (0.0, 0.055, 0.0))  # pelvis->spine1->spine2->spine3
_NECK, _HEAD = (0.0, 0.215, -0.03), (0.0, 0.09, 0.05)
_COLLAR, _SHOULDER = (0.075, 0.115, -0.02), (0.12, 0.045, -0.015)
_THIGH, _SHIN, _UPPER_ARM, _FOREARM = 0.385, 0.425, 0.26, 0.255
_FOOT = (0.02, -0.055, 0.125)   # ankle -> toe base ("foot" joint) in the foot frame
_ANKLE_H = 0.075                # ankle above the sole of a flat foot
_HEAD_TOP = 0.13                # head joint -> crown
# Joint depth under the skin (m, reference body): a joint touches a surface when its distance
# to it minus this is small. Feet use the sole; others the soft tissue around the joint.
_TISSUE = {"pelvis": 0.10, "left_hip": 0.10, "right_hip": 0.10, "spine1": 0.10, "spine2": 0.10,
           "spine3": 0.10, "neck": 0.06, "head": 0.09, "left_collar": 0.08, "right_collar": 0.08,
           "left_shoulder": 0.06, "right_shoulder": 0.06, "left_elbow": 0.04, "right_elbow": 0.04,
           "left_wrist": 0.04, "right_wrist": 0.04, "left_knee": 0.05, "right_knee": 0.05,
           "left_ankle": _ANKLE_H, "right_ankle": _ANKLE_H,
           "left_foot": _ANKLE_H + _FOOT[1], "right_foot": _ANKLE_H + _FOOT[1]}

J = {n: i for i, n in enumerate(BODY.names)}


def _lr(v) -> np.ndarray:
    """(2, 3) [left, right] copies of a left-side offset."""
    v = np.asarray(v, float)
    return np.stack([v, v * (-1.0, 1.0, 1.0)])


def rot_x(a) -> np.ndarray:
    """(..., 3, 3) rotation about +x; positive a tips +y towards +z (a forward bend)."""
    a = np.asarray(a, float)
    c, s, z, o = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(a) -> np.ndarray:
    """(..., 3, 3) rotation about +y (the geometry.yaw_matrix convention)."""
    a = np.asarray(a, float)
    c, s, z, o = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


@dataclass(frozen=True)
class Body:
    height: float  # stature, m

    @property
    def s(self) -> float:
        return self.height / REF_HEIGHT

    @property
    def thigh(self) -> float:
        return _THIGH * self.s

    @property
    def shin(self) -> float:
        return _SHIN * self.s

    @property
    def leg(self) -> float:
        return (_THIGH + _SHIN) * self.s

    @property
    def arm(self) -> float:
        return (_UPPER_ARM + _FOREARM) * self.s

    @property
    def ankle_h(self) -> float:
        return _ANKLE_H * self.s

    @property
    def toe_h(self) -> float:
        return (_ANKLE_H + _FOOT[1]) * self.s

    @property
    def hip(self) -> np.ndarray:
        return _lr(_HIP) * self.s  # (2, 3)

    @property
    def foot(self) -> np.ndarray:
        return _lr(_FOOT) * self.s  # (2, 3)

    @property
    def stand_pelvis_y(self) -> float:
        """Pelvis height standing with slightly soft knees (flat feet under the hips)."""
        return self.ankle_h + 0.985 * self.leg - _HIP[1] * self.s

    @property
    def tissue(self) -> np.ndarray:
        return np.array([_TISSUE[n] for n in BODY.names]) * self.s  # (22,)

    def crown_above_head(self) -> float:
        return _HEAD_TOP * self.s


@dataclass
class Controls:
    """Per-frame pose controls of one sequence (T frames)."""

    pelvis: np.ndarray     # (T, 3) pelvis joint, world
    root: np.ndarray       # (T, 3, 3) pelvis frame; columns = body left, up, forward in world
    lean: np.ndarray       # (T,) forward bend of the spine over the pelvis, radians
    ankle: np.ndarray      # (T, 2, 3) ankle targets [left, right]
    foot_rot: np.ndarray   # (T, 2, 3, 3) foot frames
    knee_pole: np.ndarray  # (T, 2, 3) direction the knees bend towards
    wrist: np.ndarray      # (T, 2, 3) wrist targets

    FIELDS = ("pelvis", "root", "lean", "ankle", "foot_rot", "knee_pole", "wrist")

    def take(self, idx) -> "Controls":
        return Controls(*(getattr(self, f)[idx] for f in self.FIELDS))

    @staticmethod
    def cat(parts: list["Controls"]) -> "Controls":
        return Controls(*(np.concatenate([getattr(p, f) for p in parts]) for f in Controls.FIELDS))

    def __len__(self) -> int:
        return len(self.pelvis)


def _apply(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R (T,3,3) @ v (3,) or (2,3) -> (T,3) or (T,2,3)."""
    return np.einsum("tij,...j->t...i", R, v)


def torso(body: Body, pelvis: np.ndarray, root: np.ndarray, lean: np.ndarray) -> dict[str, np.ndarray]:
    """Spine, neck, head, collars, shoulders of poses (T,) and the chest frame R3 (T,3,3).

    The bend is spread evenly over the three spine joints, like a curling back."""
    s = body.s
    R1, R2, R3 = (root @ rot_x(lean * k / 3.0) for k in (1, 2, 3))
    out = {"spine1": pelvis + _apply(R1, np.array(_SPINE[0]) * s)}
    out["spine2"] = out["spine1"] + _apply(R2, np.array(_SPINE[1]) * s)
    out["spine3"] = out["spine2"] + _apply(R3, np.array(_SPINE[2]) * s)
    out["neck"] = out["spine3"] + _apply(R3, np.array(_NECK) * s)
    out["head"] = out["neck"] + _apply(R3, np.array(_HEAD) * s)
    out["collar"] = out["spine3"][:, None] + _apply(R3, _lr(_COLLAR) * s)          # (T,2,3)
    out["shoulder"] = out["collar"] + _apply(R3, _lr(_SHOULDER) * s)               # (T,2,3)
    out["R3"] = R3
    return out


def two_bone_ik(a: np.ndarray, target: np.ndarray, l1: float, l2: float, pole: np.ndarray):
    """Middle and end joints of a two-bone chain rooted at a (...,3) reaching for target (...,3),
    bending towards pole (...,3). Unreachable targets are clamped along the root->target line
    so both bone lengths hold exactly."""
    d = target - a
    dist = np.linalg.norm(d, axis=-1, keepdims=True)
    u = d / np.maximum(dist, 1e-9)
    D = np.clip(dist, abs(l1 - l2) + 1e-4, (l1 + l2) * (1 - 1e-6))
    cos_a = np.clip((l1 ** 2 + D ** 2 - l2 ** 2) / (2 * l1 * D), -1.0, 1.0)
    b = pole - np.sum(pole * u, -1, keepdims=True) * u
    bn = np.linalg.norm(b, axis=-1, keepdims=True)
    # A pole parallel to the limb leaves the bend undefined; any perpendicular will do.
    fallback = np.cross(u, np.array([1.0, 0.0, 0.0]))
    b = np.where(bn > 1e-6, b / np.maximum(bn, 1e-9), fallback / np.maximum(np.linalg.norm(fallback, axis=-1, keepdims=True), 1e-9))
    mid = a + l1 * (cos_a * u + np.sqrt(1 - cos_a ** 2) * b)
    return mid, a + D * u


def elbow_pole(R3: np.ndarray) -> np.ndarray:
    """(T,2,3): elbows point back, down and a little out."""
    return _apply(R3, _lr((0.3, -0.4, -1.0)))


def pose(body: Body, c: Controls) -> np.ndarray:
    """Joint positions (T, 22, 3) float64 of the controlled poses."""
    T = len(c)
    out = np.zeros((T, 22, 3))
    out[:, J["pelvis"]] = c.pelvis
    hips = c.pelvis[:, None] + _apply(c.root, body.hip)                            # (T,2,3)
    knees, ankles = two_bone_ik(hips, c.ankle, body.thigh, body.shin, c.knee_pole)
    toes = ankles + np.einsum("tkij,kj->tki", c.foot_rot, body.foot)
    t = torso(body, c.pelvis, c.root, c.lean)
    elbows, wrists = two_bone_ik(t["shoulder"], c.wrist, _UPPER_ARM * body.s, _FOREARM * body.s,
                                 elbow_pole(t["R3"]))
    for name in ("spine1", "spine2", "spine3", "neck", "head"):
        out[:, J[name]] = t[name]
    for k, side in enumerate(("left", "right")):
        for name, arr in (("hip", hips), ("knee", knees), ("ankle", ankles), ("foot", toes),
                          ("collar", t["collar"]), ("shoulder", t["shoulder"]), ("elbow", elbows),
                          ("wrist", wrists)):
            out[:, J[f"{side}_{name}"]] = arr[:, k]
    return out
