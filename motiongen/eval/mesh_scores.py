"""Contact, hand–object distance and penetration measured on the posed body mesh, the same way
for the data, the network's own joints and the output, and independent of the sampler's
clean-up (whose offsets from joints to skin these figures never use).

* Every row gets a mesh: the output its own solved body; the data and the network's joints a
  body put on their joints (`BodyMeshes.of_joints`: one shape fitted to the motion's bone
  lengths, each frame posed analytically with two-bone IK to the wrists and ankles,
  `body.solve.MotionBody.project`) — no contact targets, no foot lock, no smoothing.
* Contact is `annotate-contact`'s per-vertex rule (`annotation.vertex_contact`): a vertex
  inside a surface, or within 2 cm of it with its normal facing it. A frame labelled with a
  seat action is in contact when a vertex of the action's body part (`MESH_PARTS`) touches
  the scene or the floor; a pick-up frame when a hand vertex touches the interaction's object
  at that frame's pose (only that object: the data's other objects do not count).
* Hand–object distance is signed: the exact signed distance of the hand vertices to the
  object's mesh, negative inside (`scene.distance_field.MeshField`); a frame with any hand
  vertex inside counts in `hand_inside`.
* Penetration: vertex samples inside the scene's occupancy grid (`metrics.scene_penetration`).

Labelled frames are measured every `every`-th frame, penetration every 3rd frame on every 8th
vertex (enough to find skin in furniture at a fraction of the cost of whole meshes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from motiongen import metrics as M
from motiongen.annotation.vertex_contact import BodySurface, ContactConfig, SceneTargets, vertex_contacts
from motiongen.body.model import BodyModel, BodyParams
from motiongen.body.rotations import matrix_to_axis_angle
from motiongen.body.solve import MotionBody
from motiongen.eval.scene_context import HAND_NAMES
from motiongen.skeleton import JointSet

# Body parts whose skin carries an action: thighs and buttocks on a seat, the back on a bed,
# the hand (fingers included) on an object.
MESH_PARTS: dict[str, tuple[str, ...]] = {
    "sit": ("pelvis", "left_hip", "right_hip"),
    "lie down": ("pelvis", "left_hip", "right_hip", "spine1", "spine2", "spine3"),
    "pick up": HAND_NAMES,
}


@dataclass
class InteractionObject:
    """The object one interaction is done with: its id and its pose per frame (T, 4, 4)."""
    oid: int
    poses: np.ndarray


class BodyMeshes:
    """Posed body meshes of a body model for the joints of `joint_set`."""

    def __init__(self, bm: BodyModel, joint_set: JointSet, cfg: ContactConfig = ContactConfig()):
        self.bm, self.joint_set, self.cfg = bm, joint_set, cfg
        self.surface = BodySurface(bm, joint_set)
        names = list(joint_set.names)
        self._parts = {a: np.flatnonzero(np.isin(self.surface.region, [names.index(n) for n in p if n in names]))
                       for a, p in MESH_PARTS.items()}

    def part_vertices(self, action: str) -> np.ndarray:
        """(K,) vertex ids of the body part that carries `action` (empty for other actions)."""
        return self._parts.get(action, np.zeros(0, np.int64))

    def of_joints(self, joints: np.ndarray) -> BodyParams:
        """A body on joints (T, J, 3): the shape whose bones have the motion's median lengths,
        each frame posed analytically (pelvis where it is, limbs by two-bone IK to the wrists
        and ankles). What the joints say, on a body; nothing is cleaned up."""
        j = np.asarray(joints, np.float64)[None]                                            # (1, T, J, 3)
        body = MotionBody.estimate(self.bm, self.joint_set, j)
        _, R, transl = body.project(j)                                                      # (1, T, 22, 3, 3), (1, T, 3)
        aa = matrix_to_axis_angle(R[0]).numpy()                                             # (T, 22, 3)
        return BodyParams(global_orient=aa[:, 0], body_pose=aa[:, 1:].reshape(len(aa), 63),
                          transl=transl[0].numpy(), betas=body.betas[0].numpy())

    def posed(self, params: BodyParams, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vertices and unit normals (F, V, 3) at `frames` (F,) int."""
        return self.surface.pose({"global_orient": params.global_orient, "body_pose": params.body_pose,
                                  "transl": params.transl, "betas": params.betas}, frames)

    def penetration_vertices(self, params: BodyParams, frames: int) -> np.ndarray:
        """(T', V', 3) every 3rd of the first `frames` frames, every 8th vertex."""
        return self.bm.motion_vertices(params, slice(0, frames, 3), np.arange(0, self.bm.num_vertices, 8))


def seat_contact(meshes: BodyMeshes, targets: SceneTargets, params: BodyParams, labels, action_names,
                 actions, every: int) -> tuple[int, int]:
    """(frames in contact, frames measured) over the frames labelled with any of `actions`: a
    vertex of the action's part touches the scene or the floor."""
    hits = total = 0
    for a in actions:
        if a not in action_names:
            continue
        frames = np.flatnonzero(np.asarray(labels)[:, action_names.index(a)])[::every]
        rows = meshes.part_vertices(a)
        if not frames.size or not rows.size:
            continue
        V, N = meshes.posed(params, frames)
        c = vertex_contacts(V[:, rows], N[:, rows], targets, cfg=meshes.cfg)
        hits, total = hits + int(c.contact.any(1).sum()), total + int(frames.size)
    return hits, total


def hand_object(meshes: BodyMeshes, field, params: BodyParams, frames: np.ndarray, obj: InteractionObject) -> dict:
    """Hand vertices against one object over `frames` (F,) int: contact frames (a hand vertex
    inside the object or within the threshold with its normal facing it), frames with a hand
    vertex inside, and the closest signed distance (m, negative: inside)."""
    rows = meshes.part_vertices("pick up")
    if not frames.size or not rows.size:
        return {"hits": 0, "inside": 0, "frames": 0, "sdist": float("nan")}
    V, N = meshes.posed(params, frames)
    V, N = V[:, rows], N[:, rows]
    targets = SceneTargets()
    targets.objects[obj.oid] = field
    targets.radius[obj.oid] = (np.zeros(3), np.inf)
    poses = np.asarray(obj.poses, np.float64)[frames]                                      # (F, 4, 4)
    c = vertex_contacts(V, N, targets, np.full((len(frames), 1), obj.oid), poses[:, None], meshes.cfg)
    sd = np.array([field.query(V[f], pose=poses[f]).distance.min() for f in range(len(frames))])   # (F,)
    return {"hits": int(c.contact.any(1).sum()), "inside": int((sd < 0).sum()), "frames": int(len(frames)),
            "sdist": float(sd.min())}


def mesh_scores(meshes: BodyMeshes, ctx, params: BodyParams, labels, action_names, setting: str, cfg,
                objects: list[tuple[np.ndarray, InteractionObject]] = (), every: int = 2) -> dict:
    """Per-motion mesh figures (keys starting with _ are pooled counts). labels (T, A) bool;
    objects: [(frames (F,) int, object)] — each interaction's frames and its object."""
    v = meshes.penetration_vertices(params, len(labels))                                   # (T', V', 3)
    pen = M.scene_penetration(np.zeros((len(v), 0, 3)), ctx.grid, vertices=v, sdf=ctx.sdf)
    out = {"mesh_penetration_frames": pen["frame_ratio"], "mesh_penetration_max_m": pen["max_depth"],
           "_mesh_hits": 0, "_mesh_frames": 0, "_inside": 0, "_hand_frames": 0, "_touched": [], "_sdist": []}
    if setting == "static":
        h, n = seat_contact(meshes, ctx.contact_targets(), params, labels, list(action_names),
                            cfg.static_actions, every)
        out["_mesh_hits"], out["_mesh_frames"] = h, n
        return out
    for frames, obj in objects:
        field = ctx.object_field(obj.oid)
        if field is None:
            continue
        r = hand_object(meshes, field, params, np.asarray(frames, np.int64)[::every], obj)
        out["_touched"].append(float(r["hits"] > 0))
        if not r["frames"]:
            continue                          # never got to act: not touched, nothing to measure
        out["_mesh_hits"] += r["hits"]
        out["_mesh_frames"] += r["frames"]
        out["_inside"] += r["inside"]
        out["_hand_frames"] += r["frames"]
        out["_sdist"].append(r["sdist"])
    return out



def pooled(rows: list[dict]) -> dict:
    """Setting-level mesh figures of per-motion `mesh_scores` dicts: contact and hand-inside
    pooled over measured frames, touched and the signed distance over interactions."""
    def ratio(a, b):
        n = sum(m.get(b, 0) for m in rows)
        return sum(m.get(a, 0) for m in rows) / n if n else float("nan")

    touched = [x for m in rows for x in m.get("_touched", [])]
    sdist = [x for m in rows for x in m.get("_sdist", [])]
    return {"mesh_contact_rate": ratio("_mesh_hits", "_mesh_frames"),
            "hand_inside_frames": ratio("_inside", "_hand_frames"),
            "touched": float(np.mean(touched)) if touched else float("nan"),
            "hand_object_sdist_m": float(np.mean(sdist)) if sdist else float("nan")}
