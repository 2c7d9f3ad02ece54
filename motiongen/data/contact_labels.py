"""On-disk per-vertex contact labels of a dataset: the optional ``<root>/vertex_contact/``
folder (docs/data_format.md, "Per-vertex contact"). Written by
`motiongen.annotation.annotate_contact` and the augmentation tool, read memory-mapped through
`MotionDataset.vertex_contact()`.

    info.json          format, version, num_frames N, num_vertices V, joint_names, targets,
                       config, body, penetration summary
    bits.npy           (N, ceil(V/8)) uint8   contact bits, np.packbits along vertices (big)
    offsets.npy        (N+1,) int64           frame n's contact vertices are entries
                                              offsets[n]:offsets[n+1] of the two arrays below
    target.npy         (M,) int32             target of each contact vertex (vertex order):
                                              -2 floor, -3 scene, >= 0 object id
    distance.npy       (M,) float32           its signed distance, m (< 0: penetration)
    joints.npy         (N, J) int32           per joint: the target most of its vertices touch, -1 none
    penetration.npy    (N, 3) float32         per frame max / mean / median penetration depth (m)
                                              over penetrating vertices, 0 when none
    penetrating.npy    (N,) int32             number of penetrating vertices per frame
    smplx_<field>.npy  (N, d) float32         the body the labels were computed on, when it is not
                                              the dataset's own SMPL-X (fitted to the joints)

The folder is written as ``vertex_contact.partial-<pid>`` and renamed into place, so a reader
sees the old labels or the new ones, never half of either.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from motiongen.data.schema import SMPLX_FIELDS
from motiongen.data.columns import RawColumn
from motiongen.scene.occupancy import load_npy
from motiongen.errors import DataError
from motiongen.staging import replace_dir

FOLDER = "vertex_contact"
FORMAT_NAME = "motiongen-vertex-contact"
FORMAT_VERSION = 1


class VertexContactWriter:
    """Streams the labels of consecutive frames (sequence by sequence, in dataset order)."""

    def __init__(self, dataset_root: str | Path, num_vertices: int, num_joints: int, overwrite: bool = False,
                 smplx: bool = False):
        self.root = Path(dataset_root)
        self.final = self.root / FOLDER
        if self.final.exists() and not overwrite:
            raise DataError(self.final, None, "per-vertex contact labels already exist (pass overwrite=true)")
        self.tmp = self.root / f"{FOLDER}.partial-{os.getpid()}"
        if self.tmp.exists():
            shutil.rmtree(self.tmp)
        self.tmp.mkdir(parents=True)
        self.V, self.J = int(num_vertices), int(num_joints)
        col = lambda name, shape, dt: RawColumn(self.tmp / f"{name}.npy", shape, dt)  # noqa: E731
        self.cols = {"bits": col("bits", ((self.V + 7) // 8,), np.uint8), "target": col("target", (), np.int32),
                     "distance": col("distance", (), np.float32), "joints": col("joints", (self.J,), np.int32),
                     "penetration": col("penetration", (3,), np.float32),
                     "penetrating": col("penetrating", (), np.int32)}
        if smplx:
            for k, d in SMPLX_FIELDS.items():
                self.cols[f"smplx_{k}"] = col(f"smplx_{k}", (d,), np.float32)
        self.offsets = [np.zeros(1, np.int64)]
        self.frames = 0

    def add(self, target: np.ndarray, distance: np.ndarray, joints: np.ndarray, penetration: np.ndarray,
            penetrating: np.ndarray, smplx: dict | None = None) -> None:
        """Frames (T, V) target int32 (-1 none) and distance float32, (T, J) joint targets,
        (T, 3) penetration, (T,) penetrating counts, smplx {field: (T, d) or (d,)}."""
        contact = target != -1                                                        # (T, V)
        T = len(target)
        f, v = np.nonzero(contact)
        self.cols["bits"].append(np.packbits(contact, axis=1, bitorder="big"))
        self.cols["target"].append(target[f, v])
        self.cols["distance"].append(distance[f, v])
        self.cols["joints"].append(joints)
        self.cols["penetration"].append(penetration)
        self.cols["penetrating"].append(penetrating)
        if "smplx_transl" in self.cols:
            for k, d in SMPLX_FIELDS.items():
                a = np.asarray(smplx[k], np.float32)
                self.cols[f"smplx_{k}"].append(np.broadcast_to(a, (T, d)) if a.ndim == 1 else a)
        self.offsets.append(self.offsets[-1][-1] + np.cumsum(contact.sum(1), dtype=np.int64))
        self.frames += T

    def finish(self, info: dict) -> Path:
        for c in self.cols.values():
            c.finish()
        np.save(self.tmp / "offsets.npy", np.concatenate(self.offsets))
        meta = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "num_frames": self.frames,
                "num_vertices": self.V, "smplx": "smplx_transl" in self.cols, **info}
        (self.tmp / "info.json").write_text(json.dumps(meta, indent=1))
        return replace_dir(self.tmp, self.final)

    def abort(self) -> None:
        for c in self.cols.values():
            c.f.close()
        shutil.rmtree(self.tmp, ignore_errors=True)


@dataclass
class VertexContact:
    """Opened labels (read-only memory maps); see the module docstring for the arrays."""

    path: Path
    info: dict
    bits: np.ndarray          # (N, ceil(V/8)) uint8
    offsets: np.ndarray       # (N+1,) int64
    target: np.ndarray        # (M,) int32
    distance: np.ndarray      # (M,) float32
    joints: np.ndarray        # (N, J) int32
    penetration: np.ndarray   # (N, 3) float32
    penetrating: np.ndarray   # (N,) int32
    smplx: dict | None        # {field: (N, d)} when the labels were computed on a fitted body

    @property
    def num_vertices(self) -> int:
        return int(self.info["num_vertices"])

    def contact(self, frames) -> np.ndarray:
        """(n, V) bool contact of every vertex at `frames` (an index, slice or index array)."""
        b = np.atleast_2d(np.asarray(self.bits[frames]))
        return np.unpackbits(b, axis=1, count=self.num_vertices, bitorder="big").astype(bool)

    def frame(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frame n's contact vertices: (ids (m,), targets (m,), signed distances (m,))."""
        ids = np.flatnonzero(self.contact(n)[0])
        s, e = int(self.offsets[n]), int(self.offsets[n + 1])
        return ids, np.asarray(self.target[s:e]), np.asarray(self.distance[s:e])

    def joint_target(self, joint: str | int, frames=slice(None)) -> np.ndarray:
        """What a joint touches at `frames`: -1 nothing, -2 floor, -3 scene, else an object id."""
        j = self.info["joint_names"].index(joint) if isinstance(joint, str) else int(joint)
        return np.asarray(self.joints[frames, j])

    @classmethod
    def open(cls, dataset_root: str | Path, num_frames: int, joint_names: list[str]) -> "VertexContact | None":
        """The labels of a dataset, or None when it has none. Raises DataError if present but
        inconsistent with the dataset (frames, joints) or with itself."""
        path = Path(dataset_root) / FOLDER
        if not path.is_dir():
            return None
        ip = path / "info.json"
        try:
            info = json.loads(ip.read_text())
        except (OSError, ValueError) as e:
            raise DataError(ip, None, f"missing or malformed ({e})") from None
        if not isinstance(info, dict) or info.get("format") != FORMAT_NAME or info.get("version") != FORMAT_VERSION:
            raise DataError(ip, "format", f"expected {FORMAT_NAME!r} version {FORMAT_VERSION}")
        N, V = info.get("num_frames"), info.get("num_vertices")
        if N != num_frames:
            raise DataError(ip, "num_frames", f"labels cover {N} frames, the dataset has {num_frames}")
        if info.get("joint_names") != list(joint_names):
            raise DataError(ip, "joint_names", "labels were made for another joint set")
        if not (isinstance(V, int) and V > 0):
            raise DataError(ip, "num_vertices", f"expected a positive integer, found {V!r}")
        J = len(joint_names)

        def arr(name, shape, dtype):
            a = load_npy(path / f"{name}.npy", name)
            if a.shape != shape or a.dtype != np.dtype(dtype):
                raise DataError(path / f"{name}.npy", name, f"expected {np.dtype(dtype)} {shape}, "
                                                             f"found {a.dtype} {a.shape}")
            return a

        offsets = arr("offsets", (N + 1,), np.int64)
        M = int(offsets[-1]) if N + 1 else 0
        if offsets[0] != 0 or (N and np.any(np.diff(np.asarray(offsets)) < 0)):
            raise DataError(path / "offsets.npy", "offsets", "expected non-decreasing offsets from 0")
        smplx = None
        if info.get("smplx"):
            smplx = {k: arr(f"smplx_{k}", (N, d), np.float32) for k, d in SMPLX_FIELDS.items()}
        return cls(path, info, arr("bits", (N, (V + 7) // 8), np.uint8), offsets, arr("target", (M,), np.int32),
                   arr("distance", (M,), np.float32), arr("joints", (N, J), np.int32),
                   arr("penetration", (N, 3), np.float32), arr("penetrating", (N,), np.int32), smplx)
