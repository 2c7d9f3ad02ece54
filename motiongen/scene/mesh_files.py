"""Scenes from files: `load_scene_mesh` / `load_scene_grid` turn a mesh file
(obj/ply/glb/gltf/stl/off) or a folder of them into one y-up `trimesh.Trimesh` and then an
`OccupancyGrid` (see `voxelize.py`), cached on disk under a key made of the file bytes and every
voxelisation parameter. Local (body-frame) occupancy: `motiongen.scene.local_occupancy`.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import trimesh

from motiongen.scene.occupancy import OccupancyGrid
from motiongen.scene.voxelize import VOXELIZE_VERSION, voxelize_mesh
from motiongen.errors import DataError
from motiongen.geometry import up_rotation

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")


# ---------------------------------------------------------------------------------------
# Meshes


def scene_files(path: str | Path) -> list[Path]:
    """The mesh files of a scene: the file itself, or a folder's mesh files (sorted)."""
    path = Path(path)
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in MESH_SUFFIXES)
        if not files:
            raise DataError(path, None, f"folder holds no mesh files ({', '.join(MESH_SUFFIXES)})")
        return files
    if not path.is_file():
        raise DataError(path, None, "scene mesh file or folder is missing")
    return [path]


def load_mesh_file(path: str | Path) -> trimesh.Trimesh:
    """One mesh file as a single Trimesh; glTF/GLB scenes are flattened with their node transforms."""
    path = Path(path)
    try:
        loaded = trimesh.load(path, force="mesh", process=True)
    except Exception as e:  # trimesh raises many kinds on corrupt input; all are the user's file
        raise DataError(path, None, f"cannot read mesh ({type(e).__name__}: {e})") from None
    if isinstance(loaded, trimesh.Scene):  # force="mesh" already concatenates; keep a fallback
        loaded = loaded.to_mesh()
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise DataError(path, None, "mesh has no triangles")
    if not np.all(np.isfinite(loaded.vertices)):
        raise DataError(path, None, "mesh has non-finite vertex coordinates")
    return loaded


def load_scene_mesh(path: str | Path, up: str = "y") -> trimesh.Trimesh:
    """A scene (mesh file or folder of mesh files, unioned) as one y-up Trimesh in metres."""
    if up not in ("y", "z"):
        raise ValueError(f"up must be 'y' or 'z', got {up!r}")
    meshes = [load_mesh_file(f) for f in scene_files(path)]
    # Concatenation keeps each file's vertices separate, so files stay separate components.
    mesh = meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
    if up == "z":
        mesh = mesh.copy()
        z_to_y = np.eye(4)
        z_to_y[:3, :3] = up_rotation("+z")                    # (x, y, z) -> (x, z, -y)
        mesh.apply_transform(z_to_y)
    return mesh


# ---------------------------------------------------------------------------------------
# Cached grids


def default_cache_dir() -> Path:
    env = os.environ.get("MOTIONGEN_CACHE")
    return Path(env) / "grids" if env else Path.home() / ".cache" / "motiongen" / "grids"


def grid_cache_key(path: str | Path, **params) -> str:
    """sha256 over the scene's file bytes (and names, for folders) and the voxelisation params."""
    h = hashlib.sha256()
    h.update(json.dumps({"v": VOXELIZE_VERSION, **params}, sort_keys=True, default=str).encode())
    for f in scene_files(path):
        h.update(f.name.encode() + b"\0")
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def load_scene_grid(path: str | Path, voxel_size: float = 0.02, cache_dir: str | Path | None = None,
                    bounds=None, up: str = "y", mode: str = "auto", shell_thickness: int = 1,
                    use_cache: bool = True) -> OccupancyGrid:
    """The scene's occupancy grid, voxelised once and then read (memory-mapped) from the cache.

    path: mesh file or folder; bounds: (2, 3) world min/max or None (mesh bounds + 1 voxel);
    mode / shell_thickness: see `voxelize_mesh`. The cache key covers the mesh bytes and all
    of these, so editing the mesh or any parameter makes a new entry.
    """
    path = Path(path)
    params = {"voxel_size": float(voxel_size), "up": up, "mode": mode, "shell_thickness": int(shell_thickness),
              "bounds": None if bounds is None else np.asarray(bounds, np.float64).round(9).tolist()}
    stem = None
    if use_cache:
        cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        stem = cache / f"{path.stem}-{grid_cache_key(path, **params)[:24]}"
        if Path(f"{stem}.occ.json").is_file() and Path(f"{stem}.occ.npy").is_file():
            return OccupancyGrid.load(stem)
    grid = voxelize_mesh(load_scene_mesh(path, up=up), voxel_size, bounds=bounds, mode=mode,
                         shell_thickness=shell_thickness)
    if stem is not None:
        stem.parent.mkdir(parents=True, exist_ok=True)
        grid.save(stem)  # .npy then .json, each by rename: a reader never sees half a grid
    return grid
