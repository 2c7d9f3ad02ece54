"""The motiongen on-disk dataset format (documented in docs/data_format.md).

Every source (synthetic generator, TRUMANS release, BVH) converts into this one layout.
Per-frame arrays are concatenated over all sequences and memory-mapped on open, so RAM does
not grow with the dataset. This module holds the layout's constants and the reader:
`MotionDataset.open` validates everything at open time. Writing: `motiongen.data.dataset_writer`
(`DatasetWriter` streams sequences to disk and publishes the dataset with one directory rename).
"""

from __future__ import annotations

import json
import mmap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from motiongen.data.contact_labels import VertexContact
from motiongen.data.schema import DEFAULT_SPLITS, FORMAT_NAME, FORMAT_VERSION, SMPLX_FIELDS  # noqa: F401 (the format's names)
from motiongen.scene.occupancy import OccupancyGrid, load_npy
from motiongen.errors import DataError
from motiongen.skeleton import JointSet, joint_set_for



@dataclass
class Sequence:
    name: str
    start: int   # first frame (inclusive) in the concatenated arrays
    end: int     # one past the last frame
    scene: int   # scene id

    @property
    def num_frames(self) -> int:
        return self.end - self.start


# ---------------------------------------------------------------------------------------
# Reading


def _read_json(path: Path, what: str):
    if not path.is_file():
        raise DataError(path, None, f"{what} file is missing")
    try:
        return json.loads(path.read_text())
    except ValueError as e:
        raise DataError(path, None, f"malformed JSON ({e})") from None


def _read_index(path: Path, what: str) -> dict[int, dict]:
    """scenes.json / objects.json: {"<int id>": {...}} -> {id: entry}."""
    raw = _read_json(path, what)
    if not isinstance(raw, dict):
        raise DataError(path, None, f"expected an object mapping ids to entries, found {type(raw).__name__}")
    out = {}
    for k, v in raw.items():
        try:
            i = int(k)
        except ValueError:
            raise DataError(path, k, "expected an integer id as the key") from None
        if not isinstance(v, dict):
            raise DataError(path, k, f"expected an object entry, found {v!r:.60}")
        out[i] = v
    return out


def _all_finite_chunked(a: np.ndarray, chunk_rows: int = 65536) -> int:
    """Index of the first row with a non-finite value, or -1. Reads in chunks and drops the
    pages afterwards so validation of a large memmap does not leave it resident."""
    for s in range(0, a.shape[0], chunk_rows):
        block = np.asarray(a[s:s + chunk_rows])
        bad = ~np.isfinite(block.reshape(block.shape[0], -1)).all(axis=1)
        if bad.any():
            return s + int(np.argmax(bad))
    release(a)
    return -1


def release(a: np.ndarray) -> None:
    """Drop a memmap's resident pages (they are re-read from the file on demand)."""
    mm = getattr(a, "_mmap", None)
    if mm is None and isinstance(getattr(a, "base", None), np.memmap):
        mm = getattr(a.base, "_mmap", None)
    if mm is not None and hasattr(mm, "madvise"):
        try:
            mm.madvise(mmap.MADV_DONTNEED)
        except (OSError, ValueError):
            pass


@dataclass
class MotionDataset:
    """An opened, validated dataset. Arrays are read-only memory maps.

    joints (N,J,3) float32 · scene_id (N,) int32 · contact (N,J) bool · actions (N,A) bool ·
    object_poses (N,K,4,4) float32 / object_ids (N,K) int32 when K > 0 · smplx {field: (N,d)}.
    """

    root: Path
    meta: dict
    sequences: list[Sequence]
    joints: np.ndarray
    scene_id: np.ndarray
    contact: np.ndarray
    actions: np.ndarray
    object_poses: np.ndarray | None
    object_ids: np.ndarray | None
    smplx: dict[str, np.ndarray] | None
    scenes: dict[int, dict]
    objects: dict[int, dict]
    splits: dict[str, list[int]]
    _grids: dict = field(default_factory=dict, repr=False)
    _meshes: dict = field(default_factory=dict, repr=False)

    @property
    def fps(self) -> float:
        return float(self.meta["fps"])

    @property
    def joint_set(self) -> JointSet:
        return joint_set_for(self.meta["joint_names"])

    @property
    def action_names(self) -> list[str]:
        return list(self.meta["actions"])

    @property
    def num_frames(self) -> int:
        return int(self.meta["num_frames"])

    def split_of_scene(self, scene: int) -> str | None:
        for name, ids in self.splits.items():
            if scene in ids:
                return name
        return None

    def split_sequences(self, split: str | None) -> list[Sequence]:
        """Sequences whose scene belongs to `split` (all sequences for None)."""
        if split is None:
            return list(self.sequences)
        if split not in self.splits:
            raise DataError(self.root / "meta.json", "splits", f"no split named {split!r}; have {sorted(self.splits)}")
        ids = set(self.splits[split])
        return [s for s in self.sequences if s.scene in ids]

    def grid(self, scene: int) -> OccupancyGrid:
        """The scene's occupancy grid (memory-mapped, cached)."""
        if scene not in self._grids:
            entry = self.scenes.get(scene)
            if entry is None or entry.get("grid") is None:
                raise DataError(self.root / "scenes.json", str(scene), "scene has no occupancy grid")
            self._grids[scene] = OccupancyGrid.load(self.root / entry["grid"])
        return self._grids[scene]

    def scene_mesh(self, scene: int):
        """The scene's trimesh mesh, or None when the dataset has only a grid."""
        entry = self.scenes.get(scene) or {}
        if not entry.get("mesh"):
            return None
        if scene not in self._meshes:
            import trimesh  # slow to import; only datasets with scene meshes need it
            self._meshes[scene] = trimesh.load(self.root / entry["mesh"], force="mesh", process=False)
        return self._meshes[scene]

    def vertex_contact(self):
        """The optional per-vertex contact labels (``vertex_contact/``, written by
        `motiongen.annotation.annotate_contact`) as a memory-mapped
        `motiongen.data.contact_labels.VertexContact`, or None when the dataset has none."""

        return VertexContact.open(self.root, self.num_frames, list(self.joint_set.names))

    def object_mesh(self, object_id: int):
        entry = self.objects.get(object_id) or {}
        if not entry.get("mesh"):
            return None
        import trimesh  # slow to import; only datasets with object meshes need it
        return trimesh.load(self.root / entry["mesh"], force="mesh", process=False)

    @classmethod
    def open(cls, root: str | Path, splits: dict[str, list[int]] | None = None, check_values: bool = True) -> "MotionDataset":
        """Open and validate a dataset directory. Raises DataError naming file and field."""
        root = Path(root)
        if not root.is_dir():
            raise DataError(root, None, "dataset directory does not exist")
        meta = _read_meta(root / "meta.json")
        N, J, A, K = meta["num_frames"], len(meta["joint_names"]), len(meta["actions"]), meta["num_object_slots"]
        joints = _read_array(root, "joints", (N, J, 3), np.float32, check_values)
        scene_id = _read_array(root, "scene_id", (N,), np.int32, check_values)
        contact = _read_array(root, "contact", (N, J), bool, check_values)
        actions = _read_array(root, "actions", (N, A), bool, check_values)
        object_poses = object_ids = None
        if K:
            object_poses = _read_array(root, "object_poses", (N, K, 4, 4), np.float32, check_values)
            object_ids = _read_array(root, "object_ids", (N, K), np.int32, check_values)
        smplx = None
        if meta["has_smplx"]:
            smplx = {k: _read_array(root, f"smplx_{k}", (N, d), np.float32, check_values) for k, d in SMPLX_FIELDS.items()}
        sequences = _read_sequences(root / "sequences.json", N)
        scenes = _read_index(root / "scenes.json", "scene index")
        objects = _read_index(root / "objects.json", "object index")
        _check_listed_files(root, scenes, objects)
        if check_values:
            _check_scene_ids(root, sequences, scenes, scene_id)
            if K:
                bad = _bad_object_id(object_ids, set(objects))
                if bad is not None:
                    raise DataError(root / "object_ids.npy", "object_ids", f"object id {bad} is not in objects.json")
        split_map = _split_map(splits, meta, root / "meta.json")
        return cls(root, meta, sequences, joints, scene_id, contact, actions, object_poses, object_ids, smplx,
                   scenes, objects, split_map)

    def iter_sequences(self, split: str | None = None) -> Iterator[tuple[Sequence, np.ndarray]]:
        for s in self.split_sequences(split):
            yield s, np.asarray(self.joints[s.start:s.end])


# ---------------------------------------------------------------------------------------
# The checks `MotionDataset.open` makes, file by file


def _read_meta(meta_path: Path) -> dict:
    """meta.json, with its format, version and required keys checked."""
    meta = _read_json(meta_path, "dataset metadata")
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        raise DataError(meta_path, "format", f"expected {FORMAT_NAME!r}, found {meta.get('format') if isinstance(meta, dict) else type(meta).__name__!r}")
    if meta.get("version") != FORMAT_VERSION:
        raise DataError(meta_path, "version", f"expected {FORMAT_VERSION}, found {meta.get('version')!r}")
    for key in ("fps", "num_frames", "joint_names", "actions", "num_object_slots", "has_smplx"):
        if key not in meta:
            raise DataError(meta_path, key, "required key is missing")
    if not (isinstance(meta["fps"], (int, float)) and meta["fps"] > 0):
        raise DataError(meta_path, "fps", f"expected a positive number, found {meta['fps']!r}")
    try:
        joint_set_for(meta["joint_names"])
    except Exception as e:
        raise DataError(meta_path, "joint_names", str(e)) from None
    for key in ("num_frames", "num_object_slots"):
        if not (isinstance(meta[key], int) and not isinstance(meta[key], bool) and meta[key] >= 0):
            raise DataError(meta_path, key, f"expected a non-negative integer, found {meta[key]!r}")
    if not isinstance(meta["has_smplx"], bool):
        raise DataError(meta_path, "has_smplx", f"expected true or false, found {meta['has_smplx']!r}")
    if not (isinstance(meta["actions"], list) and all(isinstance(a, str) for a in meta["actions"])):
        raise DataError(meta_path, "actions", f"expected a list of strings, found {meta['actions']!r}")
    return meta


def _read_array(root: Path, name: str, shape: tuple, dtype, check_values: bool) -> np.ndarray:
    """<name>.npy memory-mapped, with its shape, dtype and (check_values) finiteness checked."""
    path = root / f"{name}.npy"
    a = load_npy(path, name)
    if a.shape != shape:
        raise DataError(path, name, f"expected shape {shape}, found {a.shape}")
    if a.dtype != np.dtype(dtype):
        raise DataError(path, name, f"expected dtype {np.dtype(dtype)}, found {a.dtype}")
    if check_values and a.dtype.kind == "f":
        bad = _all_finite_chunked(a)
        if bad >= 0:
            raise DataError(path, name, f"non-finite value (NaN or inf) at frame {bad}")
    return a


def _read_sequences(seq_path: Path, N: int) -> list[Sequence]:
    """sequences.json: entries that tile the N frames in order."""
    raw_seqs = _read_json(seq_path, "sequence list")
    try:
        sequences = [Sequence(str(s["name"]), int(s["start"]), int(s["end"]), int(s["scene"])) for s in raw_seqs]
    except (KeyError, TypeError, ValueError) as e:
        raise DataError(seq_path, None, f"each entry needs name, start, end, scene ({e})") from None
    pos = 0
    for s in sequences:
        if s.start != pos or s.end <= s.start:
            raise DataError(seq_path, s.name, f"sequences must tile the frames in order: expected start {pos} "
                                              f"and end > start, found [{s.start}, {s.end})")
        pos = s.end
    if pos != N:
        raise DataError(seq_path, None, f"sequences cover {pos} frames, meta.json says {N}")
    return sequences


def _check_listed_files(root: Path, scenes: dict[int, dict], objects: dict[int, dict]) -> None:
    """Every grid and mesh file that scenes.json and objects.json list exists."""
    for sid, entry in scenes.items():
        for key in ("grid", "mesh"):
            if entry.get(key):
                # a grid is two files (<stem>.occ.npy + .occ.json); both must be there
                for suffix in ((".occ.npy", ".occ.json") if key == "grid" else ("",)):
                    p = root / (entry[key] + suffix)
                    if not p.is_file():
                        raise DataError(p, f"scene {sid} {key}", "file listed in scenes.json is missing")
    for oid, entry in objects.items():
        if entry.get("mesh") and not (root / entry["mesh"]).is_file():
            raise DataError(root / entry["mesh"], f"object {oid}", "file listed in objects.json is missing")


def _check_scene_ids(root: Path, sequences: list[Sequence], scenes: dict[int, dict], scene_id: np.ndarray) -> None:
    """Every sequence's scene is in scenes.json and every one of its frames carries its id."""
    seq_path = root / "sequences.json"
    for s in sequences:
        if s.scene not in scenes:
            raise DataError(seq_path, s.name, f"scene id {s.scene} is not in scenes.json")
        ids = np.asarray(scene_id[s.start:s.end])
        if not (ids == s.scene).all():
            n = s.start + int(np.argmax(ids != s.scene))
            raise DataError(root / "scene_id.npy", "scene_id", f"frame {n} has scene id {int(scene_id[n])}, "
                                                              f"but frames of sequence {s.name!r} must all "
                                                              f"carry its scene id {s.scene}")
    release(scene_id)


def _split_map(splits: dict | None, meta: dict, meta_path: Path) -> dict[str, list[int]]:
    """{split name: scene ids}: `splits` when given, else meta.json's, else the defaults."""
    split_map = splits if splits is not None else meta.get("splits", DEFAULT_SPLITS)
    try:
        return {str(k): [int(i) for i in v] for k, v in split_map.items()}
    except (AttributeError, TypeError, ValueError):
        raise DataError(meta_path if splits is None else "splits argument", "splits", f"expected an object of split name -> list of scene ids, "
                                             f"found {split_map!r:.80}") from None


def _bad_object_id(ids: np.ndarray, known: set[int]) -> int | None:
    for s in range(0, ids.shape[0], 262144):
        u = np.unique(np.asarray(ids[s:s + 262144]))
        for v in u:
            if v != -1 and int(v) not in known:
                return int(v)
    release(ids)
    return None
