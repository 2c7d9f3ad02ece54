"""Skinned glTF 2.0 (binary .glb) export of generated motion, for Blender, three.js, Unity.

One sample is one skinned body: the shaped SMPL-X mesh in its rest pose, a skeleton of the 22
body joints (nodes named as the BVH export names them, `skeleton.BODY_JOINT_NAMES`; the
model's extra joints, e.g. the index1 fingers, ride as unweighted child bones), and one
animation of local joint rotations plus the root's translation. Posing a node tree by those
channels is exactly `MotionBody.pose`: joint j = G_parent · (J_j − J_parent) + posed parent,
the root at J_0(β) + transl. World: y-up, metres (glTF's own convention, so nothing turns).

pygltflib builds the document; the binary buffer is one blob we fill with numpy arrays.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pygltflib as gl
import torch
import trimesh
from scipy.spatial.transform import Rotation

from motiongen.skeleton import BODY_JOINT_NAMES, BODY_PARENTS, EXTRA_JOINTS, NUM_BODY_JOINTS

_WIDTH = {gl.SCALAR: 1, gl.VEC3: 3, gl.VEC4: 4, gl.MAT4: 16}
_COMPONENT = {np.dtype(np.float32): gl.FLOAT, np.dtype(np.uint16): gl.UNSIGNED_SHORT,
              np.dtype(np.uint32): gl.UNSIGNED_INT}
INFLUENCES = 4    # JOINTS_0 / WEIGHTS_0 hold 4 per vertex: what every glTF loader skins with


class _Glb:
    """One glTF document under construction: its `GLTF2` and the bytes of its single buffer."""

    def __init__(self):
        self.doc = gl.GLTF2(asset=gl.Asset(generator="motiongen"), scenes=[gl.Scene(nodes=[])], scene=0)
        self.blob = bytearray()

    def accessor(self, data: np.ndarray, kind: str, target: int | None = None, bounds: bool = False) -> int:
        """Append `data` (count, width) as a buffer view of its own and an accessor over it;
        bounds: min/max, which the spec requires of POSITION and animation inputs."""
        data = np.ascontiguousarray(data)
        self.blob += b"\0" * (-len(self.blob) % 4)             # every component type stays aligned
        self.doc.bufferViews.append(gl.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=data.nbytes,
                                                  target=target))
        self.blob += data.tobytes()
        flat = data.reshape(-1, _WIDTH[kind])
        acc = gl.Accessor(bufferView=len(self.doc.bufferViews) - 1, componentType=_COMPONENT[data.dtype],
                          count=len(flat), type=kind)
        if bounds:
            acc.min, acc.max = flat.min(0).tolist(), flat.max(0).tolist()
        self.doc.accessors.append(acc)
        return len(self.doc.accessors) - 1

    def node(self, **fields) -> int:
        self.doc.nodes.append(gl.Node(**fields))
        return len(self.doc.nodes) - 1

    def finish(self) -> gl.GLTF2:
        self.blob += b"\0" * (-len(self.blob) % 4)             # the GLB BIN chunk is 4-byte aligned
        self.doc.buffers = [gl.Buffer(byteLength=len(self.blob))]
        self.doc.set_binary_blob(bytes(self.blob))
        return self.doc


# ---- the body --------------------------------------------------------------------------

def _betas(body_model, betas) -> np.ndarray:
    """(nβ,) float64: `betas` cut or zero-padded to the model's number of shape coefficients."""
    b = np.zeros(body_model.num_betas)
    given = np.asarray(betas if betas is not None else [], np.float64).reshape(-1)[: body_model.num_betas]
    b[: len(given)] = given
    return b


def _shaped_rest(body_model, betas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3), joints (J, 3)) of the shaped body in rest pose, float64. The joints
    come from the model's own regression (`rest_joints`), the same numbers `MotionBody` poses."""
    t = body_model.J_template
    with torch.no_grad():
        joints = body_model.rest_joints(torch.as_tensor(betas, dtype=t.dtype, device=t.device), body_only=False)
        shapedirs = body_model._mesh(t.device, t.dtype)["shapedirs"]                       # (V, 3, nβ), cut to nβ
        verts = body_model.template_vertices + np.einsum("vck,k->vc", shapedirs.double().cpu().numpy(), betas)
    return verts, joints.double().cpu().numpy()


def _skeleton(body_model) -> tuple[list[str], list[int], list[int]]:
    """(names, parent in this list (-1: root), index in the model's joints) of the glTF
    skeleton: the 22 body joints first (skin joint j = body joint j), then the extra joints the
    model has (`EXTRA_JOINTS`), each a child of its body joint."""
    extras = [(name, BODY_JOINT_NAMES.index(parent), index) for name, (index, parent) in EXTRA_JOINTS.items()
              if index < len(body_model.full_parents)]
    return (list(BODY_JOINT_NAMES) + [e[0] for e in extras], list(BODY_PARENTS) + [e[1] for e in extras],
            list(range(NUM_BODY_JOINTS)) + [e[2] for e in extras])


def body_weights(weights: np.ndarray, full_parents) -> np.ndarray:
    """Skinning weights (V, J_full) -> (V, 22): each hand, eye or jaw joint's weight goes to its
    nearest body-joint ancestor. The motion leaves those joints at rest, so they move rigidly with
    that ancestor and the merged skin deforms the same."""
    owner = list(range(weights.shape[1]))              # (J_full,) the body joint each joint's weight goes to
    for j, a in enumerate(owner):
        while a >= NUM_BODY_JOINTS:
            a = full_parents[a]
        owner[j] = a
    merged = np.zeros((weights.shape[0], NUM_BODY_JOINTS))
    np.add.at(merged.T, np.asarray(owner), np.asarray(weights, np.float64).T)
    return merged


def top_influences(weights: np.ndarray, k: int = INFLUENCES) -> tuple[np.ndarray, np.ndarray]:
    """(V, J) weights -> (joint ids (V, k) uint16, weights (V, k) float32 summing to 1): the k
    largest per vertex, renormalised (glTF's JOINTS_0/WEIGHTS_0 carry 4)."""
    ids = np.argsort(-weights, axis=1, kind="stable")[:, :k]                                # (V, k)
    w = np.take_along_axis(weights, ids, 1).clip(min=0.0)
    w = w / np.maximum(w.sum(1, keepdims=True), 1e-12)
    w[w.sum(1) == 0, 0] = 1.0                          # an unweighted vertex: on its first joint
    return ids.astype(np.uint16), w.astype(np.float32)


def _add_mesh(glb: _Glb, verts: np.ndarray, faces: np.ndarray, weights: np.ndarray) -> int:
    """The skinned mesh primitive: positions, normals, 4 influences per vertex, triangles."""
    normals = trimesh.Trimesh(verts, faces, process=False).vertex_normals                  # (V, 3) unit
    ids, w = top_influences(weights)
    attrs = gl.Attributes(
        POSITION=glb.accessor(verts.astype(np.float32), gl.VEC3, gl.ARRAY_BUFFER, bounds=True),
        NORMAL=glb.accessor(normals.astype(np.float32), gl.VEC3, gl.ARRAY_BUFFER),
        JOINTS_0=glb.accessor(ids, gl.VEC4, gl.ARRAY_BUFFER),
        WEIGHTS_0=glb.accessor(w, gl.VEC4, gl.ARRAY_BUFFER))
    indices = glb.accessor(faces.astype(np.uint32).reshape(-1), gl.SCALAR, gl.ELEMENT_ARRAY_BUFFER)
    glb.doc.meshes.append(gl.Mesh(primitives=[gl.Primitive(attributes=attrs, indices=indices)]))
    return len(glb.doc.meshes) - 1


def _add_joints(glb: _Glb, body_model, rest: np.ndarray) -> tuple[list[int], list[int]]:
    """(joint nodes in skin order, their indices in `rest` (J_full, 3)); each node's translation
    is its offset from its parent in the shaped rest pose (the root: its rest position), its
    rotation the identity."""
    names, parents, full = _skeleton(body_model)
    nodes = []
    for j, (name, p, f) in enumerate(zip(names, parents, full)):
        offset = rest[f] - (rest[full[p]] if p >= 0 else 0.0)
        nodes.append(glb.node(name=name, translation=offset.tolist()))
        if p >= 0:
            glb.doc.nodes[nodes[p]].children.append(nodes[j])
    return nodes, full


def _add_body(glb: _Glb, body_model, betas, name: str) -> tuple[list[int], np.ndarray]:
    """One skinned body under a node `name` in the scene: (joint nodes in skin order, its rest
    joints (J_full, 3)). Linear blend skinning only: SMPL-X's pose correctives (pose blend
    shapes driven by joint rotations) have no glTF counterpart (morph targets are weighted by
    the animation, not by the pose), so bent elbows and knees lose those few millimetres."""
    verts, rest = _shaped_rest(body_model, _betas(body_model, betas))
    joints, full = _add_joints(glb, body_model, rest)
    ibm = np.tile(np.eye(4, dtype=np.float32), (len(full), 1, 1))                          # (J, 4, 4)
    ibm[:, 3, :3] = -rest[full]                        # translate(-J) stored column-major: the 4th column
    weights = body_weights(body_model.skinning_weights, body_model.full_parents)            # (V, 22)
    glb.doc.skins.append(gl.Skin(name=name, joints=joints, skeleton=joints[0],
                                 inverseBindMatrices=glb.accessor(ibm, gl.MAT4)))
    mesh = glb.node(name=f"{name}_body", mesh=_add_mesh(glb, verts, body_model.faces, weights),
                    skin=len(glb.doc.skins) - 1)
    glb.doc.scenes[0].nodes.append(glb.node(name=name, children=[mesh, joints[0]]))
    return joints, rest


def skinned_body(body_model, betas) -> gl.GLTF2:
    """The shaped body (betas (nβ,)) in rest pose as a skinned glTF document: node "body" holding
    the mesh and the skeleton (root "pelvis"). y-up, metres."""
    glb = _Glb()
    _add_body(glb, body_model, betas, "body")
    return glb.finish()


def body_glb_bytes(body_model, betas) -> bytes:
    """`skinned_body` as .glb bytes (no animation: a viewer sets the bone quaternions itself)."""
    return b"".join(skinned_body(body_model, betas).save_to_bytes())


# ---- the motion ------------------------------------------------------------------------

def _rotmats(body) -> np.ndarray:
    """(T, 22, 3, 3) local rotations of a BodyMotion, or from the axis-angle of any BodyParams
    (a `FitResult` has no matrices)."""
    if getattr(body, "rotmats", None) is not None:
        return np.asarray(body.rotmats, np.float64)
    aa = np.concatenate([np.asarray(body.global_orient).reshape(-1, 1, 3), np.asarray(body.body_pose).reshape(-1, 21, 3)], 1)
    return Rotation.from_rotvec(aa.reshape(-1, 3).astype(np.float64)).as_matrix().reshape(aa.shape[:2] + (3, 3))


def quaternions(rotmats: np.ndarray) -> np.ndarray:
    """(T, J, 3, 3) -> (T, J, 4) unit quaternions x, y, z, w (glTF's order), each frame on the
    same side as the one before: q and -q are one rotation, and a player interpolating between
    opposite signs would swing the long way round."""
    q = Rotation.from_matrix(rotmats.reshape(-1, 3, 3)).as_quat().reshape(rotmats.shape[:-2] + (4,))
    flip = np.where(np.sum(q[1:] * q[:-1], -1) < 0, -1.0, 1.0)                               # (T-1, J)
    q[1:] *= np.cumprod(flip, 0)[..., None]
    return q


def _add_animation(glb: _Glb, body, joints: list[int], rest_root: np.ndarray, fps: float, name: str) -> None:
    """One animation: a LINEAR rotation channel per body joint and the root's translation
    (rest root + transl per frame, as `MotionBody.pose` places it), keyed at frame / fps."""
    q = quaternions(_rotmats(body)).astype(np.float32)                                    # (T, 22, 4)
    times = glb.accessor((np.arange(len(q)) / fps).astype(np.float32), gl.SCALAR, bounds=True)
    samplers, channels = [], []
    outputs = [(j, "rotation", glb.accessor(q[:, j], gl.VEC4)) for j in range(NUM_BODY_JOINTS)]
    root = (rest_root + np.asarray(body.transl, np.float64)).astype(np.float32)            # (T, 3)
    outputs.append((0, "translation", glb.accessor(root, gl.VEC3)))
    for j, path, out in outputs:
        channels.append(gl.AnimationChannel(sampler=len(samplers),
                                            target=gl.AnimationChannelTarget(node=joints[j], path=path)))
        samplers.append(gl.AnimationSampler(input=times, output=out, interpolation=gl.ANIM_LINEAR))
    glb.doc.animations.append(gl.Animation(name=name, samplers=samplers, channels=channels))


def motion_document(bodies, body_model, fps: float, names=None) -> gl.GLTF2:
    """Every sample's skinned body (its own mesh and skeleton: samples may differ in shape) and
    animation, both named `names[s]` (default sample_<s>)."""
    names = list(names) if names is not None else [f"sample_{s}" for s in range(len(bodies))]
    glb = _Glb()
    for body, name in zip(bodies, names, strict=True):
        joints, rest = _add_body(glb, body_model, body.betas, name)
        _add_animation(glb, body, joints, rest[0], fps, name)
    return glb.finish()


def _write_atomic(path: str | Path, data: bytes) -> Path:
    """`data` to `path` through a temp name in the same directory: never a half-written file."""
    path = Path(path)
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def write_motion_glb(path: str | Path, bodies, body_model, fps: float, names=None) -> Path:
    """motion.glb: `bodies` (one BodyMotion, or any BodyParams, per sample) as skinned, animated
    bodies (`motion_document`). Returns the path."""
    return _write_atomic(path, b"".join(motion_document(bodies, body_model, fps, names).save_to_bytes()))


def write_scene_glb(path: str | Path, mesh: trimesh.Trimesh) -> Path:
    """scene.glb: the scene's y-up mesh in metres, through trimesh's own glb exporter."""
    return _write_atomic(path, mesh.export(file_type="glb"))
