"""Per-vertex contact annotation (TRUMANS supp. B.6): the contact rule on known geometry (a box
touched at 1 cm facing it / facing away / inside, as a static mesh, a posed object and a grid),
the hand holding a bottle (the far side of the hand must not count), exact distance fields, the
labels on disk (round trip, memory maps, per-joint summary, penetration statistics of known
depth), the CLI and its errors, a joint-only (fitted) dataset and the TRUMANS layout."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
import trimesh

from motiongen.body.model import load_body_model
from motiongen.annotation.annotate_contact import annotate_dataset, main
from motiongen.annotation.vertex_contact import (FLOOR, NONE, SCENE, BodySurface, ContactConfig, SceneTargets, joint_targets,
                                    vertex_contacts)
from motiongen.scene.distance_field import GridField, MeshField, PlaneField, lattice_samples, winding_numbers
from motiongen.data.format import MotionDataset
from motiongen.data.dataset_writer import DatasetWriter
from motiongen.scene.voxelize import voxelize_mesh
from motiongen.errors import DataError
from motiongen.skeleton import BODY
from tests.helpers import HOLD, SMALL, make_dataset, user_error, write_fake_release, write_posed_release

BOX = trimesh.creation.box(extents=(0.4, 0.4, 0.4))          # x, y, z in [-0.2, 0.2]
E = np.eye(3)


def _one(points, normals, targets, ids=None, poses=None, **cfg):
    c = vertex_contacts(np.asarray(points, float)[None], np.asarray(normals, float)[None], targets,
                        None if ids is None else np.asarray(ids)[None], None if poses is None else np.asarray(poses)[None],
                        ContactConfig(**cfg))
    return c.target[0], c.distance[0], c.penetration[0]


def _tilted(angle_deg):
    """A unit normal at `angle_deg` from -x (the direction from x = 0.21 to the box face)."""
    a = np.radians(angle_deg)
    return [-np.cos(a), np.sin(a), 0.0]


# (point, normal, expected contact): 1 cm outside facing the box / facing away / inside /
# 3 cm outside / 50 and 70 degrees off
CASES = [([0.21, 0, 0], -E[0], True), ([0.21, 0, 0], E[0], False), ([0.19, 0, 0], E[0], True),
         ([0.23, 0, 0], -E[0], False), ([0.21, 0, 0], _tilted(50), True), ([0.21, 0, 0], _tilted(70), False)]


@pytest.mark.parametrize("kind", ["mesh", "grid"])
def test_box_touched_facing_away_inside(kind):
    fld = MeshField(BOX, voxel_size=0.01) if kind == "mesh" else GridField(voxelize_mesh(BOX, 0.005))
    pts, nrm, want = (np.array([c[i] for c in CASES], float) for i in range(3))
    tgt, dist, pen = _one(pts, nrm, SceneTargets(scene=fld))
    assert (tgt == SCENE).tolist() == want.astype(bool).tolist()
    tol = 1e-9 if kind == "mesh" else fld.error
    assert dist[0] == pytest.approx(0.01, abs=tol) and dist[2] == pytest.approx(-0.01, abs=tol)
    assert pen[2] == pytest.approx(0.01, abs=tol) and pen[0] == 0


def test_posed_object_and_floor():
    """The same box as an object rotated and moved: its id is the target; the floor plane too."""
    M = np.eye(4)
    M[:3, :3] = trimesh.transformations.rotation_matrix(0.6, [0, 1, 0])[:3, :3]
    M[:3, 3] = (1.0, 0.2, -0.5)                                             # bottom face on the floor
    pts = np.array([c[0] for c in CASES]) @ M[:3, :3].T + M[:3, 3]
    nrm = np.array([c[1] for c in CASES]) @ M[:3, :3].T
    t = SceneTargets(floor=PlaneField(0.0))
    t.add_object(7, MeshField(BOX, voxel_size=0.01), BOX.vertices)
    tgt, _, _ = _one(pts, nrm, t, ids=[7, -1], poses=[M, np.eye(4)])
    assert (tgt == 7).tolist() == [c[2] for c in CASES]
    # 1 cm above the floor facing down: floor; facing up: nothing; 5 mm under: floor, 5 mm deep
    tgt, dist, pen = _one([[3, 0.01, 3], [3, 0.01, 3], [3, -0.005, 3]], [-E[1], E[1], E[1]], t)
    assert tgt.tolist() == [FLOOR, NONE, FLOOR]
    assert dist[0] == pytest.approx(0.01) and pen[2] == pytest.approx(0.005)


def test_threshold_and_angle_are_configurable():
    t = SceneTargets(scene=MeshField(BOX, voxel_size=0.01))
    tgt, _, _ = _one([[0.23, 0, 0], [0.21, 0, 0]], [-E[0], _tilted(70)], t, threshold=0.04, max_angle=80)
    assert (tgt == SCENE).all()


def test_hand_holding_a_bottle():
    """A hand wrapped round a bottle, as a closed shell: its inner side (2 mm off, facing the
    bottle) touches; its outer side is 1.7 cm from the bottle - within the 2 cm threshold - but
    faces away, and must not count (it does with distance alone)."""
    bottle = trimesh.creation.cylinder(radius=0.035, height=0.25, sections=32)
    hand = trimesh.creation.annulus(r_min=0.037, r_max=0.052, height=0.08, sections=32)
    r = np.linalg.norm(hand.vertices[:, :2], axis=1)
    inner, outer = r < 0.04, r > 0.05
    t = SceneTargets()
    t.add_object(3, MeshField(bottle, voxel_size=0.005), bottle.vertices)
    args = (hand.vertices, hand.vertex_normals, t, [3], np.eye(4)[None])
    tgt, _, _ = _one(*args)
    assert (tgt[inner] == 3).all() and not (tgt[outer] == 3).any()
    dist = t.objects[3].query(hand.vertices).distance
    assert dist[outer] == pytest.approx(0.017, abs=1e-3)                   # within the threshold
    tgt_any, _, _ = _one(*args, max_angle=180.0)                           # distance alone
    assert (tgt_any[outer] == 3).all()


def test_body_hand_on_a_bar(tmp_path):
    """The procedural body's left hand resting on a bar: palm-side vertices touch; hand and
    forearm vertices within 2 cm that face away do not; the per-joint summary says the left
    wrist's part (the hand) touches it."""
    bm = load_body_model()
    body = BodySurface(bm, BODY)
    params = {"global_orient": np.zeros((1, 3)), "body_pose": np.zeros((1, 63)), "transl": np.zeros((1, 3)),
              "betas": np.zeros(10)}
    V, N = body.pose(params, slice(0, 1))
    hand = body.region == BODY.index("left_wrist")
    hv = V[0, hand]
    bar = trimesh.creation.cylinder(radius=0.03, height=0.4, sections=48)
    bar.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))    # along x
    M = np.eye(4)
    M[:3, 3] = (hv[:, 0].mean(), hv[:, 1].min() - 0.033, hv[:, 2].mean())              # top 3 mm under the palm
    t = SceneTargets()
    t.add_object(5, MeshField(bar, voxel_size=0.005), bar.vertices)
    c = vertex_contacts(V, N, t, np.array([[5]]), M[None, None], ContactConfig())
    q = t.objects[5].query(V[0], pose=M)
    near = (q.distance >= 0) & (q.distance <= 0.02)                         # outside, within 2 cm
    facing = np.einsum("vc,vc->v", N[0], q.direction) > 0.5
    assert (c.target[0][near & facing] == 5).all() and (near & facing & hand).sum() >= 10
    assert (near & ~facing).sum() >= 20 and not (c.target[0][near & ~facing] == 5).any()
    assert (c.target[0][q.distance < 0] == 5).all()                          # whatever sinks in touches
    jt = joint_targets(c, body.region, BODY.num_joints)
    assert jt[0, BODY.index("left_wrist")] == 5 and jt[0, BODY.index("right_wrist")] == NONE


def test_fields_exact_on_overlapping_parts():
    """Two overlapping boxes: winding number 2 in the overlap; depths measured to the union's
    surface, not to a face buried inside the other box; the sample lattice covers every face."""
    b2 = BOX.copy()
    b2.apply_translation([0.3, 0, 0])
    union = trimesh.util.concatenate([BOX, b2])
    pts = np.array([[0.15, 0, 0], [0.25, 0, 0], [0.55, 0, 0], [0.6, 0.3, 0]])
    assert np.round(winding_numbers(pts, union.triangles)).tolist() == [2, 1, 0, 0]
    f = MeshField(union, voxel_size=0.01)
    assert f(pts) == pytest.approx([-0.2, -0.2, 0.05, np.hypot(0.1, 0.1)], abs=1e-9)
    samples, owner = lattice_samples(np.asarray(union.triangles), 0.05)
    probe = trimesh.sample.sample_surface(union, 500, seed=0)[0]
    from scipy.spatial import cKDTree
    assert cKDTree(samples).query(probe)[0].max() <= 2 * 0.05
    assert set(owner.tolist()) == set(range(len(union.faces)))


# ---------------------------------------------------------------------------------------
# Labels on disk

def _write_rest_dataset(root, drops=(0.01,) * 4 + (-0.005,) * 4):
    """A has_smplx dataset: the procedural body at rest, its lowest vertex `drop` below the
    floor per frame (negative: above), a box object under its left hand, a floor-slab scene mesh."""
    bm = load_body_model()
    with torch.no_grad():
        rest = bm.vertices(torch.zeros(3), torch.zeros(63), torch.zeros(3), torch.zeros(10)).double().numpy()
    T = len(drops)
    transl = np.zeros((T, 3))
    transl[:, 1] = -rest[:, 1].min() - np.asarray(drops)
    hand = rest[BodySurface(bm, BODY).region == BODY.index("left_wrist")]              # hand and fingers
    pose = np.tile(np.eye(4, dtype=np.float32), (T, 2, 1, 1))
    cx, cz = hand[:, 0].mean(), hand[:, 2].mean()
    over = (np.abs(rest[:, 0] - cx) < 0.11) & (np.abs(rest[:, 2] - cz) < 0.11)        # above the block's top
    top = rest[over, 1].min() + transl[:, 1] - 0.003
    pose[:, 0, :3, 3] = np.stack([np.full(T, cx), top - 0.1, np.full(T, cz)], -1)
    slab = trimesh.creation.box(extents=(6, 0.1, 6))
    slab.apply_translation([0, -0.05, 0])
    params = {"global_orient": np.zeros((T, 3)), "body_pose": np.zeros((T, 63)), "transl": transl,
              "betas": np.zeros(10)}
    from motiongen.body.solve import MotionBody
    R = torch.eye(3, dtype=torch.float64).expand(1, T, 22, 3, 3)
    joints = MotionBody(bm.double(), BODY, torch.zeros(1, 10, dtype=torch.float64)).pose(
        R, torch.as_tensor(transl)[None], slice(0, 1))[0].numpy()
    bm.float()
    w = DatasetWriter(root, BODY, ["stand"], 30.0, num_object_slots=2, has_smplx=True)
    w.add_scene(1, grid=voxelize_mesh(slab, 0.05), mesh=slab)
    w.add_object(4, "block", "block", mesh=trimesh.creation.box(extents=(0.2, 0.2, 0.2)))
    ids = np.full((T, 2), -1, np.int32)
    ids[:, 0] = 4
    w.add_sequence("stand", 1, joints.astype(np.float32), np.ones((T, 1), bool), np.zeros((T, 22), bool), pose, ids,
                   smplx=params)
    return w.finish(splits={"train": [1], "val": [], "test": []}, source="test")


@pytest.fixture(scope="module")
def rest_dataset(tmp_path_factory):
    root = _write_rest_dataset(tmp_path_factory.mktemp("rest") / "ds")
    annotate_dataset(root, progress=False)
    return root


def test_labels_round_trip(rest_dataset):
    ds = MotionDataset.open(rest_dataset)
    vc = ds.vertex_contact()
    assert isinstance(vc.bits, np.memmap) and vc.num_vertices == 10475
    assert vc.info["body"]["source"] == "dataset" and vc.smplx is None
    # recompute frame 2 directly and compare every stored array
    bm = load_body_model()
    body = BodySurface(bm, BODY)
    params = {k: np.asarray(v) for k, v in ds.smplx.items()}
    V, N = body.pose(params, slice(2, 3))
    t = SceneTargets(floor=PlaneField(0.0), scene=MeshField(ds.scene_mesh(1), voxel_size=0.02))
    t.add_object(4, MeshField(ds.object_mesh(4), voxel_size=0.01), ds.object_mesh(4).vertices)
    c = vertex_contacts(V, N, t, ds.object_ids[2:3], ds.object_poses[2:3], ContactConfig())
    assert (vc.contact(2)[0] == c.contact[0]).all()
    ids, tgt, dist = vc.frame(2)
    assert (ids == np.flatnonzero(c.contact[0])).all() and (tgt == c.target[0][ids]).all()
    assert dist == pytest.approx(c.distance[0][ids], abs=1e-6)
    assert (vc.joints[2] == joint_targets(c, body.region, 22)[0]).all()
    # what the parts touch: the feet the floor (a tie with the slab goes to the floor), the left hand the block
    for name, want in (("left_foot", FLOOR), ("right_foot", FLOOR), ("left_wrist", 4), ("right_wrist", NONE)):
        assert (vc.joint_target(name) == want).all(), name


def test_penetration_statistics_known_depth(rest_dataset):
    vc = MotionDataset.open(rest_dataset).vertex_contact()
    pen = np.asarray(vc.penetration)
    assert pen[:4, 0] == pytest.approx(0.01, abs=1e-5)                     # the deepest sole vertex: 1 cm
    assert (pen[4:] == 0).all() and (np.asarray(vc.penetrating)[4:] == 0).all()
    assert (pen[:4, 1] <= pen[:4, 0]).all() and (pen[:4, 2] <= pen[:4, 0] + 1e-7).all()
    table = vc.info["penetration"]
    assert table["frames_penetrating"] == 4 and table["share_below"]["max"]["<0.5 cm"] == 0.5
    assert table["share_below"]["max"]["<2 cm"] == 1.0
    assert (vc.path / "penetration.png").read_bytes()[:4] == b"\x89PNG"
    rows = (vc.path / "penetration.csv").read_text().splitlines()
    assert rows[0].startswith("statistic") and [r.split(",")[0] for r in rows[1:]] == ["max", "mean", "median"]


def test_old_dataset_has_no_labels_and_corrupt_labels_fail(rest_dataset, tmp_path):
    plain = make_dataset(tmp_path / "plain", scenes=(1,), seqs_per_scene=1, T=10)
    assert MotionDataset.open(plain).vertex_contact() is None
    bad = tmp_path / "bad"
    shutil.copytree(rest_dataset, bad)
    np.save(bad / "vertex_contact" / "offsets.npy", np.zeros(3, np.int64))
    with pytest.raises(DataError, match="offsets"):
        MotionDataset.open(bad).vertex_contact()
    info = json.loads((bad / "vertex_contact" / "info.json").read_text())
    (bad / "vertex_contact" / "info.json").write_text(json.dumps({**info, "num_frames": 99}))
    with pytest.raises(DataError, match="99 frames"):
        MotionDataset.open(bad).vertex_contact()


# ---------------------------------------------------------------------------------------
# CLI

def test_cli_runs_and_refuses_to_overwrite(rest_dataset, tmp_path, capsys):
    root = tmp_path / "ds"
    shutil.copytree(rest_dataset, root)
    before = (root / "vertex_contact" / "bits.npy").read_bytes()
    with pytest.raises(SystemExit) as e:
        main([f"root={root}", "progress=false"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "overwrite" in err and len(err.strip().splitlines()) == 1
    assert (root / "vertex_contact" / "bits.npy").read_bytes() == before
    assert main([f"root={root}", "overwrite=true", "progress=false", "threshold=0.03", "max_angle=45"]) == 0
    assert "frames/s" in capsys.readouterr().out
    info = json.loads((root / "vertex_contact" / "info.json").read_text())
    assert info["config"]["threshold"] == 0.03 and info["config"]["max_angle"] == 45.0
    assert not list(root.glob("vertex_contact.*"))                        # no partial or old folder left


@pytest.mark.parametrize("args, words", [
    (["root=/nonexistent/ds"], "does not exist"),
    (["threshold=-1"], "threshold"),
    (["max_angle=0"], "max_angle"),
    (["scene=mesh"], "no mesh"),
    (["colour=red"], "unknown key"),
    (["object_meshes=/nonexistent/meshes"], "object_meshes"),
    ([], "missing root"),
])
def test_cli_errors(args, words, tmp_path, capsys):
    ds = make_dataset(tmp_path / "ds", scenes=(1,), seqs_per_scene=1, T=5)      # grids only, no mesh
    argv = list(args) if not args or args[0].startswith("root=") else [f"root={ds}"] + args
    assert words in user_error(capsys, main, argv)
    assert not (ds / "vertex_contact").exists() and not list(ds.glob("vertex_contact.*"))


# ---------------------------------------------------------------------------------------
# Joint-only datasets and the TRUMANS layout

def test_joint_only_dataset_is_fitted(tmp_path):
    root = make_dataset(tmp_path / "ds", scenes=(1,), seqs_per_scene=1, T=20)
    r = annotate_dataset(root, progress=False)
    vc = MotionDataset.open(root).vertex_contact()
    assert r.body == "fitted" and vc.info["body"]["source"] == "fitted"
    assert vc.smplx["transl"].shape == (20, 3) and vc.smplx["betas"].shape == (20, 10)
    assert vc.joints.shape == (20, 22) and r.frames_per_second > 0


@pytest.mark.slow
def test_trumans_layout(tmp_path):
    """The converted test release: the body is its SMPL-X; objects without meshes are listed and
    skipped, or annotated from object_meshes=; non-rigid object poses are refused."""
    from motiongen.importers.trumans import convert_trumans

    rel = tmp_path / "Data_release"
    write_posed_release(rel, tmp_path / "meshes")
    ds_root = convert_trumans(rel, tmp_path / "ds", progress=False, grid=SMALL)
    r = annotate_dataset(ds_root, progress=False)
    assert r.body == "dataset" and r.skipped_objects == ["object_03", "object_17", "object_34"]
    r = annotate_dataset(ds_root, object_meshes=tmp_path / "meshes", overwrite=True, progress=False)
    vc = MotionDataset.open(ds_root).vertex_contact()
    assert r.skipped_objects == [] and vc.joints.shape == (120, 24)
    held = vc.joint_target("left_wrist", slice(0, 40))
    assert (held[HOLD] == 3).all() and (held[:5] == NONE).all() and (held[-5:] == NONE).all()
    raw = tmp_path / "raw"
    write_fake_release(raw, grid=SMALL)                                      # random, non-rigid object poses
    raw_ds = convert_trumans(raw, tmp_path / "raw_ds", progress=False, grid=SMALL)
    with pytest.raises(DataError, match="not a rigid transform"):
        annotate_dataset(raw_ds, object_meshes=tmp_path / "meshes", progress=False)
