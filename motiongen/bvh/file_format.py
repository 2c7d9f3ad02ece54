"""BVH motion files: parser, forward kinematics and writer (import onto our 22 body joints:
`motiongen.bvh.retarget`).

Conventions we follow (documented in docs/bvh.md):
- Euler channels are *intrinsic* rotations applied in the listed order: ``Zrotation
  Yrotation Xrotation`` means R = Rz @ Ry @ Rx acting on column vectors, i.e. scipy's
  ``Rotation.from_euler("ZYX", ...)`` (upper case = intrinsic). Angles are degrees.
- Position channels, on any joint, *replace* that joint's OFFSET (as in Blender's importer
  and most parsers); missing position axes keep the OFFSET value.
- End Sites become extra joints named ``<parent>_end`` with no channels, so the head top and
  toe tips take part in height estimation.

`load_bvh` parses; `BVH.fk` gives world positions of every joint; `write_bvh` writes a `BVH`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from motiongen.errors import DataError

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
    tree = _Hierarchy(_Tokens([(i + 1, l) for i, l in enumerate(all_lines[:motion_at])], path))
    tree.parse()
    n_frames, dt, first_row = _motion_header(all_lines, motion_at + 1, path)
    motion = _motion_rows(all_lines, first_row, n_frames, sum(len(c) for c in tree.channels), path)
    return BVH(tree.names, np.array(tree.parents), np.array(tree.offsets, dtype=np.float64).reshape(-1, 3),
               tree.channels, np.array(tree.is_end, bool), motion, dt, path)


class _Hierarchy:
    """The HIERARCHY section read joint by joint into per-joint lists (file order)."""

    def __init__(self, toks: _Tokens):
        self.toks = toks
        self.names, self.parents, self.offsets, self.channels, self.is_end = [], [], [], [], []

    def parse(self) -> None:
        toks = self.toks
        first = toks.peek()
        if first is None or first.upper() != "HIERARCHY":
            raise toks.error(f"expected 'HIERARCHY' at the start of the file, found {first!r}")
        toks.next("HIERARCHY")
        tok, ln = toks.next("ROOT")
        if tok.upper() != "ROOT":
            raise toks.error(f"expected 'ROOT', found {tok!r}", ln)
        self.joint(-1, toks.rest_of_line(ln, "ROOT"), ln, False)
        if toks.peek() is not None:
            tok, ln = toks.next("end of hierarchy")
            raise toks.error(f"unexpected {tok!r} after the ROOT joint's closing '}}' (only one ROOT is supported)", ln)

    def joint(self, parent: int, name: str, ln: int, end_site: bool) -> None:
        """One joint (or End Site) from its opening '{' to its closing '}', children included."""
        toks = self.toks
        if name in self.names:
            raise toks.error(f"duplicate joint name {name!r}", ln)
        j = len(self.names)
        self.names.append(name), self.parents.append(parent), self.is_end.append(end_site)
        self.offsets.append(np.zeros(3)), self.channels.append(())
        toks.expect("{")
        toks.expect("OFFSET")
        self.offsets[j] = np.array([toks.number(f"OFFSET of {name!r}") for _ in range(3)])
        if end_site:
            toks.expect("}")
            return
        self.channels[j] = self._channel_list(name)
        while True:
            tok, lnc = toks.next(f"the children of {name!r}")
            up = tok.upper()
            if up == "}":
                return
            if up == "JOINT":
                self.joint(j, toks.rest_of_line(lnc, "JOINT"), lnc, False)
            elif up == "END":
                toks.expect("Site")
                self.joint(j, f"{name}_end", lnc, True)
            else:
                raise toks.error(f"expected JOINT, End Site or '}}' inside {name!r}, found {tok!r}", lnc)

    def _channel_list(self, name: str) -> tuple[str, ...]:
        """The joint's ``CHANNELS n name...`` line."""
        toks = self.toks
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
        return tuple(chans)


def _motion_header(all_lines: list[str], i: int, path: str) -> tuple[int, float, int]:
    """MOTION's "Frames: N" and "Frame Time: dt" lines from line index i: (N, dt, index of the
    line after them)."""
    header = {}
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
    return n_frames, dt, i


def _motion_rows(all_lines: list[str], i: int, n_frames: int, C: int, path: str) -> np.ndarray:
    """(n_frames, C) float64 channel values from the non-blank lines from line index i on."""
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
    return motion


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


__all__ = ["BVH", "parse_bvh", "load_bvh", "write_bvh"]
