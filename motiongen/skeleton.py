"""The SMPL-X body skeleton: one source of truth for joint names, order and topology.

The 22 body joints are SMPL-X joints 0..21 in SMPL-X order. The TRUMANS release adds the
left/right index1 finger joints (SMPL-X 25 and 40) to make 24; that is available as the
``body+index1`` joint set. World convention: y-up, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

from motiongen.errors import ConfigError

BODY_JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck",
    "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist",
)
# Parent of each body joint (SMPL-X kintree); -1 for the root.
BODY_PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19,
)
NUM_BODY_JOINTS = 22

# Extra joints, by name: (index in the full SMPL-X joint list, parent body joint name).
EXTRA_JOINTS: dict[str, tuple[int, str]] = {
    "left_index1": (25, "left_wrist"),
    "right_index1": (40, "right_wrist"),
}


def _idx(name: str) -> int:
    return BODY_JOINT_NAMES.index(name)


PELVIS = 0
LEFT_HIP, RIGHT_HIP = _idx("left_hip"), _idx("right_hip")
LEFT_SHOULDER, RIGHT_SHOULDER = _idx("left_shoulder"), _idx("right_shoulder")
HEAD = _idx("head")
# Feet: ankles and toe ("foot") joints, used for contact and skating.
LEFT_FOOT_JOINTS = (_idx("left_ankle"), _idx("left_foot"))
RIGHT_FOOT_JOINTS = (_idx("right_ankle"), _idx("right_foot"))
FOOT_JOINTS = LEFT_FOOT_JOINTS + RIGHT_FOOT_JOINTS
HAND_JOINTS = (_idx("left_wrist"), _idx("right_wrist"))


def _mirror_name(name: str) -> str:
    if name.startswith("left_"):
        return "right_" + name[5:]
    if name.startswith("right_"):
        return "left_" + name[6:]
    return name


@dataclass(frozen=True)
class JointSet:
    """An ordered set of joints: the 22 body joints, optionally followed by extras."""

    name: str
    names: tuple[str, ...]
    parents: tuple[int, ...]

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        return self.names.index(name)

    @property
    def mirror(self) -> tuple[int, ...]:
        """Index of each joint's left/right mirror (itself for central joints)."""
        return tuple(self.names.index(_mirror_name(n)) for n in self.names)

    @property
    def smplx_indices(self) -> tuple[int, ...]:
        """Index of each joint in the full SMPL-X joint list (body joints map to themselves)."""
        return tuple(
            i if i < NUM_BODY_JOINTS else EXTRA_JOINTS[n][0] for i, n in enumerate(self.names)
        )

    @property
    def foot_joints(self) -> tuple[int, ...]:
        return FOOT_JOINTS

    @property
    def hand_joints(self) -> tuple[int, ...]:
        """Wrists, plus index1 finger joints when present."""
        extra = tuple(self.names.index(n) for n in ("left_index1", "right_index1") if n in self.names)
        return HAND_JOINTS + extra


def _make_joint_set(name: str, extras: tuple[str, ...]) -> JointSet:
    names = BODY_JOINT_NAMES + extras
    parents = BODY_PARENTS + tuple(BODY_JOINT_NAMES.index(EXTRA_JOINTS[e][1]) for e in extras)
    return JointSet(name=name, names=names, parents=parents)


JOINT_SETS: dict[str, JointSet] = {
    "body": _make_joint_set("body", ()),
    "body+index1": _make_joint_set("body+index1", ("left_index1", "right_index1")),
}
BODY = JOINT_SETS["body"]


def get_joint_set(name: str) -> JointSet:
    try:
        return JOINT_SETS[name]
    except KeyError:
        raise ConfigError(f"unknown joint set {name!r}; expected one of {sorted(JOINT_SETS)}") from None


def joint_set_for(names: list[str] | tuple[str, ...]) -> JointSet:
    """The joint set whose names are exactly `names` (as stored in a dataset or checkpoint)."""
    for js in JOINT_SETS.values():
        if tuple(names) == js.names:
            return js
    raise ConfigError(f"joint names {list(names)[:4]}... match no known joint set")
