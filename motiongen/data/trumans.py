"""Adapter for the public TRUMANS release (``Data_release/``) into the motiongen format.

The release is one set of frame-concatenated arrays (N frames over all sequences) plus a
``Scene/`` folder of dense occupancy grids. We read every array with ``mmap_mode="r"`` and
stream sequence by sequence through `DatasetWriter`, so RAM holds one sequence and one scene
grid at a time, never the release. Everything is validated at open (presence, shapes, dtypes,
cross-file N, index ranges) or while streaming (values), and any failure aborts the writer,
so ``out`` is either a complete dataset or untouched.

Interpretations of the release (see docs/data_format.md, "TRUMANS release mapping"):
- sequences: a new sequence starts wherever ``seg_name`` changes (``idx_start`` holds
  *window* starts and ``frame_id`` is what the reference loader iterates; neither is used to
  cut sequences). Output sequences are grouped by scene, release order within a scene.
- scene ids: `scene_ids_from_names`; objects: `interpret_object_flags`;
  contacts (not in the release): `scene_contact`.

CLI:  motiongen import-trumans release=DIR out=DIR [joints=body] [overwrite=true]
      [progress=false] [allow_pickle=true]
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage

from motiongen.cli import parse_key_values, user_errors_exit_2
from motiongen.data.format import DEFAULT_SPLITS, DatasetWriter
from motiongen.data.occupancy import OccupancyGrid, load_npy
from motiongen.errors import DataError
from motiongen.skeleton import get_joint_set

TRUMANS_ACTIONS: tuple[str, ...] = (
    "lie down", "squat", "mouse", "keyboard", "laptop", "phone", "book", "bottle", "pen", "vase",
)
TRUMANS_FPS = 30.0
NUM_RELEASE_JOINTS = 24       # SMPL-X body joints 0..21, then left/right index1 (SMPL-X 25, 40)
NUM_OBJECT_TYPES = 35         # columns of object_flag
NUM_OBJECT_SLOTS = 5          # poses per frame in object_mat
CONTACT_RADIUS = 0.05         # metres
_CHUNK = 65536                # frames per chunk when scanning whole-release arrays


@dataclass(frozen=True)
class GridSpec:
    """Geometry of the release's scene grids: bool (X, Y, Z) voxels from `origin`, y-up."""

    shape: tuple[int, int, int] = (300, 100, 400)
    origin: tuple[float, float, float] = (-3.0, 0.0, -4.0)
    voxel_size: float = 0.02


TRUMANS_GRID = GridSpec()

# Per-frame arrays: name -> (row shape, allowed dtype kinds). Leading dim is N everywhere.
_REQUIRED = {
    "human_joints": ((NUM_RELEASE_JOINTS, 3), "f"),
    "human_orient": ((3,), "f"),
    "action_label": ((len(TRUMANS_ACTIONS),), "biuf"),
    "scene_flag": ((), "iu"),
    "object_flag": ((NUM_OBJECT_TYPES,), "iu"),
    "object_mat": ((NUM_OBJECT_SLOTS, 4, 4), "f"),
    "seg_name": ((), "US"),
}
# Frame-index lists: 1-D integers into [0, N). Their length is not pinned to N because the
# reference loader uses frame_id as its list of window starts (len(dataset) == len(frame_id)).
_INDEX_FILES = ("idx_start", "frame_id")
_OPTIONAL_SMPLX = {"human_pose": ((63,), "f"), "human_transl": ((3,), "f")}
_NUM_BETAS = 10


@dataclass
class TrumansSequence:
    name: str
    start: int        # first release frame (inclusive)
    end: int          # one past the last release frame
    scene_index: int  # index into the sorted Scene/*.npy list (the release's scene_flag)


@dataclass
class TrumansRelease:
    """A validated, memory-mapped release. Per-frame arrays are (N, ...) read-only memmaps."""

    root: Path
    num_frames: int
    arrays: dict[str, np.ndarray]                # name -> (N, ...) array (see _REQUIRED)
    smplx: dict[str, np.ndarray] | None          # human_pose (N,63), human_transl (N,3)
    betas: np.ndarray | None                     # (B,) or (N,B), B >= 10
    scene_files: list[Path]                      # sorted Scene/*.npy
    scene_ids: list[int]                         # scene id of each scene file
    scene_id_rule: str
    sequences: list[TrumansSequence]
    object_names: list[str]
    norm: dict | None = None
    grid: GridSpec = field(default_factory=GridSpec)

    def path(self, name: str) -> Path:
        return self.root / f"{name}.npy"


# ---------------------------------------------------------------------------------------
# Interpretations (each isolated so it can be changed in one place)


def scene_ids_from_names(names: list[str]) -> tuple[list[int], str]:
    """Scene id of each sorted Scene/*.npy file name, and the rule that produced them.

    If every stem holds exactly one run of digits ("scene_012", "12", "Scene12") and those
    numbers are distinct, that number is the id (the paper's split is by scene number
    1-70 / 71-80 / 91-100). Otherwise (names such as 3D-FRONT uuids, which hold many digit
    runs) every scene gets its 1-based position in the sorted list; the two rules are never
    mixed.
    """
    nums = []
    for n in names:
        runs = re.findall(r"\d+", Path(n).stem)
        nums.append(int(runs[0]) if len(runs) == 1 else None)
    if nums and all(v is not None for v in nums) and len(set(nums)) == len(nums):
        return [int(v) for v in nums], "number in file name"
    return list(range(1, len(names) + 1)), "1-based position in sorted file names"


def interpret_object_flags(flag: np.ndarray, mat: np.ndarray, path: Path, frame0: int
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Release objects of T frames -> our slots: object_ids (T,5) int32, object_poses (T,5,4,4).

    Interpretation: ``object_flag[n, t]`` (T,35) is, for object type t (the t-th object of the
    release's sorted object list), the index 0..4 of its pose in ``object_mat[n]`` (T,5,4,4), or
    -1 when type t is absent in frame n. This is how the reference loader consumes it
    (``for t, slot in enumerate(flag): if slot >= 0: pose = mat[slot]``). So our slot s holds
    object id t = the type whose flag is s. Empty slots get the identity pose (the release may
    hold anything there). Poses are copied verbatim; see the docs for the rotation caveat.
    """
    T = flag.shape[0]
    flag = np.asarray(flag).astype(np.int64)
    bad = (flag < -1) | (flag >= NUM_OBJECT_SLOTS)
    if bad.any():
        n, t = np.argwhere(bad)[0]
        raise DataError(path, "object_flag", f"value {flag[n, t]} for object type {t} at frame {frame0 + n} "
                                             f"is out of range: expected -1 or 0..{NUM_OBJECT_SLOTS - 1}")
    rows, types = np.nonzero(flag >= 0)              # (P,), (P,) present (frame, type) pairs
    slots = flag[rows, types]
    key = rows * NUM_OBJECT_SLOTS + slots
    uniq, counts = np.unique(key, return_counts=True)
    if (counts > 1).any():
        k = uniq[np.argmax(counts > 1)]
        n, s = divmod(int(k), NUM_OBJECT_SLOTS)
        clash = types[(rows == n) & (slots == s)].tolist()
        raise DataError(path, "object_flag", f"object types {clash} share pose slot {s} at frame {frame0 + n}: "
                                             f"expected each slot used by at most one type")
    ids = np.full((T, NUM_OBJECT_SLOTS), -1, np.int32)
    ids[rows, slots] = types
    mat = np.asarray(mat, np.float32)
    poses = np.where((ids >= 0)[:, :, None, None], mat, np.eye(4, dtype=np.float32))  # (T,5,4,4)
    finite = np.isfinite(poses.reshape(T, -1)).all(axis=1)
    if not finite.all():
        raise DataError(path.with_name("object_mat.npy"), "object_mat",
                        f"non-finite pose of a present object at frame {frame0 + int(np.argmin(finite))}")
    return ids, poses


def _ball_boxes(r: float) -> list[tuple[int, int, int]]:
    """Half-extents of the maximal centred boxes whose union is the digital ball |d| <= r.

    Every lattice point d of the ball lies in box(|dx|,|dy|,|dz|), which is inside the ball,
    so the ball is the union of these boxes; dilating by a box is three 1-D max filters.
    """
    R = int(np.floor(r))
    cands = [(a, b, int(np.floor(np.sqrt(r * r - a * a - b * b))))
             for a in range(R + 1) for b in range(R + 1) if a * a + b * b <= r * r]
    return [c for c in cands
            if not any(o != c and o[0] >= c[0] and o[1] >= c[1] and o[2] >= c[2] for o in cands)]


def near_occupied(occ: np.ndarray, radius_vox: float) -> np.ndarray:
    """(X,Y,Z) bool: voxels whose centre is within `radius_vox` voxels of an occupied centre."""
    u = np.ascontiguousarray(occ, dtype=bool).view(np.uint8)
    out = np.zeros(occ.shape, bool)
    for box in _ball_boxes(radius_vox):
        d = u
        for axis, h in enumerate(box):
            if h:
                d = ndimage.maximum_filter1d(d, 2 * h + 1, axis=axis, mode="constant", cval=0)
        out |= d.view(bool)
    return out


def scene_contact(joints: np.ndarray, near: OccupancyGrid, floor_y: float, radius: float) -> np.ndarray:
    """Per-joint contact (T,J) bool for joints (T,J,3): the joint's voxel is within `radius`
    of an occupied scene voxel (`near` = the grid dilated by `radius`, see `near_occupied`), or
    the joint is less than `radius` above the floor plane y = `floor_y`.

    The release has no contact labels, and its object meshes are not part of the layout we
    read, so this is scene + floor contact only: a hand holding a bottle is not in contact.
    Joints outside the grid touch nothing but the floor.
    """
    return near.occupied(joints, outside=False) | (joints[..., 1] - floor_y < radius)


# ---------------------------------------------------------------------------------------
# Opening and validation


def _load(root: Path, name: str, allow_pickle: bool = False) -> np.ndarray:
    path = root / f"{name}.npy"
    try:
        return load_npy(path, name)
    except DataError as e:
        # np.load says "pickled" without a memory map and "Python objects" with one
        if "pickled" not in e.problem and "Python objects" not in e.problem:
            raise
        if not allow_pickle:
            raise DataError(path, name, "stored as a pickled object array; pass allow_pickle=true "
                                        "only if you trust the file") from None
    try:  # pickled object arrays cannot be memory-mapped
        return np.load(path, allow_pickle=True)
    except Exception as e:  # noqa: BLE001 - any unpickling failure is a corrupt file
        raise DataError(path, name, f"not a readable .npy file ({type(e).__name__}: {e})") from None


def _check(root: Path, name: str, a: np.ndarray, N: int | None, row: tuple, kinds: str) -> None:
    path = root / f"{name}.npy"
    lead = a.shape[:1] if N is None else (N,)
    if a.shape != lead + row:
        want = ("N" if N is None else f"N={N}",) + row
        raise DataError(path, name, f"expected shape ({', '.join(map(str, want))}), found {a.shape}")
    if a.dtype.kind not in kinds:
        names = {"f": "float", "i": "int", "u": "uint", "b": "bool", "U": "str", "S": "bytes", "O": "object"}
        raise DataError(path, name, f"expected dtype {'/'.join(names[k] for k in kinds)}, found {a.dtype}")


def _scan_changes(a: np.ndarray) -> np.ndarray:
    """Frames n > 0 where a[n] != a[n-1], scanning a (N,) array in chunks."""
    out = []
    for s in range(0, a.shape[0], _CHUNK):
        block = np.asarray(a[max(s - 1, 0):s + _CHUNK])
        ch = np.nonzero(block[1:] != block[:-1])[0] + max(s - 1, 0) + 1
        out.append(ch)
    return np.unique(np.concatenate(out)) if out else np.zeros(0, np.int64)


def _scan_range(a: np.ndarray, lo: int, hi: int) -> int:
    """First index whose value is outside [lo, hi), or -1."""
    for s in range(0, a.shape[0], _CHUNK):
        block = np.asarray(a[s:s + _CHUNK]).reshape(-1)
        bad = (block < lo) | (block >= hi)
        if bad.any():
            return s + int(np.argmax(bad))
    return -1


def _seg_str(v) -> str:
    return v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)


def _object_names(root: Path) -> list[str]:
    """Names of the 35 object types: the stems of the release's sorted object point files
    (Object_chairs/Object/*.npy or Object/*.npy) when there are exactly 35, else object_NN."""
    for d in (root / "Object_chairs" / "Object", root / "Object"):
        files = sorted(d.glob("*.npy")) if d.is_dir() else []
        if len(files) == NUM_OBJECT_TYPES:
            return [f.stem for f in files]
    return [f"object_{i:02d}" for i in range(NUM_OBJECT_TYPES)]


def open_release(release_dir: str | Path, grid: GridSpec = TRUMANS_GRID, allow_pickle: bool = False) -> TrumansRelease:
    """Open and validate a release directory; raises DataError naming the file and field.

    Reads headers of every file and scans only the small per-frame index arrays (seg_name,
    scene_flag, idx_start, frame_id); joint/object values are checked while converting.
    """
    root = Path(release_dir)
    if not root.is_dir():
        raise DataError(root, None, "release directory does not exist")
    arrays: dict[str, np.ndarray] = {}
    joints = arrays["human_joints"] = _load(root, "human_joints")
    _check(root, "human_joints", joints, None, *_REQUIRED["human_joints"])
    N = joints.shape[0]
    if N == 0:
        raise DataError(root / "human_joints.npy", "human_joints", "release has no frames")
    for name, (row, kinds) in _REQUIRED.items():
        if name != "human_joints":
            arrays[name] = _load(root, name, allow_pickle=allow_pickle and name == "seg_name")
            _check(root, name, arrays[name], N, row, kinds + ("O" if name == "seg_name" else ""))
    for name in _INDEX_FILES:
        a = _load(root, name)
        if a.ndim != 1 or a.dtype.kind not in "iu":
            raise DataError(root / f"{name}.npy", name, f"expected a 1-D integer array, found {a.dtype} {a.shape}")
        bad = _scan_range(a, 0, N)
        if bad >= 0:
            raise DataError(root / f"{name}.npy", name, f"entry {bad} = {a[bad]} is not a frame index in [0, {N})")

    smplx = None
    present = {k: (root / f"{k}.npy").exists() for k in _OPTIONAL_SMPLX}
    if any(present.values()):
        missing = [k for k, p in present.items() if not p]
        if missing:
            have = [k for k, p in present.items() if p][0]
            raise DataError(root / f"{missing[0]}.npy", missing[0], f"file is missing ({have}.npy is present; "
                                                                   f"SMPL-X parameters need both)")
        smplx = {}
        for name, (row, kinds) in _OPTIONAL_SMPLX.items():
            smplx[name] = _load(root, name)
            _check(root, name, smplx[name], N, row, kinds)
    betas = None
    if smplx is not None and (root / "human_betas.npy").exists():
        betas = _load(root, "human_betas")
        ok = betas.dtype.kind == "f" and ((betas.ndim == 1 and betas.shape[0] >= _NUM_BETAS) or
                                          (betas.ndim == 2 and betas.shape[0] == N and betas.shape[1] >= _NUM_BETAS))
        if not ok:
            raise DataError(root / "human_betas.npy", "human_betas",
                            f"expected float (B,) or (N={N}, B) with B >= {_NUM_BETAS}, "
                            f"found {betas.dtype} {betas.shape}")
        if not np.isfinite(np.asarray(betas[:1] if betas.ndim == 2 else betas)).all():
            raise DataError(root / "human_betas.npy", "human_betas", "non-finite value (NaN or inf)")

    scene_dir = root / "Scene"
    if not scene_dir.is_dir():
        raise DataError(scene_dir, "Scene", "scene folder is missing")
    scene_files = sorted(scene_dir.glob("*.npy"))
    if not scene_files:
        raise DataError(scene_dir, "Scene", "scene folder holds no .npy occupancy grids")
    for f in scene_files:
        g = load_npy(f, "Scene")
        if g.shape != tuple(grid.shape) or g.dtype != np.bool_:
            raise DataError(f, "Scene", f"expected bool {tuple(grid.shape)} occupancy grid, found {g.dtype} {g.shape}")
        del g
    scene_ids, rule = scene_ids_from_names([f.name for f in scene_files])

    flag = arrays["scene_flag"]
    bad = _scan_range(flag, 0, len(scene_files))
    if bad >= 0:
        raise DataError(root / "scene_flag.npy", "scene_flag",
                        f"value {int(flag[bad])} at frame {bad} is out of range: Scene/ holds {len(scene_files)} "
                        f"grids, expected 0..{len(scene_files) - 1} (is a Scene file missing?)")
    seg = arrays["seg_name"]
    starts = np.concatenate([[0], _scan_changes(seg), [N]]).astype(np.int64)
    inner_scene_changes = np.setdiff1d(_scan_changes(flag), starts)
    if len(inner_scene_changes):
        n = int(inner_scene_changes[0])
        raise DataError(root / "scene_flag.npy", "scene_flag",
                        f"scene changes at frame {n} inside sequence {_seg_str(seg[n])!r} "
                        f"({int(flag[n - 1])} -> {int(flag[n])}): expected one scene per seg_name run")
    sequences, seen = [], {}
    for s, e in zip(starts[:-1], starts[1:]):
        name = _seg_str(seg[s])
        k = seen[name] = seen.get(name, 0) + 1
        # a name that reappears later is a separate sequence; keep names unique
        sequences.append(TrumansSequence(name if k == 1 else f"{name}~{k}", int(s), int(e), int(flag[s])))

    norm = None
    if allow_pickle and (root / "norm.npy").exists():
        norm = _load_norm(root / "norm.npy")
    return TrumansRelease(root, N, arrays, smplx, betas, scene_files, scene_ids, rule, sequences,
                          _object_names(root), norm, grid)


def _load_norm(path: Path) -> dict:
    """norm.npy: a pickled dict {str(window shape): (min, max)} -> JSON-able lists."""
    try:
        obj = np.load(path, allow_pickle=True)
        obj = obj.item() if obj.dtype == object and obj.shape == () else obj
    except Exception as e:  # noqa: BLE001 - any unpickling failure is a corrupt file
        raise DataError(path, "norm", f"not a readable .npy file ({type(e).__name__}: {e})") from None
    if not isinstance(obj, dict):
        raise DataError(path, "norm", f"expected a pickled dict of (min, max), found {type(obj).__name__}")
    try:
        return {str(k): {"min": np.asarray(v[0], np.float64).tolist(), "max": np.asarray(v[1], np.float64).tolist()}
                for k, v in obj.items()}
    except (TypeError, IndexError, ValueError) as e:
        raise DataError(path, "norm", f"expected each value to be a (min, max) pair ({e})") from None


# ---------------------------------------------------------------------------------------
# Conversion


def _finite_rows(a: np.ndarray, path: Path, name: str, frame0: int) -> None:
    ok = np.isfinite(a.reshape(a.shape[0], -1)).all(axis=1)
    if not ok.all():
        raise DataError(path, name, f"non-finite value (NaN or inf) at frame {frame0 + int(np.argmin(ok))}")


def _sequence_arrays(rel: TrumansRelease, seq: TrumansSequence, joint_idx: list[int], near: OccupancyGrid,
                     radius: float) -> dict:
    """Everything `DatasetWriter.add_sequence` needs for one release sequence."""
    s, e = seq.start, seq.end
    A = rel.arrays
    joints = np.asarray(A["human_joints"][s:e], np.float32)[:, joint_idx]      # (T,J,3)
    _finite_rows(joints, rel.path("human_joints"), "human_joints", s)
    labels = np.asarray(A["action_label"][s:e])                                 # (T,10)
    if labels.dtype.kind == "f":
        _finite_rows(labels, rel.path("action_label"), "action_label", s)
    actions = labels >= 0.5 if labels.dtype.kind != "b" else labels             # (T,10) bool
    contact = scene_contact(joints, near, rel.grid.origin[1], radius)           # (T,J) bool
    ids, poses = interpret_object_flags(np.asarray(A["object_flag"][s:e]), np.asarray(A["object_mat"][s:e]),
                                        rel.path("object_flag"), s)
    smplx = None
    if rel.smplx is not None:
        smplx = {"global_orient": np.asarray(A["human_orient"][s:e], np.float32),     # (T,3) axis-angle
                 "body_pose": np.asarray(rel.smplx["human_pose"][s:e], np.float32),   # (T,63)
                 "transl": np.asarray(rel.smplx["human_transl"][s:e], np.float32)}    # (T,3)
        for k, src in (("global_orient", "human_orient"), ("body_pose", "human_pose"), ("transl", "human_transl")):
            _finite_rows(smplx[k], rel.path(src), src, s)
        if rel.betas is None:
            smplx["betas"] = np.zeros(_NUM_BETAS, np.float32)                 # mean shape
        elif rel.betas.ndim == 1:
            smplx["betas"] = np.asarray(rel.betas[:_NUM_BETAS], np.float32)
        else:
            smplx["betas"] = np.asarray(rel.betas[s:e, :_NUM_BETAS], np.float32)      # (T,10)
            _finite_rows(smplx["betas"], rel.path("human_betas"), "human_betas", s)
    return dict(joints=joints, actions=actions, contact=contact, object_ids=ids, object_poses=poses, smplx=smplx)


def convert_trumans(release_dir: str | Path, out_dir: str | Path, joints: str = "body+index1",
                    overwrite: bool = False, progress: bool = True, *, allow_pickle: bool = False,
                    grid: GridSpec = TRUMANS_GRID, contact_radius: float = CONTACT_RADIUS) -> Path:
    """Convert a TRUMANS ``Data_release/`` directory into a motiongen dataset at `out_dir`.

    joints: "body+index1" keeps all 24 release joints, "body" the first 22.
    allow_pickle: trust pickled files: load norm.npy (recorded in meta.json as
    ``trumans.norm``) and accept a seg_name.npy stored as an object array. Off by default.
    grid: geometry of Scene/*.npy (the release's; smaller only for tests).
    Returns the dataset path. On any error nothing is left at `out_dir` (an existing dataset
    there is only replaced, atomically, when the conversion succeeds and `overwrite` is set).
    """
    js = get_joint_set(joints)
    out = Path(out_dir)
    if out.exists() and not overwrite:
        raise DataError(out, None, "output directory already exists (pass overwrite=true)")
    rel = open_release(release_dir, grid=grid, allow_pickle=allow_pickle)
    joint_idx = list(range(js.num_joints))  # release order is body 0..21 then index1 L/R, as ours
    log = (lambda msg: print(msg, file=sys.stderr, flush=True)) if progress else (lambda msg: None)

    by_scene: dict[int, list[TrumansSequence]] = {}
    for seq in rel.sequences:
        by_scene.setdefault(seq.scene_index, []).append(seq)
    writer = DatasetWriter(out, js, list(TRUMANS_ACTIONS), fps=TRUMANS_FPS, num_object_slots=NUM_OBJECT_SLOTS,
                           has_smplx=rel.smplx is not None, overwrite=overwrite)
    try:
        for oid, name in enumerate(rel.object_names):
            writer.add_object(oid, name=name, type=re.sub(r"[_\-\s]*\d+$", "", name) or name)
        for si, (path, sid) in enumerate(zip(rel.scene_files, rel.scene_ids)):
            occ = np.asarray(np.load(path, mmap_mode="r"))                # (X,Y,Z) bool, ~12 MB
            writer.add_scene(sid, grid=OccupancyGrid.from_dense(occ, grid.origin, grid.voxel_size), name=path.stem)
            seqs = by_scene.get(si, [])
            if seqs:
                near = OccupancyGrid.from_dense(near_occupied(occ, contact_radius / grid.voxel_size),
                                                grid.origin, grid.voxel_size)
                for seq in seqs:
                    writer.add_sequence(seq.name, scene=sid, **_sequence_arrays(rel, seq, joint_idx, near,
                                                                                contact_radius))
            del occ
            log(f"trumans: scene {si + 1}/{len(rel.scene_files)} {path.name} (id {sid}): {len(seqs)} sequences, "
                f"{sum(s.end - s.start for s in seqs)} frames")
        extra = {"trumans": {
            "release": str(rel.root.resolve()),
            "scene_files": {str(sid): p.name for sid, p in zip(rel.scene_ids, rel.scene_files)},
            "scene_id_rule": rel.scene_id_rule,
            "contact": f"scene voxel within {contact_radius} m (voxel centres) or joint < {contact_radius} m "
                       f"above the floor y={grid.origin[1]}",
            "object_flag": "object_flag[n, type] = slot in object_mat[n] (-1 absent); object id = type",
            "norm": rel.norm,
        }}
        return writer.finish(splits=DEFAULT_SPLITS, source="trumans", extra=extra)
    except BaseException:
        writer.abort()
        raise


# ---------------------------------------------------------------------------------------
# CLI

_CLI_SPEC = {"release": (str, None), "out": (str, None), "joints": (str, "body+index1"), "overwrite": (bool, False),
             "progress": (bool, True), "allow_pickle": (bool, False)}


def parse_cli(argv: list[str]) -> dict:
    """key=value arguments -> convert_trumans kwargs; ConfigError on anything else."""
    return parse_key_values(argv, _CLI_SPEC, required=("release", "out"),
                            usage="motiongen import-trumans release=DIR out=DIR", doc=__doc__.split("CLI:")[1])


@user_errors_exit_2
def main(argv: list[str] | None = None) -> int:
    kw = parse_cli(sys.argv[1:] if argv is None else list(argv))
    path = convert_trumans(kw.pop("release"), kw.pop("out"), **kw)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
