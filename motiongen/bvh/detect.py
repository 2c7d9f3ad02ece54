"""Up axis, unit and plausibility of imported mocap, inferred from the motion itself.

Many public datasets write skeletons whose zero pose is not an upright body (LAFAN1-style
rigs lay every bone along +x and let the motion channels stand the body up), so the rest
pose cannot be trusted: it is only a hint here. What a human motion reliably shows is

- its up axis: the head is above the feet in (nearly) every frame, so the mean of the unit
  feet→head directions over the frames points up;
- its size: the leg (hip→knee→ankle) is about half the stature (0.45-0.53 in the bodies
  measured) and does not change with pose, so its length in file units picks the unit;
- and that it is a body standing on a floor, which `check_plausible` verifies after the
  conversion so that a wrong guess (or a wrong `up=` / `unit=` / mapping from the user) is
  refused instead of written.

Arrays here are body joints in `motiongen.skeleton.BODY` order: (T, 22, 3).
"""

from __future__ import annotations

import numpy as np

from motiongen.errors import DataError
from motiongen.geometry import up_rotation
from motiongen.skeleton import BODY_JOINT_NAMES, FOOT_JOINTS, HEAD, PELVIS

# Candidate units, metres per file unit. CMU's ASF units are 1/0.45 inch.
UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "cmu": 0.0254 / 0.45}

# Leg = mean over sides of |hip-knee| + |knee-ankle|. Measured: CMU subject 1 0.835 m
# (stature ~1.6 m), Boxing_Toes 0.857 m (1.70 m), SMPL-X-like templates 0.78 m (1.7 m);
# anthropometric tables give thigh + shin = 0.49 x stature.
LEG_TYPICAL = 0.82                # metres, the prior the unit is chosen by (log distance)
LEG_RANGE = (0.45, 1.15)          # metres: statures of about 1.0 - 2.3 m
MIN_UP_VOTE = 0.5                 # |mean unit feet->head| along one axis for the motion to decide

# The plausibility check (metres, y-up, after conversion).
STATURE_RANGE = (1.0, 2.3)        # head top (or head joint) above the lowest joint, 95th percentile
HEAD_ABOVE_PELVIS = 0.1           # a frame counts as upright when the head is this far above the
PELVIS_ABOVE_FEET = 0.1           # pelvis and the pelvis this far above the lowest foot joint
MIN_UPRIGHT = 0.5                 # ... in at least this fraction of the frames
FLOOR_TOLERANCE = 0.25            # the lowest foot is within this of the clip's floor level
MIN_ON_FLOOR = 0.5                # ... in at least this fraction of the frames

_AXES = "xyz"


def parse_up(value: str, path: str = "<memory>") -> str:
    """'y', '+z', '-x', 'Z' ... -> canonical '+y', '+z', '-x'."""
    v = str(value).strip().lower()
    sign = "-" if v.startswith("-") else "+"
    v = v.lstrip("+-")
    if v not in _AXES:
        raise DataError(path, "up", f"expected x, y or z with an optional sign (e.g. z, -y), got {value!r}")
    return sign + v


def _signed_axis(v: np.ndarray) -> str:
    a = int(np.argmax(np.abs(v)))
    return ("+" if v[a] > 0 else "-") + _AXES[a]


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def rest_pose_hint(rest: np.ndarray) -> str | None:
    """The rest pose's up axis, if it stands upright: pelvis->head and feet->pelvis point the
    same way along one dominant axis. None for rigs with bones laid along an axis (legs
    and spine both along +x) or any other non-standing zero pose."""
    feet = rest[list(FOOT_JOINTS)].mean(0)
    a, b = _unit(rest[HEAD] - rest[PELVIS]), _unit(rest[PELVIS] - feet)
    if _signed_axis(a) != _signed_axis(b) or a @ b < 0.7 or min(np.abs(a).max(), np.abs(b).max()) < 0.7:
        return None
    return _signed_axis(a + b)


def detect_up(joints: np.ndarray, rest: np.ndarray, path: str = "<memory>") -> tuple[str, str, float]:
    """Up axis of a motion: joints (T, 22, 3) and rest pose (22, 3), file axes.

    Returns (signed axis, what decided it: "motion" | "rest pose", share of the vote). The
    mean over frames of the unit feet->head direction decides when one axis carries at
    least MIN_UP_VOTE of it; the rest pose decides only when the motion is ambiguous (e.g.
    mostly lying), and refuses when an upright rest pose contradicts a clear motion.
    """
    feet = joints[:, list(FOOT_JOINTS)].mean(1)                  # (T, 3)
    vote = _unit(joints[:, HEAD] - feet).mean(0)                 # (3,)
    strength = float(np.abs(vote).max())
    motion = _signed_axis(vote) if strength >= MIN_UP_VOTE else None
    hint = rest_pose_hint(rest)
    if motion is not None and hint is not None and motion != hint:
        raise DataError(path, None, f"cannot tell the up axis: the head is above the feet along {motion} over the "
                                    f"motion but the rest pose stands along {hint}; pass up=")
    if motion is not None:
        return motion, "motion", strength
    if hint is not None:
        return hint, "rest pose", strength
    raise DataError(path, None, "cannot find the up axis: the head is not above the feet along one axis over the "
                                f"motion (mean feet-to-head direction {np.round(vote, 2).tolist()}) and the rest "
                                "pose does not stand upright; pass up=")


def leg_length(joints: np.ndarray) -> float:
    """Median over frames of the mean leg length |hip-knee| + |knee-ankle|, joints (T, 22, 3)."""
    total = 0.0
    for side in ("left", "right"):
        hip, knee, ankle = (joints[:, BODY_JOINT_NAMES.index(f"{side}_{j}")] for j in ("hip", "knee", "ankle"))
        total = total + np.linalg.norm(knee - hip, axis=-1) + np.linalg.norm(ankle - knee, axis=-1)
    return float(np.median(total / 2))


def detect_unit(leg_file_units: float, path: str = "<memory>") -> str:
    """The unit (key of UNITS) that makes a leg of `leg_file_units` a human's: within
    LEG_RANGE, closest to LEG_TYPICAL in log scale. Units differ by at least 2.2x (inch vs
    CMU's), so only statures near the ends of the range can be ambiguous."""
    lo, hi = LEG_RANGE
    ok = [u for u in UNITS if lo <= leg_file_units * UNITS[u] <= hi]
    if not ok:
        raise DataError(path, None, f"cannot detect units: a leg (hip-knee-ankle) of {leg_file_units:.4g} file units "
                                    f"is not {lo}-{hi} m in any of {list(UNITS)}; pass unit=")
    return min(ok, key=lambda u: abs(np.log(leg_file_units * UNITS[u] / LEG_TYPICAL)))


def stature(points: np.ndarray, top: list[int]) -> float:
    """95th percentile over frames of the height of the highest of `top` (the head joint and
    what hangs below it in the file: head-top End Site) above the lowest point.
    points (T, P, 3) metres, y-up. Raised hands do not count, crouched frames do not
    dominate."""
    h = points[:, top, 1].max(1) - points[..., 1].min(1)          # (T,)
    return float(np.percentile(h, 95))


def check_plausible(joints: np.ndarray, height: float, path: str = "<memory>", how: str = "",
                    hint: str = "check up=, unit= or mapping=") -> None:
    """Refuse a converted motion that is not a standing human: joints (T, 22, 3) metres,
    y-up; `height` its stature (m). Raises one DataError naming everything that looked wrong
    (`how`: where the conventions came from; `hint`: what the user can change)."""
    y = joints[..., 1]                                            # (T, 22)
    feet = y[:, list(FOOT_JOINTS)].min(1)                         # (T,) lowest foot joint
    upright = (y[:, HEAD] - y[:, PELVIS] > HEAD_ABOVE_PELVIS) & (y[:, PELVIS] - feet > PELVIS_ABOVE_FEET)
    floor = np.percentile(feet, 5)
    on_floor = feet - floor < FLOOR_TOLERANCE
    problems = []
    if upright.mean() < MIN_UPRIGHT:
        problems.append(f"head above pelvis above feet in {upright.mean():.0%} of frames (expected most)")
    lo, hi = STATURE_RANGE
    if not lo <= height <= hi:
        problems.append(f"height {height:.3g} m (expected {lo}-{hi} m)")
    if on_floor.mean() < MIN_ON_FLOOR:
        problems.append(f"the lowest foot is within {FLOOR_TOLERANCE} m of one floor in {on_floor.mean():.0%} of "
                        f"frames (expected most)")
    if problems:
        where = f" ({how})" if how else ""
        raise DataError(path, None, f"not a plausible standing human after import{where}: {'; '.join(problems)}; "
                                    f"{hint}")


__all__ = ["UNITS", "parse_up", "up_rotation", "rest_pose_hint", "detect_up", "leg_length", "detect_unit",
           "stature", "check_plausible"]
