"""Where `sample.py` samples: the scene from its spec (mesh file, `synthetic:ID`,
`dataset:PATH:ID`, or none), with its objects, and a default start and goals when the user
gives none."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable

import numpy as np
import scipy.ndimage as ndi
import trimesh

from motiongen.data.format import MotionDataset
from motiongen.errors import ConfigError
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.routing import WalkableMap, walkable_map
from motiongen.sampling.goals import Goal, plan_route
from motiongen.scene.distance_field import OBJECT_VOXEL, MeshField
from motiongen.scene.mesh_files import load_scene_grid, load_scene_mesh
from motiongen.scene.voxelize import voxelize_mesh
from motiongen.synthetic.scenes import make_scene


@dataclass
class SceneInfo:
    grid: object | None                     # OccupancyGrid or None (empty floor)
    label: str
    objects: list = field(default_factory=list)   # [(OccupancyGrid, pose (4, 4))]
    synthetic: object | None = None         # motiongen.synthetic.scenes.Scene when known
    # () -> the scene's y-up trimesh (metres), placed objects included; None: not known.
    mesh_loader: Callable[[], object] | None = field(default=None, repr=False)

    @cached_property
    def mesh(self):
        """The scene's mesh (None: not known), read on first use: only the video needs it, and a
        mesh file's grid comes from the cache without reading the file."""
        return None if self.mesh_loader is None else self.mesh_loader()


def _dataset_scene(ds, scene_id: int, label: str, with_objects: bool) -> SceneInfo:
    if scene_id not in ds.scenes:
        raise ConfigError(f"scene {label}: dataset {ds.root} has no scene {scene_id} "
                          f"(scenes: {', '.join(str(s) for s in sorted(ds.scenes)[:20])}...)")
    grid = ds.grid(scene_id)
    objects, meshes = [], [ds.scene_mesh(scene_id)]
    if with_objects and ds.object_ids is not None:
        # Movable objects at their resting poses: the first frame of the scene's first sequence.
        seq = next((s for s in ds.sequences if s.scene == scene_id), None)
        if seq is not None:
            ids = np.asarray(ds.object_ids[seq.start])
            for slot, oid in enumerate(ids):
                mesh = ds.object_mesh(int(oid)) if oid >= 0 else None
                if mesh is not None:
                    pose = np.asarray(ds.object_poses[seq.start, slot], np.float64)
                    ogrid = voxelize_mesh(mesh, voxel_size=grid.voxel_size)
                    ogrid.exact_surface = MeshField(mesh, voxel_size=OBJECT_VOXEL)   # hands measured against it
                    objects.append((ogrid, pose))
                    meshes.append(mesh.copy().apply_transform(pose))
    # The video draws the scene's mesh with its objects where the dataset has one.
    mesh = trimesh.util.concatenate(meshes) if meshes[0] is not None else None
    return SceneInfo(grid, label, objects, mesh_loader=lambda: mesh)


def resolve_scene(spec, ckpt_config=None, voxel_size: float = 0.02, up: str = "y", objects: bool = True,
                  unit: str = "m") -> SceneInfo:
    """scene=None | 'none' | mesh file/folder (in `unit`: m | cm | mm) | 'synthetic:ID' | 'dataset:PATH:ID'."""
    if spec is None or str(spec).strip().lower() in ("", "none", "null", "empty"):
        return SceneInfo(None, "empty floor")
    spec = str(spec)
    if spec.startswith("synthetic:"):
        sid = _scene_id(spec.split(":", 1)[1], spec)
        data = ckpt_config.get("data") if ckpt_config is not None else None
        if data is not None and data.get("source") == "synthetic":
            dcfg = DataConfig(source="synthetic", size=str(data.get("size", "default")), seed=int(data.get("seed", 0)))
        else:
            dcfg = DataConfig(source="synthetic")
        ds = open_dataset(dcfg, verbose=True)
        info = _dataset_scene(ds, sid, spec, objects)
        info.synthetic = _synthetic_layout(sid, dcfg.seed, info.grid)
        return info
    if spec.startswith("dataset:"):
        rest = spec[len("dataset:"):]
        root, _, sid = rest.rpartition(":")
        if not root:
            raise ConfigError(f"scene={spec!r}: expected dataset:PATH:ID")
        return _dataset_scene(MotionDataset.open(root), _scene_id(sid, spec), spec, objects)
    # The mesh when the video asks: it draws it and its camera's rays meet it (the grid is it voxelised).
    return SceneInfo(load_scene_grid(spec, voxel_size=voxel_size, up=up, unit=unit), spec,
                     mesh_loader=lambda: load_scene_mesh(spec, up=up, unit=unit))


def scene_for_keys(keys, ckpt_config=None) -> tuple[SceneInfo, WalkableMap | None]:
    """The scene `keys` name (`sample_config.SceneRouteKeys`: scene, voxel_size, scene_up,
    objects, scene_unit) and its walkable map for the body's radius and height (None without a
    grid): what `sample` and `serve` start from."""
    scene = resolve_scene(keys.scene, ckpt_config, keys.voxel_size, keys.scene_up, keys.objects, keys.scene_unit)
    fmap = walkable_map(scene.grid, keys.body_radius, tuple(keys.body_height)) if scene.grid is not None else None
    return scene, fmap


def _scene_id(s: str, spec: str) -> int:
    try:
        return int(s)
    except ValueError:
        raise ConfigError(f"scene={spec!r}: scene id must be an integer, got {s!r}") from None


def _synthetic_layout(scene_id: int, seed: int, grid):
    """The generator's layout of a synthetic scene (seats, beds), rebuilt from its seed; None if
    it does not reproduce the stored grid (another generator version)."""
    try:
        scene = make_scene(scene_id, np.random.default_rng([seed, scene_id]))
        g = scene.grid()
        if tuple(g.shape) == tuple(grid.shape) and np.array_equal(np.asarray(g.bits), np.asarray(grid.bits)):
            return scene
    except Exception:  # the layout is a nicety for the demo route; the grid is what matters
        pass
    return None


def default_route_goals(scene: SceneInfo, fmap: WalkableMap | None, action_names, rng: np.random.Generator):
    """(start (2,), goals) for a scene when the user gives none: in a synthetic scene, walk to
    a chair and sit on it (if the vocabulary has 'sit'), then on to a far free point; otherwise
    a tour of free points far apart. On an empty floor: a 3 m walk with a turn."""
    if fmap is None:
        return np.zeros(2), [Goal([0.0, 2.0]), Goal([1.5, 3.0])]
    # Components of the coarse map A* plans on (narrow gaps may be open only at 2 cm).
    cfree, corigin, ccell = fmap.coarse(0.05)
    labels, n = ndi.label(cfree)
    if n == 0:
        raise ConfigError(f"scene {scene.label} has no walkable floor for body_radius={fmap.body_radius} m")
    biggest = 1 + int(np.argmax(ndi.sum(np.ones_like(labels), labels, index=np.arange(1, n + 1))))
    cells = np.argwhere(labels == biggest)
    pts = corigin + (cells + 0.5) * ccell                                                    # (N, 2)
    centre = pts.mean(0)
    start = pts[np.argmin(np.linalg.norm(pts - centre, axis=-1))]
    chosen = [start]
    goals: list[Goal] = []

    def tour(k: int) -> list[Goal]:
        # Farthest-point tour over the walkable component, 0.3 m back from its edge.
        out = []
        for _ in range(k):
            d = np.min(np.stack([np.linalg.norm(pts - c, axis=-1) for c in chosen]), axis=0)
            p = pts[int(np.argmax(d))]
            v = centre - p
            p2 = p + 0.3 * v / max(np.linalg.norm(v), 1e-9)
            p = p2 if fmap.is_free(p2) else p
            out.append(Goal(p))
            chosen.append(p)
        return out

    lower = {a.lower(): a for a in action_names}
    if scene.synthetic is not None and scene.synthetic.seats and "sit" in lower:
        seats = list(scene.synthetic.seats)
        for i in rng.permutation(len(seats)):
            seat = seats[int(i)]
            trial = [Goal(np.asarray(seat.surface, np.float64)[[0, 2]], lower["sit"], 3.0)]
            stand = np.asarray(seat.stand_xz, np.float64)
            if fmap.is_free(stand):
                trial.insert(0, Goal(stand))
            try:
                plan_route(start, [Goal(tour(1)[0].xz)] + trial, fmap)
            except ConfigError:
                chosen.pop()
                continue
            goals = [Goal(chosen[-1])] + trial
            break
    goals += tour(3 - min(len(goals), 2) if goals else 3)
    try:
        plan_route(start, goals, fmap)
    except ConfigError:
        chosen[:] = [start]
        goals = tour(3)
    return start, goals


def default_start(fmap: WalkableMap | None, first_goal: np.ndarray) -> np.ndarray:
    if fmap is None:
        return np.zeros(2)
    (x0, z0), (x1, z1) = fmap.bounds
    p = fmap.nearest_free(np.array([(x0 + x1) / 2, (z0 + z1) / 2]))
    if p is None:
        raise ConfigError("the scene has no walkable floor to start from")
    return p
