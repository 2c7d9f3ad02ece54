"""One scene of a MotionDataset as the evaluation protocol sees it: the walkable map, where the
data performs interactions (`Spot`s), the objects at rest and at their interaction poses, and
distances to the scene's surfaces and to objects."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from motiongen.annotation.vertex_contact import SceneTargets
from motiongen.routing import walkable_map
from motiongen.scene.distance_field import OBJECT_VOXEL, MeshField, PlaneField, surface_distance
from motiongen.scene.voxelize import voxelize_mesh
from motiongen.skeleton import PELVIS
from motiongen.spans import true_runs

HAND_NAMES = ("left_wrist", "right_wrist", "left_index1", "right_index1")


@dataclass
class Spot:
    """A place where the data performs an interaction."""
    xz: np.ndarray                      # (2,) pelvis (x, z) during the interaction
    action: str
    object_id: int | None = None
    object_pose: np.ndarray | None = None   # (4, 4) object -> world at the interaction's start
    duration: float = 2.0               # seconds the data spends in the action there


class SceneContext:
    """Everything the protocol needs about one scene of a MotionDataset, built lazily."""

    def __init__(self, ds, scene_id: int, body_radius: float = 0.25):
        self.ds, self.id = ds, int(scene_id)
        self.grid = ds.grid(self.id)
        self.fmap = walkable_map(self.grid, body_radius)
        self.sequences = [s for s in ds.sequences if s.scene == self.id]
        free = np.argwhere(self.fmap.free)                                                   # (N, 2) cells
        self.free_xz = self.fmap.origin + (free + 0.5) * self.fmap.cell                     # (N, 2) centres
        self._obj_cache: dict[int, tuple] = {}
        self._fields: dict[int, MeshField | None] = {}
        self._targets: SceneTargets | None = None

    @property
    def sdf(self):
        """The grid's signed distance field (built once per grid)."""
        return surface_distance(self.grid)

    def surface(self, points) -> np.ndarray:
        """(N,) distance (m) of points (N, 3) to the nearest surface, the floor y = 0 included."""
        p = np.asarray(points, np.float64)
        return np.minimum(self.sdf(p), p[..., 1])

    def spots(self, action: str, min_sep: float = 0.3) -> list[Spot]:
        """Where the scene's motion data performs `action`: one spot per labelled segment
        (pelvis at its middle frame), spots closer than `min_sep` to an earlier one dropped."""
        names = self.ds.action_names
        if action not in names:
            return []
        a = names.index(action)
        hands = [i for i, n in enumerate(self.ds.joint_set.names) if n in HAND_NAMES]
        out: list[Spot] = []
        for seq in self.sequences:
            lab = np.asarray(self.ds.actions[seq.start:seq.end, a])
            for s, e in true_runs(lab):
                f = seq.start + (s + e) // 2
                xz = np.asarray(self.ds.joints[f, PELVIS], np.float64)[[0, 2]]
                oid = pose = None
                if action == "pick up" and self.ds.object_ids is not None:
                    oid, pose = self._object_near(seq.start + s, hands)
                    if oid is None:
                        continue
                if any(np.linalg.norm(xz - o.xz) < min_sep and o.object_id == oid for o in out):
                    continue
                out.append(Spot(xz, action, oid, pose, (e - s) / self.ds.fps))
        return out

    def object_spots(self, action: str, reach: float = 0.8) -> list[Spot]:
        """Fallback when the data never interacts with an object here: each object at rest,
        approached from the nearest walkable point within `reach` m of it."""
        out = []
        for oid, pose in self.rest_objects():
            xz = self.fmap.nearest_free(pose[[0, 2], 3], reach)
            if xz is not None:
                out.append(Spot(np.asarray(xz, np.float64), action, oid, pose))
        return out

    def _object_near(self, f: int, hands: list[int]):
        ids = np.asarray(self.ds.object_ids[f])
        valid = np.flatnonzero(ids >= 0)
        if not valid.size or not hands:
            return None, None
        poses = np.asarray(self.ds.object_poses[f], np.float64)                             # (K, 4, 4)
        h = np.asarray(self.ds.joints[f, hands], np.float64)                                 # (H, 3)
        d = [np.linalg.norm(h - poses[k, :3, 3], axis=-1).min() for k in valid]
        k = int(valid[int(np.argmin(d))])
        return int(ids[k]), poses[k]

    def rest_objects(self) -> list[tuple[int, np.ndarray]]:
        """[(object id, pose (4, 4))]: the scene's objects at the first frame of its first sequence."""
        if self.ds.object_ids is None or not self.sequences:
            return []
        f = self.sequences[0].start
        ids = np.asarray(self.ds.object_ids[f])
        return [(int(o), np.asarray(self.ds.object_poses[f, k], np.float64)) for k, o in enumerate(ids) if o >= 0]

    def segment_object(self, seq, start: int, hands: list[int]) -> tuple[int, np.ndarray] | None:
        """The object an interaction starting at frame `start` of `seq` (relative) is done with:
        the one nearest the hands there (the rule the dynamic pairs use), as (id, its poses over
        the whole sequence (T, 4, 4), far away where it is absent), or None."""
        f = seq.start + start
        oid, _ = self._object_near(f, hands)
        if oid is None:
            return None
        ids = np.asarray(self.ds.object_ids[seq.start:seq.end])                               # (T, K)
        k = int(np.flatnonzero(ids[start] == oid)[0])
        poses = np.asarray(self.ds.object_poses[seq.start:seq.end, k], np.float64).copy()    # (T, 4, 4)
        poses[ids[:, k] != oid, :3, 3] = 1e6
        return oid, poses

    def contact_targets(self) -> SceneTargets:
        """The floor and the static scene as contact surfaces (`annotation.vertex_contact`):
        the scene's mesh where the dataset has one, else its occupancy grid."""
        if self._targets is None:
            mesh = self.ds.scene_mesh(self.id)
            scene = MeshField(mesh, voxel_size=self.grid.voxel_size) if mesh is not None else self.sdf
            self._targets = SceneTargets(floor=PlaneField(0.0), scene=scene)
        return self._targets

    def object_field(self, oid: int) -> MeshField | None:
        """Exact signed distance to object `oid`'s mesh, in the object's frame (None: no mesh)."""
        if oid not in self._fields:
            mesh = self.ds.object_mesh(oid)
            self._fields[oid] = None if mesh is None else MeshField(mesh, voxel_size=OBJECT_VOXEL)
        return self._fields[oid]

    def object(self, oid: int):
        """(occupancy grid in the object frame, KD-tree of surface samples in the object frame) or None."""
        if oid not in self._obj_cache:
            mesh = self.ds.object_mesh(oid)
            if mesh is None:
                self._obj_cache[oid] = None
            else:
                pts, _ = trimesh.sample.sample_surface(mesh, 2000, seed=0)                   # (2000, 3)
                pts = np.concatenate([pts, mesh.vertices])
                grid = voxelize_mesh(mesh, voxel_size=self.grid.voxel_size)
                grid.exact_surface = self.object_field(oid)       # the sampler's hand clearance measures against it
                self._obj_cache[oid] = (grid, cKDTree(pts))
        return self._obj_cache[oid]

    def objects_for_generate(self, target: tuple[int, np.ndarray] | None = None) -> list[tuple]:
        """[(object grid, pose)] for `generate(objects=)`: the scene's objects at rest, the target
        (if given) at its interaction pose instead of its rest pose."""
        placed = dict(self.rest_objects())
        if target is not None:
            placed[target[0]] = target[1]
        out = []
        for oid, pose in placed.items():
            obj = self.object(oid)
            if obj is not None:
                out.append((obj[0], pose))
        return out

    def object_distance(self, points, oid: int, poses) -> np.ndarray:
        """(F, P) distance (m) from points (F, P, 3) to object `oid`'s surface at poses (F, 4, 4)."""
        obj = self.object(oid)
        pts = np.asarray(points, np.float64)
        if obj is None:
            return np.full(pts.shape[:2], np.inf)
        poses = np.broadcast_to(np.asarray(poses, np.float64), (pts.shape[0], 4, 4))
        R, t = poses[:, :3, :3], poses[:, :3, 3]
        local = np.einsum("fji,fpj->fpi", R, pts - t[:, None])                              # R^T (p - t)
        d, _ = obj[1].query(local.reshape(-1, 3))
        return d.reshape(pts.shape[:2])
