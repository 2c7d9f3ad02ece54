"""The video's camera for the `video_camera` key: `adaptive` (the TRUMANS supplement's ring
camera, `adaptive_camera`), `follow` (behind the body, `follow_camera`) or `top` (high above
it), as one `CameraPath` over the motion that `motion.npz` saves and the video shows."""

from __future__ import annotations

import numpy as np

from motiongen.export.adaptive_camera import GridRays, MeshRays, adaptive_path
from motiongen.export.camera import CAMERA_MODES, CameraPath, top_path
from motiongen.export.follow_camera import follow_path

MAX_OBJECT_POINTS = 256      # per object: enough to tell which hand is nearer it


def camera_path(mode: str, joints: np.ndarray, fps: float, grid=None, mesh=None,
                objects: np.ndarray | None = None) -> CameraPath:
    """The camera over joints (T, J, 3) at `fps`. The adaptive camera's rays go against `mesh`
    (a y-up trimesh) when given, else against `grid` (an OccupancyGrid), else meet nothing;
    objects: points on the dynamic objects, (N, 3) at rest or (T, N, 3) moving
    (`object_points`), whose nearer hand it keeps in view."""
    if mode not in CAMERA_MODES:
        raise ValueError(f"video_camera: expected one of {', '.join(CAMERA_MODES)}, got {mode!r}")
    if mode == "follow":
        return follow_path(joints, fps)
    if mode == "top":
        return top_path(joints)
    rays = MeshRays(mesh) if mesh is not None else GridRays(grid) if grid is not None else None
    return adaptive_path(joints, fps, rays or _NoScene(), objects)


def object_points(objects) -> np.ndarray | None:
    """(N, 3) world points inside the placed objects (voxel centres, at most MAX_OBJECT_POINTS
    each), or None without objects."""
    pts = []
    for grid, pose in objects:
        ijk = np.argwhere(np.asarray(grid.dense()))                                          # (M, 3)
        if not len(ijk):
            continue
        ijk = ijk[np.linspace(0, len(ijk) - 1, min(len(ijk), MAX_OBJECT_POINTS)).astype(int)]
        local = grid.origin + (ijk + 0.5) * grid.voxel_size
        pose = np.asarray(pose, np.float64)
        pts.append(local @ pose[:3, :3].T + pose[:3, 3])
    return np.concatenate(pts) if pts else None


class _NoScene:
    """An empty floor: no ray meets anything."""

    def first_hit(self, origins: np.ndarray, ends: np.ndarray) -> np.ndarray:
        return np.full(len(origins), np.inf)
