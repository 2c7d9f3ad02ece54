"""The evaluation's figures on the body mesh (`motiongen.eval.mesh_scores`) and PSKL at equal
sizes, on geometry with known answers: a body in its rest pose, a box beside its hand or under
its hips, a body put back on its own joints."""

import numpy as np
import pytest
import torch
import trimesh

from motiongen.body.model import BodyParams, load_body_model
from motiongen.eval.mesh_scores import BodyMeshes, InteractionObject, hand_object, pooled, seat_contact
from motiongen.eval.motion_scores import only_during
from motiongen.eval.pskl_sets import even_subset, pskl_equal, reference_halves
from motiongen.annotation.vertex_contact import SceneTargets
from motiongen.scene.distance_field import MeshField, PlaneField
from motiongen.skeleton import BODY

T = 4


@pytest.fixture(scope="module")
def meshes():
    return BodyMeshes(load_body_model(), BODY)


def standing(yaw: float = 0.0, knee: float = 0.0) -> BodyParams:
    """T frames of the rest pose (arms out along x, the right hand at -x), pelvis 1 m up."""
    go, bp, tr = np.zeros((T, 3)), np.zeros((T, 63)), np.zeros((T, 3))
    go[:, 1], bp[:, 9], tr[:, 1] = yaw, knee, 1.0                       # body_pose[9]: left knee x
    return BodyParams(go, bp, tr, np.zeros(10))


def box_at(face_x: float, size: float = 1.0) -> tuple[MeshField, np.ndarray]:
    """A 1 m box whose +x face is at x = face_x, centred on the hand in y and z (field, pose)."""
    pose = np.eye(4)
    pose[:3, 3] = [face_x - size / 2, 1.1, 0.0]
    return MeshField(trimesh.creation.box([size] * 3), voxel_size=0.01), pose


def test_a_body_put_on_its_own_joints_is_that_body(meshes):
    p = standing(yaw=0.3, knee=0.5)
    J = meshes.bm.joints(*(torch.as_tensor(x, dtype=torch.float32) for x in (p.global_orient, p.body_pose, p.transl)))
    back = meshes.of_joints(J.numpy())
    err = np.linalg.norm(meshes.bm.motion_vertices(back) - meshes.bm.motion_vertices(p), axis=-1)
    assert err.max() < 0.003, err.max()                             # millimetres over 10,475 vertices


def test_every_action_has_its_body_part(meshes):
    hands, seat = meshes.part_vertices("pick up"), meshes.part_vertices("sit")
    assert len(hands) > 1000 and len(seat) > 1000 and not set(hands) & set(seat)
    assert set(seat) < set(meshes.part_vertices("lie down")) and not len(meshes.part_vertices("walk"))


@pytest.mark.parametrize("gap", [0.10, 0.005, -0.05])
def test_signed_hand_object_distance_closed_form(meshes, gap):
    """The right fingertips reach x = tip; a box face at tip - gap: the closest hand vertex is
    `gap` away (negative: that deep inside). Inside or within 2 cm facing it is contact."""
    p = standing()
    tip = meshes.bm.motion_vertices(p, slice(0, 1), meshes.part_vertices("pick up"))[0, :, 0].min()
    field, pose = box_at(tip - gap)
    r = hand_object(meshes, field, p, np.arange(T), InteractionObject(7, np.repeat(pose[None], T, 0)))
    assert r["sdist"] == pytest.approx(gap, abs=1e-6) and r["frames"] == T
    assert r["inside"] == (T if gap < 0 else 0)
    assert r["hits"] == (T if gap < 0.02 else 0)


def test_seat_contact_needs_the_seat_under_the_hips(meshes):
    p = standing()
    low = meshes.bm.motion_vertices(p, slice(0, 1), meshes.part_vertices("sit"))[0, :, 1].min()   # lowest thigh skin
    labels = np.zeros((T, 2), bool)
    labels[1:, 1] = True                                                                         # "sit" on 3 frames
    for top, hits in ((low + 0.01, 3), (low - 0.10, 0)):
        seat = np.eye(4)
        seat[:3, 3] = [0.0, top - 0.25, 0.0]
        box = trimesh.creation.box([0.5, 0.5, 0.5])
        box.apply_transform(seat)
        targets = SceneTargets(floor=PlaneField(0.0), scene=MeshField(box, voxel_size=0.02))
        assert seat_contact(meshes, targets, p, labels, ["walk", "sit"], ("sit",), every=1) == (hits, 3)


def test_pooled_counts_frames_and_interactions():
    rows = [{"_mesh_hits": 3, "_mesh_frames": 4, "_inside": 1, "_hand_frames": 4, "_touched": [1.0], "_sdist": [-0.01]},
            {"_mesh_hits": 0, "_mesh_frames": 0, "_inside": 0, "_hand_frames": 0, "_touched": [0.0], "_sdist": []}]
    out = pooled(rows)
    assert out == {"mesh_contact_rate": 0.75, "hand_inside_frames": 0.25, "touched": 0.5, "hand_object_sdist_m": -0.01}


def test_an_interaction_object_counts_during_its_own_frames_only():
    poses = np.repeat(np.eye(4)[None], 10, 0)
    oid, p = only_during(np.arange(3, 6), InteractionObject(4, poses))
    far = np.linalg.norm(p[:, :3, 3], axis=-1) > 1e5
    assert oid == 4 and far.tolist() == [True] * 3 + [False] * 3 + [True] * 4


def test_pskl_halves_have_equal_size_and_come_from_other_sequences():
    rng = np.random.default_rng(0)
    motions = [rng.normal(size=(n, 3, 3)).cumsum(0) + k for k, n in enumerate((130, 61, 250, 70, 180))]
    a, b = reference_halves(motions, 30)
    # chunks of sequences 0, 2, 4 (4 + 8 + 6 = 18) against 1, 3 (2 + 2 = 4): both thinned to 4
    assert len(a) == len(b) == 4
    assert not any(any(np.shares_memory(c, motions[i]) for i in (0, 2, 4)) for c in b)
    assert not any(any(np.shares_memory(c, motions[i]) for i in (1, 3)) for c in a)
    kab, kba, n = pskl_equal(a, a, 30.0, 30)
    assert (kab, kba, n) == (0.0, 0.0, 4)
    _, _, n = pskl_equal(motions, b, 30.0, 30)                     # 22 generated chunks: thinned to the half's 4
    assert n == 4 and even_subset(list(range(10)), 4) == [0, 2, 5, 7]
