"""Import a BVH motion onto our 22 body joints: skeleton layouts (name maps for common rigs,
or the user's JSON mapping), unit and up axis from the motion (`motiongen.bvh.detect`),
resampling to 30 fps, a refusal of what does not look like a standing human, and the lowest
joint put on the floor. Conventions: docs/bvh.md.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from motiongen.bvh.file_format import BVH, load_bvh
from motiongen.bvh.detect import (UNITS, check_plausible, detect_unit, detect_up, leg_length, parse_up,
                                       stature, up_rotation)
from motiongen.errors import DataError
from motiongen.rates import DATA_FPS
from motiongen.skeleton import BODY_JOINT_NAMES, HEAD

# ---------------------------------------------------------------------------------------
# Import onto the 22 SMPL-X body joints

# A layout maps each of our joints to one BVH joint name or to a list of names whose
# positions are averaged (the midpoint of one bone stays rigid, so round trips stay exact).
# Names are compared case-insensitively after dropping any "namespace:" prefix (mixamorig:).
_SIDES = ("left", "right")


def _sided(fn) -> dict[str, object]:
    out = {}
    for s in _SIDES:
        out.update(fn(s, s.capitalize(), s[0].upper()))
    return out


LAYOUTS: dict[str, dict[str, object]] = {
    # CMU (cgspeed conversion, 31 joints). LowerBack sits on Hips; Spine/Spine1 are the only
    # real spine bones, so spine2 is their midpoint. LeftShoulder is the clavicle.
    "cmu": {"pelvis": "Hips", "spine1": "Spine", "spine2": ["Spine", "Spine1"], "spine3": "Spine1",
            "neck": "Neck", "head": "Neck1",
            **_sided(lambda s, S, c: {
                f"{s}_hip": f"{S}UpLeg", f"{s}_knee": f"{S}Leg", f"{s}_ankle": f"{S}Foot",
                f"{s}_foot": f"{S}ToeBase", f"{s}_collar": f"{S}Shoulder", f"{s}_shoulder": f"{S}Arm",
                f"{s}_elbow": f"{S}ForeArm", f"{s}_wrist": f"{S}Hand"})},
    # Motion Analysis / Biovision style (Hips, Ab, Chest, LeftCollar, LeftHip, LeftToes...),
    # e.g. assimp's Boxing_Toes.bvh. Its collars sit on the neck joint.
    "biovision": {"pelvis": "Hips", "spine1": "Ab", "spine2": ["Ab", "Chest"], "spine3": "Chest",
                  "neck": "Neck", "head": "Head",
                  **_sided(lambda s, S, c: {
                      f"{s}_hip": f"{S}Hip", f"{s}_knee": f"{S}Knee", f"{s}_ankle": f"{S}Ankle",
                      f"{s}_foot": f"{S}Toes", f"{s}_collar": f"{S}Collar", f"{s}_shoulder": f"{S}Shoulder",
                      f"{s}_elbow": f"{S}Elbow", f"{s}_wrist": f"{S}Wrist"})},
    # The common 22-joint SMPL-like layout and Mixamo (LeftToe or LeftToeBase).
    "mixamo": {"pelvis": "Hips", "spine1": "Spine", "spine2": "Spine1", "spine3": "Spine2",
               "neck": "Neck", "head": "Head",
               **_sided(lambda s, S, c: {
                   f"{s}_hip": f"{S}UpLeg", f"{s}_knee": f"{S}Leg", f"{s}_ankle": f"{S}Foot",
                   f"{s}_foot": [f"{S}Toe", f"{S}ToeBase"], f"{s}_collar": f"{S}Shoulder",
                   f"{s}_shoulder": f"{S}Arm", f"{s}_elbow": f"{S}ForeArm", f"{s}_wrist": f"{S}Hand"})},
    # What motiongen.bvh.export writes: our own joint names.
    "smplx": {n: n for n in BODY_JOINT_NAMES},
}
# In "mixamo", a list means "first name present" (LeftToe vs LeftToeBase), not an average.
_FIRST_OF = {("mixamo", f"{s}_foot") for s in _SIDES}

def _norm(name: str) -> str:
    return name.rsplit(":", 1)[-1].strip().lower()


def load_mapping(path: str | Path) -> dict[str, object]:
    """Read a user mapping file: JSON {our_joint_name: bvh_joint_name or [names to average]}."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, None, "joint mapping file is missing")
    try:
        m = json.loads(path.read_text())
    except ValueError as e:
        raise DataError(path, None, f"malformed JSON ({e})") from None
    if not isinstance(m, dict):
        raise DataError(path, None, "expected a JSON object {our_joint_name: bvh_joint_name}")
    unknown = sorted(set(m) - set(BODY_JOINT_NAMES))
    if unknown:
        raise DataError(path, unknown[0], f"not one of our body joints {list(BODY_JOINT_NAMES)}")
    missing = [n for n in BODY_JOINT_NAMES if n not in m]
    if missing:
        raise DataError(path, missing[0], f"mapping must name a BVH joint for all 22 body joints; missing {missing}")
    for k, v in m.items():
        if not (isinstance(v, str) or (isinstance(v, list) and v and all(isinstance(x, str) for x in v))):
            raise DataError(path, k, f"expected a BVH joint name or a list of names, found {v!r}")
    return m


def resolve_mapping(bvh: BVH, mapping: dict[str, object] | None = None,
                    mapping_path: str | Path | None = None) -> tuple[str, list[list[int]]]:
    """For each of our 22 joints, the BVH joint indices whose positions are averaged.
    Tries the built-in layouts when `mapping` is None. Returns (layout name, indices)."""
    by_name = {}
    for j, n in enumerate(bvh.names):
        if not bvh.is_end[j]:
            by_name.setdefault(_norm(n), j)

    def try_layout(name: str, layout: dict) -> list[list[int]] | None:
        out = []
        for ours in BODY_JOINT_NAMES:
            v = layout[ours]
            names = [v] if isinstance(v, str) else list(v)
            idx = [by_name.get(_norm(x)) for x in names]
            if (name, ours) in _FIRST_OF:
                idx = [i for i in idx if i is not None][:1]
                if not idx:
                    return None
            elif None in idx:
                return None
            out.append(idx)
        return out

    if mapping is not None:
        got = try_layout("user", mapping)
        if got is None:
            have = set(by_name)
            bad = next(x for v in mapping.values() for x in ([v] if isinstance(v, str) else v) if _norm(x) not in have)
            raise DataError(mapping_path or bvh.path, None, f"mapping names BVH joint {bad!r}, which {bvh.path} does not have")
        return "user", got
    for name, layout in LAYOUTS.items():
        got = try_layout(name, layout)
        if got is not None:
            return name, got
    shown = [n for j, n in enumerate(bvh.names) if not bvh.is_end[j]]
    raise DataError(bvh.path, None, f"joint names match no known layout ({', '.join(LAYOUTS)}): "
                                    f"{shown[:6]}{'...' if len(shown) > 6 else ''}; pass mapping=FILE "
                                    "(JSON {our_joint_name: bvh_joint_name})")


def _gather(positions: np.ndarray, idx: list[list[int]]) -> np.ndarray:
    """(..., Jb, 3) BVH positions -> (..., 22, 3) body joints (means over each index list)."""
    return np.stack([positions[..., i, :].mean(axis=-2) for i in idx], axis=-2)


@dataclass
class ImportedMotion:
    joints: np.ndarray       # (T, 22, 3) float64, metres, y-up, at `fps`
    fps: float
    layout: str              # built-in layout name or "user"
    unit: str                # key of UNITS
    up_axis: str             # "+y", "+z", ... of the file
    height: float            # stature, metres: head top above the lowest point, 95th pct over frames
    source_fps: float
    up_from: str = "given"   # what decided up_axis: "motion", "rest pose" or "given"
    unit_from: str = "given"  # "leg length" or "given"


def resample_times(T: int, src_fps: float, dst_fps: float) -> tuple[np.ndarray, np.ndarray]:
    """(t_src (T,), t_dst (T',)) seconds: a clip's frame times and those of the same duration at
    dst_fps (the last at or before the clip's end)."""
    t_src = np.arange(T) / src_fps
    return t_src, np.arange(int(np.floor(t_src[-1] * dst_fps + 1e-6)) + 1) / dst_fps


def resample(positions: np.ndarray, src_fps: float, dst_fps: float) -> np.ndarray:
    """Cubic-spline resampling of (T, ...) positions from src_fps to dst_fps (same duration)."""
    T = positions.shape[0]
    if abs(src_fps - dst_fps) < 1e-3 * dst_fps or T < 2:
        return positions
    t_src, t_dst = resample_times(T, src_fps, dst_fps)
    return CubicSpline(t_src, positions, axis=0)(t_dst)


def _head_and_below(bvh: BVH, head: list[int]) -> list[int]:
    """The mapped head joint(s) and their descendants (head-top End Site, HeadTop_End...)."""
    keep = set(head)
    for j, p in enumerate(bvh.parents):
        if p in keep:
            keep.add(j)
    return sorted(keep)


def bvh_to_body(bvh: BVH, mapping: dict[str, object] | None = None, mapping_path: str | Path | None = None,
                fps: float | None = DATA_FPS, unit: str | None = None, floor: bool = True,
                up: str | None = None) -> ImportedMotion:
    """Map a BVH onto our 22 body joints: metres, y-up, resampled to `fps` (None keeps the file's).

    up: "y", "+z", "-x"... or None to detect it from the motion (the head is above the feet;
    the rest pose is only a hint, see `bvh_detect.detect_up`); it is turned onto +y.
    unit: a key of UNITS, or None to detect it from the leg length. The result must look like
    a standing human (`bvh_detect.check_plausible`), else DataError: nothing implausible is
    returned. floor=True shifts y so that the lowest joint over the clip sits at y = 0 (the
    HumanML3D convention our foot-skating thresholds were designed for); False keeps the
    file's vertical origin.
    """
    layout, idx = resolve_mapping(bvh, mapping, mapping_path)
    world = bvh.fk()                                          # (T, Jb, 3) file units and axes
    body = _gather(world, idx)                                # (T, 22, 3)
    if up is None:
        up_axis, up_from, _ = detect_up(body, _gather(bvh.rest_positions(), idx), bvh.path)
    else:
        up_axis, up_from = parse_up(up, bvh.path), "given"
    if unit is None:
        unit, unit_from = detect_unit(leg_length(body), bvh.path), "leg length"
    elif unit not in UNITS:
        raise DataError(bvh.path, "unit", f"unknown unit {unit!r}; expected one of {list(UNITS)}")
    else:
        unit_from = "given"
    world = world @ up_rotation(up_axis).T * UNITS[unit]     # (T, Jb, 3) metres, y-up
    joints = _gather(world, idx)                              # (T, 22, 3)
    height = stature(world, _head_and_below(bvh, idx[HEAD]))
    out_fps = bvh.fps if fps is None else float(fps)
    joints = resample(joints, bvh.fps, out_fps)
    check_plausible(joints, height, bvh.path, f"up {up_axis} from {up_from}, unit {unit} from {unit_from}")
    if floor:
        joints[..., 1] -= joints[..., 1].min()
    return ImportedMotion(joints, out_fps, layout, unit, up_axis, height, bvh.fps, up_from, unit_from)


def import_bvh(path: str | Path, mapping: str | Path | dict | None = None, **kw) -> ImportedMotion:
    """`load_bvh` + `bvh_to_body`; `mapping` may be a JSON file path or a dict."""
    mapping_path = None
    if isinstance(mapping, (str, Path)):
        mapping_path = mapping
        mapping = load_mapping(mapping)
    return bvh_to_body(load_bvh(path), mapping, mapping_path, **kw)


__all__ = ["LAYOUTS", "load_mapping", "resolve_mapping", "bvh_to_body", "import_bvh", "ImportedMotion", "resample",
           "resample_times"]
