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
from motiongen.scene.voxelize import VOXELIZE_VERSION, grid_frame, voxelize_mesh
from motiongen.errors import DataError
from motiongen.geometry import up_rotation

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")
UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}     # the `scene_unit` key: what a mesh file's 1.0 is
# A scene wider than this (metres) is a mesh in centimetres or millimetres read as metres (a
# 10 m room in cm reads as 1 km), or a terrain no walkable map of a room covers.
MAX_SCENE_EXTENT_M = 200.0
# Voxels of the dense grid voxelising makes (one byte each, with working copies several times
# that): beyond this a typo in voxel_size or the unit would try to allocate tens of GB or more.
MAX_GRID_VOXELS = 2_000_000_000


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


def load_scene_mesh(path: str | Path, up: str = "y", unit: str = "m") -> trimesh.Trimesh:
    """A scene (mesh file or folder of mesh files, unioned) as one y-up Trimesh in metres
    (`unit`: the files' length unit, m | cm | mm)."""
    if up not in ("y", "z"):
        raise ValueError(f"up must be 'y' or 'z', got {up!r}")
    if unit not in UNITS_M:
        raise ValueError(f"unit must be one of {list(UNITS_M)}, got {unit!r}")
    meshes = [load_mesh_file(f) for f in scene_files(path)]
    # Concatenation keeps each file's vertices separate, so files stay separate components.
    mesh = meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
    to_y_up_m = np.eye(4) * UNITS_M[unit]
    to_y_up_m[3, 3] = 1.0
    if up == "z":
        to_y_up_m[:3, :3] = up_rotation("+z") * UNITS_M[unit]    # (x, y, z) -> (x, z, -y)
    if up == "z" or unit != "m":
        mesh = mesh.copy()
        mesh.apply_transform(to_y_up_m)
    return mesh


def check_scene_size(mesh: trimesh.Trimesh, path: str | Path, voxel_size: float, unit: str = "m") -> None:
    """Refuse a scene whose size says its unit is not the one given (centimetres read as
    metres) or whose grid would not fit in memory, naming the key that fixes it."""
    extent = float(np.ptp(mesh.bounds[:, [0, 2]], axis=0).max())
    if extent > MAX_SCENE_EXTENT_M:
        finer = {"m": "scene_unit=cm (or mm)", "cm": "scene_unit=mm", "mm": "a mesh in metres"}[unit]
        raise DataError(path, None, f"scene is {extent:.4g} m across with scene_unit={unit}, more than "
                                    f"{MAX_SCENE_EXTENT_M:g} m: if the mesh is in smaller units use {finer}")
    voxels = int(np.prod(grid_frame(mesh, voxel_size)[1], dtype=np.float64))
    if voxels > MAX_GRID_VOXELS:
        raise DataError(path, None, f"voxel grid at voxel_size={voxel_size:g} would hold {voxels:.3g} voxels "
                                    f"(at most {MAX_GRID_VOXELS:.0e}): use a larger voxel_size")


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
                    use_cache: bool = True, unit: str = "m") -> OccupancyGrid:
    """The scene's occupancy grid, voxelised once and then read (memory-mapped) from the cache.

    path: mesh file or folder; bounds: (2, 3) world min/max or None (mesh bounds + 1 voxel);
    mode / shell_thickness: see `voxelize_mesh`. The cache key covers the mesh bytes and all
    of these, so editing the mesh or any parameter makes a new entry.
    """
    path = Path(path)
    params = {"voxel_size": float(voxel_size), "up": up, "mode": mode, "shell_thickness": int(shell_thickness),
              "bounds": None if bounds is None else np.asarray(bounds, np.float64).round(9).tolist()}
    if unit != "m":                          # metres keep the cache keys they always had
        params["unit"] = unit
    stem = None
    if use_cache:
        cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        stem = cache / f"{path.stem}-{grid_cache_key(path, **params)[:24]}"
        if Path(f"{stem}.occ.json").is_file() and Path(f"{stem}.occ.npy").is_file():
            return OccupancyGrid.load(stem)
    mesh = load_scene_mesh(path, up=up, unit=unit)
    if bounds is None:
        check_scene_size(mesh, path, voxel_size, unit)
    grid = voxelize_mesh(mesh, voxel_size, bounds=bounds, mode=mode, shell_thickness=shell_thickness)
    if stem is not None:
        stem.parent.mkdir(parents=True, exist_ok=True)
        grid.save(stem)  # .npy then .json, each by rename: a reader never sees half a grid
    return grid
