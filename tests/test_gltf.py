"""Skinned glTF export (motiongen.export.gltf): a .glb re-read with pygltflib and posed here, in
numpy, by the glTF rules (node TRS, animation keys, linear blend skinning with the inverse bind
matrices) must give back the motion's joints and the body model's mesh."""

from __future__ import annotations

import numpy as np
import pygltflib as gl
import pytest
import torch
import trimesh

from motiongen.body.model import BodyModel
from motiongen.body.rotations import axis_angle_to_matrix
from motiongen.body.solve import BodyMotion, MotionBody
from motiongen.export.gltf import body_glb_bytes, body_weights, top_influences, write_motion_glb, write_scene_glb
from motiongen.skeleton import BODY_JOINT_NAMES, BODY_PARENTS, get_joint_set
from tests.run_inprocess import run_command
from tests.test_sample_cli import _checkpoint

FPS = 30.0
_TYPES = {gl.FLOAT: np.float32, gl.UNSIGNED_SHORT: np.uint16, gl.UNSIGNED_INT: np.uint32, gl.UNSIGNED_BYTE: np.uint8}


def make_motion(bm: BodyModel, seed: int, T: int = 12) -> BodyMotion:
    """A body of random shape posed by random small rotations (≤ ~0.4 rad a joint) on a drifting
    root: its joints from `MotionBody.pose`, as the sampler makes them (index1 joints too)."""
    g = torch.Generator().manual_seed(seed)
    betas = torch.randn(1, bm.num_betas, generator=g)
    body = MotionBody(bm, get_joint_set("body+index1"), betas)
    aa = 0.25 * torch.randn(T, 22, 3, generator=g) + 0.1 * torch.linspace(-1, 1, T)[:, None, None]
    aa[:, 0, 1] += torch.linspace(0, 3.0, T)                         # the root turns right round
    R = axis_angle_to_matrix(aa)                                     # (T, 22, 3, 3)
    transl = torch.cumsum(0.03 * torch.randn(T, 3, generator=g), 0)
    J = body.pose(R[None], transl[None])[0]                          # (T, 24, 3)
    return BodyMotion(global_orient=aa[:, 0].numpy(), body_pose=aa[:, 1:].reshape(T, 63).numpy(),
                      transl=transl.numpy(), betas=betas[0].numpy(), joints=J.numpy(), rotmats=R.numpy())


# ---- reading a .glb back, in numpy -------------------------------------------------------

def accessor(doc: gl.GLTF2, i: int) -> np.ndarray:
    acc = doc.accessors[i]
    view = doc.bufferViews[acc.bufferView]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[acc.type]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    a = np.frombuffer(doc.binary_blob(), _TYPES[acc.componentType], acc.count * width, start)
    return a.reshape(acc.count, width) if width > 1 else a


def trs(t, q) -> np.ndarray:
    """4x4 of a node's translation and quaternion (x, y, z, w)."""
    x, y, z, w = np.asarray(q if q is not None else (0, 0, 0, 1), np.float64)
    M = np.eye(4)
    M[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    M[:3, 3] = t if t is not None else 0.0
    return M


def world_matrices(doc: gl.GLTF2, anim: gl.Animation | None, frame: int) -> list[np.ndarray]:
    """Every node's world matrix with `anim`'s keys of `frame` applied (the nodes' own TRS
    elsewhere): what a glTF player shows at time frame / fps."""
    local = {i: [n.translation, n.rotation] for i, n in enumerate(doc.nodes)}
    for ch in (anim.channels if anim is not None else []):
        value = accessor(doc, anim.samplers[ch.sampler].output)[frame]
        local[ch.target.node][0 if ch.target.path == "translation" else 1] = value
    parent = {c: i for i, n in enumerate(doc.nodes) for c in n.children}
    out = {}

    def world(i):
        if i not in out:
            out[i] = (world(parent[i]) if i in parent else np.eye(4)) @ trs(*local[i])
        return out[i]

    return [world(i) for i in range(len(doc.nodes))]


def skin_vertices(doc: gl.GLTF2, mesh_node: int, W: list[np.ndarray]) -> np.ndarray:
    """(V, 3) linear blend skinning by the glTF rule: Σ_k w_k · world(joint_k) · IBM_k · v."""
    node = doc.nodes[mesh_node]
    skin, prim = doc.skins[node.skin], doc.meshes[node.mesh].primitives[0]
    ibm = accessor(doc, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)   # column-major
    M = np.stack([W[j] @ ibm[k] for k, j in enumerate(skin.joints)])                      # (J, 4, 4)
    v = accessor(doc, prim.attributes.POSITION).astype(np.float64)
    ids, w = accessor(doc, prim.attributes.JOINTS_0), accessor(doc, prim.attributes.WEIGHTS_0)
    Mv = np.einsum("vkab,vb->vka", M[ids], np.c_[v, np.ones(len(v))])                     # (V, 4, 4)
    return np.einsum("vk,vka->va", w, Mv)[:, :3]


def posed_joints(doc: gl.GLTF2, s: int, frame: int) -> np.ndarray:
    """(J, 3) sample s's skeleton at `frame` of its animation."""
    W = world_matrices(doc, doc.animations[s], frame)
    return np.stack([W[j][:3, 3] for j in doc.skins[s].joints])


# ---- tests ---------------------------------------------------------------------------------

def test_motion_glb_round_trips_to_the_joints(bm, tmp_path):
    bodies = [make_motion(bm, 0), make_motion(bm, 1, T=9)]          # two shapes, two lengths
    path = write_motion_glb(tmp_path / "motion.glb", bodies, bm, FPS)
    assert path == tmp_path / "motion.glb" and [p.name for p in tmp_path.iterdir()] == ["motion.glb"]
    doc = gl.GLTF2().load(str(path))
    assert [a.name for a in doc.animations] == ["sample_0", "sample_1"] and len(doc.skins) == 2
    for s, body in enumerate(bodies):
        skin = doc.skins[s]
        names = [doc.nodes[j].name for j in skin.joints]
        assert tuple(names[:22]) == BODY_JOINT_NAMES and names[22:] == ["left_index1", "right_index1"]
        times = accessor(doc, doc.animations[s].samplers[0].input)
        np.testing.assert_allclose(times, np.arange(len(body.joints)) / FPS, atol=1e-6)
        assert {smp.interpolation for smp in doc.animations[s].samplers} == {"LINEAR"}
        for t in (0, len(times) // 2, len(times) - 1):
            err = np.linalg.norm(posed_joints(doc, s, t) - body.joints[t], axis=-1)    # index1 joints too
            assert err.max() < 1e-3, (s, t, err.max())


def test_motion_from_axis_angle_parameters(bm, tmp_path):
    """A `FitResult`-like body without rotation matrices (the body=true fit) poses the same."""
    body = make_motion(bm, 2)
    body.rotmats = None
    doc = gl.GLTF2().load(str(write_motion_glb(tmp_path / "m.glb", [body], bm, 20.0, names=["walk"])))
    assert doc.animations[0].name == "walk" and accessor(doc, doc.animations[0].samplers[0].input)[1] == pytest.approx(0.05)
    err = np.linalg.norm(posed_joints(doc, 0, 7) - body.joints[7], axis=-1)
    assert err.max() < 1e-3


def test_skinned_mesh_matches_the_body_model(model_path, tmp_path):
    """glTF skinning of the exported rest mesh at a posed frame = the body model's own mesh of
    that pose without SMPL-X pose correctives (glTF cannot express them): zeroed here, in a model
    of this test's own, so the two skinnings must agree to float precision."""
    bm = BodyModel(model_path)
    body = make_motion(bm, 3)
    doc = gl.GLTF2().load(str(write_motion_glb(tmp_path / "motion.glb", [body], bm, FPS)))
    t = 5
    mesh_node = next(i for i, n in enumerate(doc.nodes) if n.skin is not None)
    got = skin_vertices(doc, mesh_node, world_matrices(doc, doc.animations[0], t))
    R, tr, b = (torch.as_tensor(x) for x in (body.rotmats[t], body.transl[t], body.betas))
    with_correctives = bm.vertices_from_rotmats(R, tr, b).numpy()
    bm._mesh(bm.J_template.device, bm.J_template.dtype)["posedirs"].zero_()
    want = bm.vertices_from_rotmats(R, tr, b).numpy()
    assert np.abs(got - want).max() < 2e-4
    # What the missing correctives cost here: real, and small (the procedural model's are mild).
    gap = np.linalg.norm(got - with_correctives, axis=-1).max()
    assert 1e-5 < gap < 0.02, gap


def test_rest_body_bytes_weights_and_normals(bm):
    doc = gl.GLTF2.load_from_bytes(body_glb_bytes(bm, np.full(bm.num_betas, 0.5)))
    assert not doc.animations and len(doc.skins) == 1
    prim = doc.meshes[0].primitives[0]
    ids, w = accessor(doc, prim.attributes.JOINTS_0), accessor(doc, prim.attributes.WEIGHTS_0)
    assert ids.shape == w.shape == (bm.num_vertices, 4)
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)
    assert ids.max() < 22 and (w >= 0).all()                        # hand and face weights went to body joints
    n = accessor(doc, prim.attributes.NORMAL)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-4)
    # The rest skeleton is the shaped one: the rest mesh skinned at rest is itself.
    W = world_matrices(doc, None, 0)
    v = accessor(doc, prim.attributes.POSITION)
    np.testing.assert_allclose(skin_vertices(doc, next(i for i, x in enumerate(doc.nodes) if x.skin is not None), W),
                               v, atol=1e-5)
    rest = bm.rest_joints(torch.full((bm.num_betas,), 0.5)).numpy()
    np.testing.assert_allclose(np.stack([W[j][:3, 3] for j in doc.skins[0].joints[:22]]), rest, atol=1e-5)


def test_weights_merge_into_body_joints_and_keep_four():
    full = BODY_PARENTS + (20, 22, 23)                               # a finger chain under left_wrist (20)
    W = np.zeros((2, 25))
    W[0, [20, 22, 23, 24]] = 0.25                                    # all of a finger on the wrist
    W[1, [0, 1, 2, 3, 4, 5]] = [0.3, 0.25, 0.2, 0.1, 0.1, 0.05]      # six influences
    merged = body_weights(W, full)
    assert merged.shape == (2, 22) and merged[0, 20] == pytest.approx(1.0)
    ids, w = top_influences(merged)
    assert ids.dtype == np.uint16 and list(ids[1]) == [0, 1, 2, 3]
    np.testing.assert_allclose(w[1], np.array([0.3, 0.25, 0.2, 0.1]) / 0.85, rtol=1e-6)
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-6)


def test_scene_glb_is_the_mesh(tmp_path):
    box = trimesh.creation.box([2.0, 1.0, 3.0])
    path = write_scene_glb(tmp_path / "scene.glb", box)
    back = trimesh.load(path, force="mesh")
    np.testing.assert_allclose(back.bounds, box.bounds, atol=1e-6)
    assert [p.name for p in tmp_path.iterdir()] == ["scene.glb"]


@pytest.mark.parametrize("project", [True, False])
def test_sample_gltf_true_end_to_end(model_path, tmp_path, capsys, project):
    """gltf=true writes motion.glb, posing motion.npz's joints (loop.project=false: no body, so
    each sample is fitted as body=true fits it, and the glb poses that fit, body_<s>.npz), and
    scene.glb for a mesh scene."""
    d = tmp_path / "in"
    d.mkdir()
    ckpt = _checkpoint(d / "tiny.pt")
    room = trimesh.util.concatenate([trimesh.creation.box([4.0, 0.02, 4.0]),
                                     trimesh.creation.box([1.0, 1.0, 1.0], trimesh.transformations.translation_matrix([0, 0.5, 0]))])
    room.export(d / "room.obj")
    out = tmp_path / "out"
    r = run_command("sample", [f"ckpt={ckpt}", f"scene={d / 'room.obj'}", "start=[-1.5,-1.5]", "goals=[[1.5,-1.0]]",
                               "steps=2", "num_samples=2", "gltf=true", f"body={not project}", "video=false",
                               "plot=false", "loop.max_episodes=2", "loop.warmup=1", f"loop.project={project}",
                               f"body_model={model_path}", f"out={out}", "threads=1"], capsys)
    assert r.returncode in (0, 3), r.stderr[-2000:]              # 3: the random model reached no goal
    assert {"motion.glb", "scene.glb", "motion.npz"} <= {p.name for p in out.iterdir()}
    doc = gl.GLTF2().load(str(out / "motion.glb"))
    with np.load(out / "motion.npz") as z:
        joints, fps = z["joints"], float(z["fps"])
    assert len(doc.animations) == 2
    for s in range(2):
        if not project:
            with np.load(out / f"body_{s}.npz") as z:
                joints[s, :, :22] = z["joints"]
        times = accessor(doc, doc.animations[s].samplers[0].input)
        assert len(times) == joints.shape[1] and times[1] == pytest.approx(1 / fps)
        for t in (0, joints.shape[1] // 2, joints.shape[1] - 1):
            assert np.linalg.norm(posed_joints(doc, s, t)[:22] - joints[s, t, :22], axis=-1).max() < 0.01
    scene = trimesh.load(out / "scene.glb", force="mesh")
    np.testing.assert_allclose(scene.bounds, room.bounds, atol=1e-4)
