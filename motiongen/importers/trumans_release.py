"""Reading the public TRUMANS release (``Data_release/``): its layout (`TrumansRelease`,
`TrumansSequence`, `GridSpec`), `open_release` with every check made at open (presence,
shapes, dtypes, cross-file N, index ranges), and the interpretations of its fields, each in one
place (`scene_ids_from_names`, `interpret_object_flags`). Conversion: `motiongen.importers.trumans`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from motiongen.scene.occupancy import load_npy
from motiongen.errors import DataError

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
_NUM_BETAS = 10                # betas the release stores per frame (the converter reads them too)


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


# ---------------------------------------------------------------------------------------
# Opening and validation


def _load(root: Path, name: str, allow_pickle: bool | None = None) -> np.ndarray:
    """`root/name.npy`. allow_pickle: the user's allow_pickle= for an array the release may store
    pickled (seg_name); None for one that must be plain numbers whatever allow_pickle= says."""
    path = root / f"{name}.npy"
    try:
        return load_npy(path, name)
    except DataError as e:
        # np.load says "pickled" without a memory map and "Python objects" with one
        if "pickled" not in e.problem and "Python objects" not in e.problem:
            raise
        if allow_pickle is None:                         # the key would not help: say what is wrong
            raise DataError(path, name, "stored as a pickled object array; expected a plain numeric array "
                                        "(allow_pickle= applies to seg_name and norm.npy only)") from None
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
    arrays = _frame_arrays(root, allow_pickle)
    N = arrays["human_joints"].shape[0]
    smplx, betas = _smplx_arrays(root, N)
    scene_files = _scene_files(root, grid)
    scene_ids, rule = scene_ids_from_names([f.name for f in scene_files])
    sequences = _sequences(root, arrays, N, len(scene_files))
    norm = None
    if allow_pickle and (root / "norm.npy").exists():
        norm = _load_norm(root / "norm.npy")
    return TrumansRelease(root, N, arrays, smplx, betas, scene_files, scene_ids, rule, sequences,
                          _object_names(root), norm, grid)


def _frame_arrays(root: Path, allow_pickle: bool) -> dict[str, np.ndarray]:
    """The required per-frame arrays (`_REQUIRED`, all of N frames) and a check of the frame-index
    lists (`_INDEX_FILES`)."""
    arrays: dict[str, np.ndarray] = {}
    joints = arrays["human_joints"] = _load(root, "human_joints")
    _check(root, "human_joints", joints, None, *_REQUIRED["human_joints"])
    N = joints.shape[0]
    if N == 0:
        raise DataError(root / "human_joints.npy", "human_joints", "release has no frames")
    for name, (row, kinds) in _REQUIRED.items():
        if name != "human_joints":
            arrays[name] = _load(root, name, allow_pickle=allow_pickle if name == "seg_name" else None)
            _check(root, name, arrays[name], N, row, kinds + ("O" if name == "seg_name" else ""))
    for name in _INDEX_FILES:
        a = _load(root, name)
        if a.ndim != 1 or a.dtype.kind not in "iu":
            raise DataError(root / f"{name}.npy", name, f"expected a 1-D integer array, found {a.dtype} {a.shape}")
        bad = _scan_range(a, 0, N)
        if bad >= 0:
            raise DataError(root / f"{name}.npy", name, f"entry {bad} = {a[bad]} is not a frame index in [0, {N})")
    return arrays


def _smplx_arrays(root: Path, N: int) -> tuple[dict[str, np.ndarray] | None, np.ndarray | None]:
    """The optional SMPL-X parameters (`_OPTIONAL_SMPLX`: both or neither) and their betas."""
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
    return smplx, betas


def _scene_files(root: Path, grid: GridSpec) -> list[Path]:
    """The sorted Scene/*.npy occupancy grids, each checked against `grid`."""
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
    return scene_files


def _sequences(root: Path, arrays: dict[str, np.ndarray], N: int, num_scenes: int) -> list[TrumansSequence]:
    """The release's sequences: runs of equal seg_name, each in one scene of the `num_scenes`."""
    flag = arrays["scene_flag"]
    bad = _scan_range(flag, 0, num_scenes)
    if bad >= 0:
        raise DataError(root / "scene_flag.npy", "scene_flag",
                        f"value {int(flag[bad])} at frame {bad} is out of range: Scene/ holds {num_scenes} "
                        f"grids, expected 0..{num_scenes - 1} (is a Scene file missing?)")
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
    return sequences


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
