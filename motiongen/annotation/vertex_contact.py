"""Per-vertex contact between a posed body mesh and the surfaces of a scene (TRUMANS supp. B.6).

A vertex is in contact with a surface when it lies inside it, or lies outside within
`threshold` (2 cm) and the angle between its normal and the direction to the nearest surface
point is under `max_angle` (60 deg): the angle test keeps the back of a hand that holds a
bottle out of the contact set although it is within 2 cm of the bottle. Surfaces ("targets")
are the floor plane, the static scene (mesh, else its occupancy grid) and every object with a
mesh at its per-frame pose; each contact vertex keeps the id of the target it touches (the
deepest / closest one when several qualify): `FLOOR`, `SCENE` or the object id.

    body = BodySurface(bm, joint_set)                 # vertex normals, joint regions
    V, N = body.pose(params, frames)                   # (B, V, 3) vertices and unit normals
    targets = SceneTargets(floor=PlaneField(), scene=MeshField(mesh), objects={7: MeshField(cup)})
    c = vertex_contacts(V, N, targets, object_ids (B, K), object_poses (B, K, 4, 4), ContactConfig())
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from motiongen.body.model import BodyModel
from motiongen.scene.distance_field import SurfaceField
from motiongen.skeleton import JointSet

NONE, FLOOR, SCENE = -1, -2, -3
TARGET_NAMES = {NONE: "none", FLOOR: "floor", SCENE: "scene"}


@dataclass
class ContactConfig:
    threshold: float = 0.02       # m: outside vertices closer than this can be in contact
    max_angle: float = 60.0       # deg: vertex normal vs direction to the nearest surface point
    floor: bool = True            # the plane y = floor_y is a target (FLOOR)
    floor_y: float = 0.0
    scene: str = "auto"           # scene surface: auto (mesh if the dataset has one, else grid) | mesh | grid
    voxel_size: float = 0.02      # solid grid of scene meshes (objects use at most 1 cm)
    batch_frames: int = 32        # frames posed and queried at once


@dataclass
class SceneTargets:
    """The surfaces of one scene. objects: object id -> field in the object's local frame."""

    floor: SurfaceField | None = None
    scene: SurfaceField | None = None
    objects: dict[int, SurfaceField] = field(default_factory=dict)
    radius: dict[int, tuple[np.ndarray, float]] = field(default_factory=dict)   # id -> (local centre, radius)

    def add_object(self, oid: int, fld: SurfaceField, vertices: np.ndarray) -> None:
        lo, hi = vertices.min(0), vertices.max(0)
        centre = (lo + hi) / 2
        self.objects[int(oid)] = fld
        self.radius[int(oid)] = (centre, float(np.linalg.norm(vertices - centre, axis=-1).max()))


@dataclass
class FrameContacts:
    target: np.ndarray        # (B, V) int32: NONE, FLOOR, SCENE or object id
    distance: np.ndarray      # (B, V) float32: signed distance to that target (inf where none)
    penetration: np.ndarray   # (B, V) float32: deepest penetration over all targets, m (0 = none)

    @property
    def contact(self) -> np.ndarray:
        return self.target != NONE


class BodySurface:
    """A body model's mesh for contact: posed vertices with unit normals, and each vertex's
    joint in `joint_set` (the joint whose skinning weight is largest, moved up the tree to the
    nearest joint of the set: finger vertices belong to the wrist, or to index1 where the set
    has it)."""

    def __init__(self, bm: BodyModel, joint_set: JointSet):
        self.bm, self.joint_set = bm, joint_set
        self.faces = np.asarray(bm.faces, np.int64)                                   # (F, 3)
        in_set = {s: k for k, s in enumerate(joint_set.smplx_indices)}
        owner = np.asarray(bm.skinning_weights).argmax(1)                             # (V,) of 55
        table = np.empty(len(bm.full_parents), np.int64)
        for j in range(len(table)):
            k = j
            while k not in in_set:
                k = bm.full_parents[k]
            table[j] = in_set[k]
        self.region = table[owner]                                                    # (V,) joint index

    @property
    def num_vertices(self) -> int:
        return int(self.bm.num_vertices)

    def normals(self, verts) -> np.ndarray:
        """Unit vertex normals (B, V, 3) of posed vertices (B, V, 3) (numpy or torch)."""
        v = torch.as_tensor(verts)
        B, V = v.shape[:2]
        f = torch.as_tensor(self.faces, device=v.device)
        tri = v.transpose(0, 1)[f]                                                     # (F, 3, B, 3)
        fn = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).reshape(len(f), B * 3)  # area-weighted
        vn = torch.zeros(V, B * 3, dtype=v.dtype, device=v.device)
        for k in range(3):                                                             # each face to its 3 corners
            vn.index_add_(0, f[:, k], fn)
        vn = vn.reshape(V, B, 3).transpose(0, 1)
        return torch.nn.functional.normalize(vn, dim=-1).cpu().numpy().astype(np.float64)

    def pose(self, params: dict, frames: slice) -> tuple[np.ndarray, np.ndarray]:
        """Vertices and unit normals (B, V, 3) float64 of SMPL-X parameters {global_orient
        (T,3), body_pose (T,63), transl (T,3), betas (T,10) or (10,)} at `frames`."""
        dt, dev = self.bm.J_template.dtype, self.bm.J_template.device

        def t(k):
            a = np.asarray(params[k])
            a = a[frames] if a.ndim == 2 else a
            return torch.as_tensor(np.array(a), dtype=dt, device=dev)

        with torch.no_grad():
            v = self.bm.vertices(t("global_orient"), t("body_pose"), t("transl"), t("betas"))
            n = self.normals(v)
        return v.cpu().numpy().astype(np.float64), n


def vertex_contacts(verts: np.ndarray, normals: np.ndarray, targets: SceneTargets, object_ids=None,
                    object_poses=None, cfg: ContactConfig = ContactConfig()) -> FrameContacts:
    """Contacts of B posed frames: verts, normals (B, V, 3); object_ids (B, K) int (-1 empty),
    object_poses (B, K, 4, 4) object -> world (None: no objects)."""
    B, V = verts.shape[:2]
    best = np.full((B, V), np.inf)
    target = np.full((B, V), NONE, np.int32)
    pen = np.zeros((B, V))
    cos_max = np.cos(np.radians(cfg.max_angle))

    def consider(tid: int, frame: slice | int, rows: np.ndarray | None, q) -> None:
        idx = (frame, slice(None)) if rows is None else (frame, rows)
        d = q.distance.reshape(best[idx].shape)
        u = q.direction.reshape(best[idx].shape + (3,))
        facing = np.einsum("...c,...c->...", normals[idx], u) > cos_max
        ok = (d < 0) | ((d <= cfg.threshold) & facing)
        better = ok & (d < best[idx])
        best[idx] = np.where(better, d, best[idx])
        target[idx] = np.where(better, tid, target[idx])
        pen[idx] = np.maximum(pen[idx], np.where(np.isfinite(d), -d, 0.0))

    flat = verts.reshape(-1, 3)
    if targets.floor is not None:
        consider(FLOOR, slice(None), None, targets.floor.query(flat, cfg.threshold))
    if targets.scene is not None:
        consider(SCENE, slice(None), None, targets.scene.query(flat, cfg.threshold))
    if object_ids is not None and targets.objects:
        ids = np.asarray(object_ids)
        poses = np.asarray(object_poses, np.float64)
        for b in range(B):
            for k in np.flatnonzero(ids[b] >= 0):
                oid = int(ids[b, k])
                if oid not in targets.objects:
                    continue
                centre, radius = targets.radius[oid]
                M = poses[b, k]
                c = M[:3, :3] @ centre + M[:3, 3]
                # only vertices that can be within the threshold of the object's bounding sphere
                rows = np.flatnonzero(np.linalg.norm(verts[b] - c, axis=-1) <= radius + cfg.threshold)
                if len(rows):
                    consider(oid, b, rows, targets.objects[oid].query(verts[b, rows], cfg.threshold, pose=M))
    dist = np.where(target != NONE, best, np.inf).astype(np.float32)
    return FrameContacts(target, dist, pen.astype(np.float32))


def joint_targets(c: FrameContacts, region: np.ndarray, num_joints: int) -> np.ndarray:
    """(B, J) int32 per-joint summary: the target touched by most of the joint's contact
    vertices (NONE when none is in contact). region (V,) joint index of each vertex."""
    B, V = c.target.shape
    out = np.full((B, num_joints), NONE, np.int32)
    f, v = np.nonzero(c.contact)
    if not len(f):
        return out
    codes, tcode = np.unique(c.target[f, v], return_inverse=True)
    key = (f * num_joints + region[v]) * len(codes) + tcode.ravel()
    keys, counts = np.unique(key, return_counts=True)
    fj, tc = keys // len(codes), keys % len(codes)
    order = np.lexsort((-counts, fj))                  # per (frame, joint): most vertices first
    fj, tc = fj[order], tc[order]
    first = np.r_[True, fj[1:] != fj[:-1]]
    out.reshape(-1)[fj[first]] = codes[tc[first]]
    return out


def penetration_per_frame(c: FrameContacts) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: (max, mean, median) penetration depth over the penetrating vertices (B, 3)
    float32, metres (0 for frames without any), and how many vertices penetrate (B,) int32."""
    depth = c.penetration
    B = depth.shape[0]
    out = np.zeros((B, 3), np.float32)
    n = (depth > 0).sum(1).astype(np.int32)
    for b in np.flatnonzero(n):
        d = depth[b][depth[b] > 0]
        out[b] = (d.max(), d.mean(), np.median(d))
    return out, n
