"""Writing the motiongen dataset format (docs/data_format.md): `DatasetWriter` streams
sequences into raw per-frame columns in a temp directory and publishes the dataset with one
directory rename (`staging.replace_dir`), so `root` is either the complete new dataset or what
was there before."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from motiongen.data.columns import RawColumn
from motiongen.data.schema import DEFAULT_SPLITS, FORMAT_NAME, FORMAT_VERSION, SMPLX_FIELDS
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.errors import DataError
from motiongen.output_lock import OutputLock
from motiongen.skeleton import JointSet
from motiongen.staging import replace_dir



class DatasetWriter:
    """Streams sequences, scenes and objects into a new dataset directory.

    Everything is written under ``<root>.partial-<pid>``; `finish` renames it to `root`, so a
    crash never leaves a half-written dataset where a reader would find it.

        w = DatasetWriter(root, joint_set=BODY, actions=[...], fps=30, num_object_slots=2)
        w.add_scene(1, grid=grid, mesh=mesh)
        w.add_object(0, name="cup_0", type="cup", mesh=cup_mesh)
        w.add_sequence("walk_000", scene=1, joints=..., actions=..., contact=..., ...)
        w.finish(splits=DEFAULT_SPLITS, source="synthetic")
    """

    def __init__(self, root: str | Path, joint_set: JointSet, actions: list[str], fps: float,
                 num_object_slots: int = 0, has_smplx: bool = False, overwrite: bool = False):
        self.root = Path(root)
        if self.root.exists() and not overwrite:
            raise DataError(self.root, None, "dataset directory already exists (pass overwrite)")
        if self.root.exists() and not _is_dataset_or_empty(self.root):
            # overwrite deletes `root`: never do that to something that is not ours
            raise DataError(self.root, None, "refusing to overwrite: not a dataset directory (no meta.json) "
                                             "and not empty")
        lock = OutputLock(self.root, "dataset")
        if self.root.exists() and lock.holder() is not None:
            raise lock.busy_error()                       # annotate-contact is writing labels into it
        self.tmp = self.root.with_name(self.root.name + f".partial-{os.getpid()}")
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        try:
            (self.tmp / "scenes").mkdir(parents=True)
            (self.tmp / "objects").mkdir()
        except OSError as e:                              # /proc/x, a read-only disk, a file as parent
            shutil.rmtree(self.tmp, ignore_errors=True)
            raise DataError(self.root, None, f"cannot create the dataset here ({e.strerror})") from None
        self.joint_set, self.actions, self.fps = joint_set, list(actions), float(fps)
        self.K, self.has_smplx, self.overwrite = int(num_object_slots), bool(has_smplx), overwrite
        J, A, K = joint_set.num_joints, len(self.actions), self.K
        col = lambda name, shape, dt: RawColumn(self.tmp / f"{name}.npy", shape, dt)  # noqa: E731
        self.cols = {"joints": col("joints", (J, 3), np.float32), "scene_id": col("scene_id", (), np.int32),
                     "contact": col("contact", (J,), bool), "actions": col("actions", (A,), bool)}
        if K:
            self.cols["object_poses"] = col("object_poses", (K, 4, 4), np.float32)
            self.cols["object_ids"] = col("object_ids", (K,), np.int32)
        if has_smplx:
            for k, d in SMPLX_FIELDS.items():
                self.cols[f"smplx_{k}"] = col(f"smplx_{k}", (d,), np.float32)
        self.sequences: list[dict] = []
        self.scenes: dict[int, dict] = {}
        self.objects: dict[int, dict] = {}
        self.frames = 0

    def add_scene(self, scene_id: int, grid: OccupancyGrid | None = None, mesh=None, name: str | None = None) -> None:
        """A scene: its occupancy grid and/or its mesh (a trimesh.Trimesh, saved as .ply)."""
        scene_id = int(scene_id)
        stem = f"scene_{scene_id:03d}"
        entry: dict = {"name": name or stem, "grid": None, "mesh": None}
        if grid is not None:
            grid.save(self.tmp / "scenes" / stem)
            entry["grid"] = f"scenes/{stem}"
        if mesh is not None:
            mesh.export(self.tmp / "scenes" / f"{stem}.ply")
            entry["mesh"] = f"scenes/{stem}.ply"
        self.scenes[scene_id] = entry

    def add_object(self, object_id: int, name: str, type: str, mesh=None) -> None:
        entry = {"name": name, "type": type, "mesh": None}
        if mesh is not None:
            mesh.export(self.tmp / "objects" / f"{name}.ply")
            entry["mesh"] = f"objects/{name}.ply"
        self.objects[int(object_id)] = entry

    def add_sequence(self, name: str, scene: int, joints, actions, contact, object_poses=None,
                     object_ids=None, smplx: dict | None = None) -> None:
        """One sequence of T frames: joints (T,J,3), actions (T,A) bool, contact (T,J) bool,
        object_poses (T,K,4,4) and object_ids (T,K) (-1 = empty slot), smplx {field: (T,d)}."""
        T = len(joints)
        if T == 0:
            raise ValueError(f"sequence {name!r} is empty")
        self.cols["joints"].append(joints)
        self.cols["scene_id"].append(np.full(T, scene, np.int32))
        self.cols["contact"].append(contact)
        self.cols["actions"].append(actions)
        if self.K:
            self.cols["object_poses"].append(np.broadcast_to(np.eye(4, dtype=np.float32), (T, self.K, 4, 4))
                                             if object_poses is None else object_poses)
            self.cols["object_ids"].append(np.full((T, self.K), -1, np.int32) if object_ids is None else object_ids)
        if self.has_smplx:
            if smplx is None:
                raise ValueError(f"sequence {name!r}: dataset has SMPL-X parameters but none given")
            for k, d in SMPLX_FIELDS.items():
                v = np.asarray(smplx[k], np.float32)
                self.cols[f"smplx_{k}"].append(np.broadcast_to(v, (T, d)) if v.ndim == 1 else v)
        for c in self.cols.values():
            if c.rows != self.frames + T:
                raise ValueError(f"sequence {name!r}: {c.path.stem} has {c.rows - self.frames} rows, expected {T}")
        self.sequences.append({"name": name, "start": self.frames, "end": self.frames + T, "scene": int(scene)})
        self.frames += T

    def finish(self, splits: dict[str, list[int]] | None = None, source: str = "unknown", extra: dict | None = None) -> Path:
        for c in self.cols.values():
            c.finish()
        meta = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "source": source, "fps": self.fps,
                "units": "m", "up": "y", "num_frames": self.frames, "joint_set": self.joint_set.name,
                "joint_names": list(self.joint_set.names), "actions": self.actions,
                "num_object_slots": self.K, "has_smplx": self.has_smplx,
                "splits": splits or DEFAULT_SPLITS, **(extra or {})}
        _write_json(self.tmp / "meta.json", meta)
        _write_json(self.tmp / "sequences.json", self.sequences)
        _write_json(self.tmp / "scenes.json", {str(k): v for k, v in sorted(self.scenes.items())})
        _write_json(self.tmp / "objects.json", {str(k): v for k, v in sorted(self.objects.items())})
        return replace_dir(self.tmp, self.root)    # the old dataset stays until the new one is in place

    def abort(self) -> None:
        for c in self.cols.values():
            c.f.close()
        shutil.rmtree(self.tmp, ignore_errors=True)


def _is_dataset_or_empty(path: Path) -> bool:
    return path.is_dir() and ((path / "meta.json").is_file() or not any(path.iterdir()))


def _write_json(path: Path, obj) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1))
    os.replace(tmp, path)
