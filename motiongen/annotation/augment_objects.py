"""Object edits of contact-preserving augmentation (TRUMANS supp. B.5): scale an object, swap it
for another mesh of the same type, or move it within the scene. Each edit gives the new mesh
(in the object's local frame), the new per-frame poses, and the map of a contact point on the
old object to its corresponding point on the new one (v_m -> v'_m of Eq. A1), in world
coordinates, so the joints touching it can follow (`augment_offsets`).

Objects rest on their lowest point, so scaling and swapping keep the bottom centre of the
object (as posed at the sequence's first frame) where it was: a scaled bottle still stands on
the table instead of sinking into it or floating.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from motiongen.scene.distance_field import SurfaceField

OPS = ("scale", "swap", "move")


@dataclass
class ObjectEdit:
    op: str                       # scale | swap | move
    object_id: int                # the edited object
    mesh: trimesh.Trimesh         # the new object's mesh, local frame
    matrix: np.ndarray            # (4, 4) old local point -> new local point (affine)
    shift: np.ndarray             # (3,) world translation added to every pose (move)
    params: dict = field(default_factory=dict)   # what was done (for meta.json)

    def poses(self, poses: np.ndarray) -> np.ndarray:
        """New poses (T, 4, 4) of the object from its old ones."""
        out = np.array(poses, np.float64)
        out[:, :3, 3] += self.shift
        return out

    def offsets(self, local_points: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """World offsets v'_m - v_m (n, 3) of contact points given in the old object's local
        frame (n, 3), at frames with the old poses (n, 4, 4)."""
        p = np.asarray(local_points, np.float64)
        M = np.asarray(poses, np.float64)
        new_local = p @ self.matrix[:3, :3].T + self.matrix[:3, 3]
        old_w = np.einsum("nij,nj->ni", M[:, :3, :3], p) + M[:, :3, 3]
        new_w = np.einsum("nij,nj->ni", M[:, :3, :3], new_local) + M[:, :3, 3] + self.shift
        return new_w - old_w


def bottom_anchor(mesh: trimesh.Trimesh, pose: np.ndarray) -> np.ndarray:
    """The bottom centre of the mesh as posed by `pose` (4, 4), in the mesh's local frame:
    the centre of the world bounding box's lowest face (what the object stands on)."""
    M = np.asarray(pose, np.float64)
    w = np.asarray(mesh.vertices, np.float64) @ M[:3, :3].T + M[:3, 3]
    lo, hi = w.min(0), w.max(0)
    bottom = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    return M[:3, :3].T @ (bottom - M[:3, 3])


def _about(point: np.ndarray, linear: np.ndarray, to: np.ndarray | None = None) -> np.ndarray:
    """(4, 4): p -> to + linear (p - point)."""
    A = np.eye(4)
    A[:3, :3] = linear
    A[:3, 3] = (point if to is None else to) - linear @ point
    return A


def scale_edit(object_id: int, mesh: trimesh.Trimesh, pose0: np.ndarray, factor: float) -> ObjectEdit:
    """Uniform scale by `factor` about the bottom centre (pose0: the object's first pose)."""
    if not factor > 0:
        raise ValueError(f"scale factor must be positive, got {factor}")
    A = _about(bottom_anchor(mesh, pose0), factor * np.eye(3))
    new = mesh.copy()
    new.apply_transform(A)
    return ObjectEdit("scale", object_id, new, A, np.zeros(3), {"factor": float(factor)})


def swap_edit(object_id: int, mesh: trimesh.Trimesh, other: trimesh.Trimesh, other_id: int,
              pose0: np.ndarray) -> ObjectEdit:
    """Replace the mesh by `other` (same type), standing on the same bottom centre. Contact
    points follow the map of the old local bounding box onto the new one (per-axis scale about
    the bottom centres)."""
    a_old = bottom_anchor(mesh, pose0)
    a_new = bottom_anchor(other, pose0)
    ext_old, ext_new = mesh.extents, other.extents
    D = np.diag(np.where(ext_old > 1e-9, ext_new / np.maximum(ext_old, 1e-9), 1.0))
    new = other.copy()
    new.apply_translation(a_old - a_new)              # its bottom centre onto the old one's
    return ObjectEdit("swap", object_id, new, _about(a_old, D), np.zeros(3), {"with_object": int(other_id)})


def move_edit(object_id: int, mesh: trimesh.Trimesh, delta: np.ndarray) -> ObjectEdit:
    """Translate the object by `delta` (world, metres) in every frame."""
    return ObjectEdit("move", object_id, mesh.copy(), np.eye(4), np.asarray(delta, np.float64),
                      {"delta": [float(v) for v in delta]})


def placement_ok(mesh: trimesh.Trimesh, pose: np.ndarray, scene: SurfaceField | None, floor_y: float = 0.0,
                 support: float = 0.02, overlap: float = 0.01) -> bool:
    """Whether a resting object at `pose` fits its scene: no vertex more than `overlap` inside
    the scene (or the floor), and its lowest vertex at most `support` above a surface."""
    M = np.asarray(pose, np.float64)
    w = np.asarray(mesh.vertices, np.float64) @ M[:3, :3].T + M[:3, 3]
    if w[:, 1].min() < floor_y - overlap:
        return False
    low = w[w[:, 1] <= w[:, 1].min() + 1e-4]
    if scene is None:
        return bool(low[:, 1].min() - floor_y <= support)
    if scene(w).min() < -overlap:
        return False
    below = low - np.array([0.0, support, 0.0])       # a support surface just under the base
    return bool((scene(below) <= 0).any() or low[:, 1].min() - floor_y <= support)
