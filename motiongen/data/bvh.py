"""BVH motion files: parser, forward kinematics, writer, and import onto our 22 body joints.

Conventions we follow (documented in docs/bvh.md):
- Euler channels are *intrinsic* rotations applied in the listed order: ``Zrotation
  Yrotation Xrotation`` means R = Rz @ Ry @ Rx acting on column vectors, i.e. scipy's
  ``Rotation.from_euler("ZYX", ...)`` (upper case = intrinsic). Angles are degrees.
- Position channels, on any joint, *replace* that joint's OFFSET (as in Blender's importer
  and most parsers); missing position axes keep the OFFSET value.
- End Sites become extra joints named ``<parent>_end`` with no channels, so the head top and
  toe tips take part in height estimation.

`load_bvh` parses; `BVH.fk` gives world positions of every joint; `bvh_to_body` maps a BVH
skeleton onto `motiongen.skeleton.BODY` (22 SMPL-X joints), detects unit and up axis from
the motion (`motiongen.data.bvh_detect`), resamples to 30 fps, refuses what does not look
like a standing human and puts the lowest joint on the floor. `write_bvh` writes a `BVH`.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from motiongen.data.bvh_detect import (UNITS, check_plausible, detect_unit, detect_up, leg_length, parse_up,
                                       stature, up_rotation)
from motiongen.errors import DataError
from motiongen.skeleton import BODY_JOINT_NAMES, HEAD

_CHANNEL_RE = re.compile(r"^([xyz])(position|rotation)$", re.IGNORECASE)


@dataclass
class BVH:
    """A parsed BVH file. J counts joints *and* End Sites (``is_end``), in file order
    (a parent always precedes its children). C = total channel count per frame."""

    names: list[str]
    parents: np.ndarray            # (J,) int, -1 for the root
    offsets: np.ndarray            # (J, 3) float64, file units
    channels: list[tuple[str, ...]]  # per joint, e.g. ("Xposition", ..., "Zrotation"); () for End Sites
    is_end: np.ndarray             # (J,) bool
    motion: np.ndarray             # (T, C) float64, channel values in file order
    frame_time: float              # seconds
    path: str = "<memory>"
    _slices: list[slice] = field(default_factory=list, repr=False)

    def __post_init__(self):
        self._slices, c = [], 0
        for ch in self.channels:
            self._slices.append(slice(c, c + len(ch)))
            c += len(ch)

    @property
    def num_frames(self) -> int:
        return self.motion.shape[0]

    @property
    def num_channels(self) -> int:
        return sum(len(c) for c in self.channels)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def index(self, name: str) -> int:
        return self.names.index(name)

    def local_transforms(self, motion: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Local rotations (T, J, 3, 3) and translations (T, J, 3) of each joint w.r.t. its parent."""
        motion = self.motion if motion is None else motion
        T, J = motion.shape[0], len(self.names)
        rot = np.broadcast_to(np.eye(3), (T, J, 3, 3)).copy()
        trans = np.broadcast_to(self.offsets, (T, J, 3)).copy()
        for j, ch in enumerate(self.channels):
            if not ch:
                continue
            vals = motion[:, self._slices[j]]   # (T, len(ch))
            axes, rot_cols = "", []
            for k, name in enumerate(ch):
                axis, kind = _CHANNEL_RE.match(name).groups()
                if kind.lower() == "position":
                    trans[:, j, "xyz".index(axis.lower())] = vals[:, k]
                else:
                    axes += axis.upper()          # upper case: intrinsic sequence
                    rot_cols.append(k)
            if axes:
                rot[:, j] = Rotation.from_euler(axes, vals[:, rot_cols], degrees=True).as_matrix()
        return rot, trans

    def fk(self, motion: np.ndarray | None = None) -> np.ndarray:
        """World positions (T, J, 3) of every joint and End Site, in file units and axes."""
        rot, trans = self.local_transforms(motion)
        world_R = np.empty_like(rot)
        world_p = np.empty_like(trans)
        for j, p in enumerate(self.parents):
            if p < 0:
                world_R[:, j], world_p[:, j] = rot[:, j], trans[:, j]
            else:
                world_R[:, j] = world_R[:, p] @ rot[:, j]
                world_p[:, j] = world_p[:, p] + (world_R[:, p] @ trans[:, j, :, None])[..., 0]
        return world_p

    def rest_positions(self) -> np.ndarray:
        """(J, 3) joint positions with every channel zero and offsets only (the file's rest pose)."""
        pos = np.zeros((len(self.names), 3))
        for j, p in enumerate(self.parents):
            pos[j] = self.offsets[j] + (pos[p] if p >= 0 else 0.0)
        return pos


# ---------------------------------------------------------------------------------------
# Parsing


class _Tokens:
    """Whitespace tokens of the HIERARCHY section with their 1-based line numbers."""

    def __init__(self, lines: list[tuple[int, str]], path: str):
        self.toks: list[tuple[str, int]] = []
        for ln, line in lines:
            for t in line.replace("{", " { ").replace("}", " } ").split():
                self.toks.append((t, ln))
        self.i, self.path = 0, path
        self.last_line = lines[-1][0] if lines else 1

    def error(self, problem: str, line: int | None = None) -> DataError:
        line = line if line is not None else (self.toks[self.i][1] if self.i < len(self.toks) else self.last_line)
        return DataError(self.path, None, f"line {line}: {problem}")

    def peek(self) -> str | None:
        return self.toks[self.i][0] if self.i < len(self.toks) else None

    def next(self, what: str) -> tuple[str, int]:
        if self.i >= len(self.toks):
            raise self.error(f"unexpected end of HIERARCHY while reading {what} (missing '}}' or MOTION?)")
        tok = self.toks[self.i]
        self.i += 1
        return tok

    def expect(self, word: str) -> int:
        tok, ln = self.next(repr(word))
        if tok.upper() != word.upper():
            raise self.error(f"expected {word!r}, found {tok!r}", ln)
        return ln

    def rest_of_line(self, ln: int, what: str) -> str:
        parts = []
        while self.i < len(self.toks) and self.toks[self.i][1] == ln and self.toks[self.i][0] not in "{}":
            parts.append(self.toks[self.i][0])
            self.i += 1
        if not parts:
            raise self.error(f"{what} has no name", ln)
        return " ".join(parts)

    def number(self, what: str, cast=float):
        tok, ln = self.next(what)
        try:
            return cast(tok)
        except ValueError:
            raise self.error(f"expected a number for {what}, found {tok!r}", ln) from None


def parse_bvh(text: str, path: str | Path = "<memory>") -> BVH:
    """Parse BVH text. Raises DataError naming `path` and the line of the problem."""
    path = str(path)
    all_lines = text.splitlines()
    motion_at = next((i for i, l in enumerate(all_lines) if l.strip().upper() == "MOTION"), None)
    if motion_at is None:
        raise DataError(path, None, "no MOTION section (truncated or not a BVH file)")
    toks = _Tokens([(i + 1, l) for i, l in enumerate(all_lines[:motion_at])], path)
    first = toks.peek()
    if first is None or first.upper() != "HIERARCHY":
        raise toks.error(f"expected 'HIERARCHY' at the start of the file, found {first!r}")
    toks.next("HIERARCHY")

    names, parents, offsets, channels, is_end = [], [], [], [], []

    def joint_body(parent: int, name: str, ln: int, end_site: bool) -> None:
        if name in names:
            raise toks.error(f"duplicate joint name {name!r}", ln)
        j = len(names)
        names.append(name), parents.append(parent), is_end.append(end_site)
        offsets.append(np.zeros(3)), channels.append(())
        toks.expect("{")
        toks.expect("OFFSET")
        offsets[j] = np.array([toks.number(f"OFFSET of {name!r}") for _ in range(3)])
        if end_site:
            toks.expect("}")
            return
        tok, ln2 = toks.next(f"CHANNELS of {name!r}")
        if tok.upper() != "CHANNELS":
            raise toks.error(f"expected 'CHANNELS' for joint {name!r}, found {tok!r}", ln2)
        n = toks.number(f"channel count of {name!r}", int)
        if not 0 <= n <= 6:
            raise toks.error(f"joint {name!r} declares {n} channels (0..6 allowed)", ln2)
        chans = []
        for _ in range(n):
            c, lnc = toks.next(f"channel names of {name!r}")
            if not _CHANNEL_RE.match(c):
                raise toks.error(f"joint {name!r}: unknown channel {c!r} (expected e.g. Xposition, Zrotation)", lnc)
            chans.append(c)
        rot_axes = [c[0].upper() for c in chans if c.lower().endswith("rotation")]
        if len(set(rot_axes)) != len(rot_axes):
            raise toks.error(f"joint {name!r}: repeated rotation axis in {chans}", ln2)
        channels[j] = tuple(chans)
        while True:
            tok, lnc = toks.next(f"the children of {name!r}")
            up = tok.upper()
            if up == "}":
                return
            if up == "JOINT":
                joint_body(j, toks.rest_of_line(lnc, "JOINT"), lnc, False)
            elif up == "END":
                toks.expect("Site")
                joint_body(j, f"{name}_end", lnc, True)
            else:
                raise toks.error(f"expected JOINT, End Site or '}}' inside {name!r}, found {tok!r}", lnc)

    tok, ln = toks.next("ROOT")
    if tok.upper() != "ROOT":
        raise toks.error(f"expected 'ROOT', found {tok!r}", ln)
    joint_body(-1, toks.rest_of_line(ln, "ROOT"), ln, False)
    if toks.peek() is not None:
        tok, ln = toks.next("end of hierarchy")
        raise toks.error(f"unexpected {tok!r} after the ROOT joint's closing '}}' (only one ROOT is supported)", ln)

    # MOTION: "Frames: N", "Frame Time: dt", then N lines of C numbers.
    header, i = {}, motion_at + 1
    for key in ("frames", "frame time"):
        while i < len(all_lines) and not all_lines[i].strip():
            i += 1
        if i >= len(all_lines):
            raise DataError(path, None, f"line {i + 1}: truncated MOTION header (missing '{key.title()}:')")
        k, _, v = all_lines[i].partition(":")
        if k.strip().lower() != key:
            raise DataError(path, None, f"line {i + 1}: expected '{key.title()}:', found {all_lines[i].strip()[:40]!r}")
        try:
            header[key] = int(v) if key == "frames" else float(v)
        except ValueError:
            raise DataError(path, None, f"line {i + 1}: bad {key.title()} value {v.strip()!r}") from None
        i += 1
    n_frames, dt = header["frames"], header["frame time"]
    if n_frames <= 0:
        raise DataError(path, None, f"empty motion (Frames: {n_frames})")
    if not dt > 0:
        raise DataError(path, None, f"Frame Time must be positive, found {dt}")
    C = sum(len(c) for c in channels)
    data = [(ln + 1, l.split()) for ln, l in enumerate(all_lines[i:], start=i) if l.strip()]
    if len(data) < n_frames:
        where = f" (last line {data[-1][0]} has {len(data[-1][1])} of {C} values)" if data and len(data[-1][1]) != C else ""
        raise DataError(path, None, f"truncated motion block: header says {n_frames} frames, found {len(data)}{where}")
    # Extra lines beyond the header's count are ignored: real exporters write them
    # (assimp's Boxing_Toes.bvh has 3070 lines for Frames: 3069), as Blender tolerates.
    data = data[:n_frames]
    for k, (ln, vals) in enumerate(data):
        if len(vals) != C:
            raise DataError(path, None, f"line {ln}: frame {k} has {len(vals)} values, the hierarchy declares {C} channels")
    try:
        motion = np.array([v for _, v in data], dtype=np.float64).reshape(n_frames, C)
    except ValueError:
        for ln, vals in data:
            try:
                [float(v) for v in vals]
            except ValueError as e:
                raise DataError(path, None, f"line {ln}: {e}") from None
        raise
    if not np.isfinite(motion).all():
        k = int(np.argmax(~np.isfinite(motion).all(axis=1)))
        raise DataError(path, None, f"line {data[k][0]}: non-finite channel value")
    return BVH(names, np.array(parents), np.array(offsets, dtype=np.float64).reshape(-1, 3), channels,
               np.array(is_end, bool), motion, dt, path)


def load_bvh(path: str | Path) -> BVH:
    path = Path(path)
    if not path.is_file():
        raise DataError(path, None, "BVH file is missing")
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise DataError(path, None, f"cannot read file ({e.strerror})") from None
    return parse_bvh(text, path)


# ---------------------------------------------------------------------------------------
# Writing


def write_bvh(path: str | Path, bvh: BVH, precision: int = 6) -> Path:
    """Write `bvh` as a BVH file (tabs, one frame per line)."""
    path = Path(path)
    children: dict[int, list[int]] = {j: [] for j in range(len(bvh.names))}
    for j, p in enumerate(bvh.parents):
        if p >= 0:
            children[int(p)].append(j)
    out = ["HIERARCHY"]
    fmt = f"{{:.{precision}f}}"

    def emit(j: int, depth: int) -> None:
        ind = "\t" * depth
        off = " ".join(fmt.format(v) for v in bvh.offsets[j])
        if bvh.is_end[j]:
            out.extend([f"{ind}End Site", f"{ind}{{", f"{ind}\tOFFSET {off}", f"{ind}}}"])
            return
        out.append(f"{ind}{'ROOT' if bvh.parents[j] < 0 else 'JOINT'} {bvh.names[j]}")
        out.extend([f"{ind}{{", f"{ind}\tOFFSET {off}",
                    f"{ind}\tCHANNELS {len(bvh.channels[j])} {' '.join(bvh.channels[j])}".rstrip()])
        for c in children[j]:
            emit(c, depth + 1)
        out.append(f"{ind}}}")

    emit(int(np.flatnonzero(bvh.parents < 0)[0]), 0)
    out += ["MOTION", f"Frames: {bvh.num_frames}", f"Frame Time: {bvh.frame_time:.10f}"]
    # A reader takes channels in depth-first file order, which need not be our joint order.
    order: list[int] = []
    stack = [int(np.flatnonzero(bvh.parents < 0)[0])]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(children[j]))
    cols = np.concatenate([np.arange(bvh.num_channels)[bvh._slices[j]] for j in order])
    body = "\n".join(" ".join(fmt.format(v) for v in row) for row in bvh.motion[:, cols])
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(out) + "\n" + body + "\n")
    return path


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
    # What motiongen.export.bvh writes: our own joint names.
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
                fps: float | None = 30.0, unit: str | None = None, floor: bool = True,
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


__all__ = ["BVH", "parse_bvh", "load_bvh", "write_bvh", "LAYOUTS", "UNITS", "load_mapping",
           "resolve_mapping", "bvh_to_body", "import_bvh", "ImportedMotion", "detect_unit", "resample"]
