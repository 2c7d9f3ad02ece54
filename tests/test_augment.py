"""Contact-preserving augmentation (TRUMANS supp. B.5): the offsets of Eq. A1-A6 and the
smoothness bound A13 on generated cases, the object edits, a contact that stays a contact after
a scale change or a swap, a sequence without contacts coming back unchanged, the output dataset,
the CLI and its errors, and mixing augmented sequences into training (`data.augmented`)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from motiongen.body.model import load_body_model
from motiongen.annotation import augment_objects as edits
from motiongen.annotation.annotate_contact import SurfaceBank, annotate_dataset
from motiongen.annotation.augment import AugmentConfig, AugmentContext, augment_dataset, augment_sequence, main, object_track
from motiongen.annotation.augment_offsets import (ContactEvent, blended_offsets, ramp_weights_span, smoothness_bound,
                                            target_trajectory)
from motiongen.annotation.vertex_contact import BodySurface, ContactConfig
from motiongen.scene.distance_field import MeshField
from motiongen.data.format import MotionDataset
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.errors import ConfigError
from tests.helpers import HOLD, SMALL, make_dataset, write_posed_release

W = 30


# ---------------------------------------------------------------------------------------
# Eq. A1-A6 and A13

def test_ramp_and_blend_closed_forms():
    v1, v2 = np.array([0.1, 0.0, 0.0]), np.array([0.0, 0.06, 0.0])
    off = blended_offsets(200, [ContactEvent(50, 51, v1)], W)
    assert off[50] == pytest.approx(v1) and off[65] == pytest.approx(v1 / 2) and off[35] == pytest.approx(v1 / 2)
    assert (off[80:] == 0).all() and (off[:21] == 0).all()
    # two contacts (A5-A6): at t = 55, both weights are 1 - 5/30
    off = blended_offsets(200, [ContactEvent(50, 51, v1), ContactEvent(60, 61, v2)], W)
    a, b = (25 / 30) * v1, (25 / 30) * v2
    want = (np.linalg.norm(a) * a + np.linalg.norm(b) * b) / (np.linalg.norm(a) + np.linalg.norm(b))
    assert off[55] == pytest.approx(want)
    # a span holds its (per-frame) offset in full and ramps from its ends
    w = ramp_weights_span(100, 40, 60, 10)
    assert w[40:60].tolist() == [1.0] * 20 and w[35] == pytest.approx(0.5) and w[64] == pytest.approx(0.5)
    with pytest.raises(ValueError):
        blended_offsets(10, [ContactEvent(2, 3, v1)], 0)


def test_smoothness_bound_a13_on_generated_cases():
    """|l'_{t+1} - l'_t| <= |l_{t+1} - l_t| + 4/W (|v1| + |v2|) for random trajectories, contact
    times, spans, offsets and windows (the paper's two-contact case and up to four contacts)."""
    rng = np.random.default_rng(0)
    worst = -np.inf
    for case in range(400):
        T, window = 150, int(rng.integers(3, 45))
        l = np.cumsum(rng.normal(0, 0.01, (T, 3)), 0)
        n = 2 if case < 200 else int(rng.integers(1, 5))
        evs = []
        for _ in range(n):
            s = int(rng.integers(0, T - 1))
            e = s + 1 if case < 200 else min(T, s + int(rng.integers(1, 40)))     # instants, then spans
            evs.append(ContactEvent(s, e, rng.normal(0, 0.15, 3)))
        lhs = np.linalg.norm(np.diff(target_trajectory(l, evs, window), axis=0), axis=-1)
        worst = max(worst, float((lhs - smoothness_bound(l, evs, window)).max()))
    assert worst <= 1e-12


# ---------------------------------------------------------------------------------------
# Object edits

def test_edits_keep_the_bottom_and_map_contact_points():
    box = trimesh.creation.box(extents=(0.2, 0.4, 0.2))              # local y in [-0.2, 0.2]
    pose = np.eye(4)
    pose[:3, :3] = trimesh.transformations.rotation_matrix(0.7, [0, 1, 0])[:3, :3]
    pose[:3, 3] = (1.0, 0.95, 2.0)                                   # standing on a table top at y = 0.75
    e = edits.scale_edit(3, box, pose, 1.5)
    assert e.mesh.bounds[0, 1] == pytest.approx(-0.2)                # the base stays where it was
    top = np.array([[0.1, 0.2, 0.0]])
    assert e.offsets(top, pose[None])[0] == pytest.approx(pose[:3, :3] @ (0.5 * np.array([0.1, 0.4, 0.0])))
    other = trimesh.creation.box(extents=(0.1, 0.8, 0.1))
    e = edits.swap_edit(3, box, other, 9, pose)
    assert e.mesh.bounds[0, 1] == pytest.approx(-0.2) and e.mesh.extents == pytest.approx([0.1, 0.8, 0.1])
    assert e.offsets(top, pose[None])[0] @ pose[:3, 1] == pytest.approx(0.4)   # the top point is 0.4 m higher
    e = edits.move_edit(3, box, [0.1, 0.0, -0.05])
    assert e.poses(pose[None])[0, :3, 3] == pytest.approx([1.1, 0.95, 1.95])
    assert e.offsets(top, pose[None])[0] == pytest.approx([0.1, 0.0, -0.05])


def test_placement():
    table = trimesh.creation.box(extents=(1.0, 0.75, 1.0))
    table.apply_translation([0, 0.375, 0])
    scene = MeshField(table, voxel_size=0.02)
    cup = trimesh.creation.box(extents=(0.08, 0.1, 0.08))
    at = lambda y, x=0.0: np.array([[1, 0, 0, x], [0, 1, 0, y], [0, 0, 1, 0], [0, 0, 0, 1.0]])   # noqa: E731
    assert edits.placement_ok(cup, at(0.80), scene)                  # on the top
    assert not edits.placement_ok(cup, at(0.90), scene)              # floating 10 cm
    assert not edits.placement_ok(cup, at(0.74), scene)              # sunk into the top
    assert edits.placement_ok(cup, at(0.05, x=2.0), scene)           # on the floor


# ---------------------------------------------------------------------------------------
# Sequences (the TRUMANS-layout test release: a box under the left hand)

@pytest.fixture(scope="module")
def posed(tmp_path_factory):
    from motiongen.importers.trumans import convert_trumans

    base = tmp_path_factory.mktemp("posed")
    arrays = write_posed_release(base / "Data_release", base / "meshes")
    root = convert_trumans(base / "Data_release", base / "ds", progress=False, grid=SMALL)
    annotate_dataset(root, object_meshes=base / "meshes", progress=False)
    return root, base / "meshes", arrays["box_height"]


def _ctx(root, meshes, **cfg):
    ds = MotionDataset.open(root)
    bm = load_body_model()
    c = AugmentConfig(**cfg)
    return AugmentContext(ds, ds.vertex_contact(), bm, BodySurface(bm, ds.joint_set), SurfaceBank(ds, c.contact, meshes), c)


def test_contact_stays_after_scale(posed):
    root, meshes, h = posed
    ctx = _ctx(root, meshes)
    seq = ctx.ds.sequences[0]                                        # seqA: the left hand rests on object 3
    slots, poses = object_track(ctx.ds, seq, 3)
    a = augment_sequence(ctx, seq, edits.scale_edit(3, ctx.bank.object_mesh(3), poses[0], 1.1), 99)
    lw = ctx.ds.joint_set.index("left_wrist")
    new_target = np.concatenate([lab[2] for lab in a.labels])[:, lw]
    assert a.changed and (new_target[HOLD] == 99).all()              # still touching, the new object
    rise = a.joints[:, lw, 1] - np.asarray(ctx.ds.joints[seq.start:seq.end, lw, 1])
    assert rise[HOLD] == pytest.approx(0.1 * h, abs=0.01)            # the box top rose by 10 % of its height
    assert a.stats["target_error_m"] < 0.01 and a.stats["contact_kept"] == 1.0
    assert a.stats["bone_cv"] < 1e-5                                 # one rigid body
    assert (a.object_ids[slots] == 99).all()
    assert (a.object_poses[slots] == ctx.ds.object_poses[seq.start:seq.end][slots]).all()       # scaled in place
    assert a.stats["fit_m"] < 1e-5                                   # the release's SMPL-X was the start


@pytest.mark.slow
def test_swap_and_move_follow_the_object(posed):
    root, meshes, h = posed
    ctx = _ctx(root, meshes)
    seq = ctx.ds.sequences[0]
    lw = ctx.ds.joint_set.index("left_wrist")
    _, poses = object_track(ctx.ds, seq, 3)
    src = np.asarray(ctx.ds.joints[seq.start:seq.end, lw])
    a = augment_sequence(ctx, seq, edits.swap_edit(3, ctx.bank.object_mesh(3), ctx.bank.object_mesh(17), 17, poses[0]), 98)
    assert (a.joints[HOLD, lw, 1] - src[HOLD, 1]) == pytest.approx(-0.1 * h, abs=0.01)   # a 10 % lower box
    delta = np.array([0.05, 0.0, -0.04])
    a = augment_sequence(ctx, seq, edits.move_edit(3, ctx.bank.object_mesh(3), delta), 97)
    assert np.abs(a.joints[HOLD, lw] - src[HOLD] - delta).max() < 0.01
    assert a.stats["contact_kept"] > 0.9


def test_sequence_without_contact_comes_back_unchanged(posed):
    root, meshes, _ = posed
    ctx = _ctx(root, meshes)
    for seq, oid in ((ctx.ds.sequences[0], 17), (ctx.ds.sequences[1], 34)):     # objects nobody touches
        slots, poses = object_track(ctx.ds, seq, oid)
        edit = edits.scale_edit(oid, ctx.bank.object_mesh(oid), poses[slots[0][0]], 1.2)
        a = augment_sequence(ctx, seq, edit, 90)
        assert not a.changed and np.array_equal(a.joints, ctx.ds.joints[seq.start:seq.end])
        assert np.array_equal(a.contact, ctx.ds.contact[seq.start:seq.end])


@pytest.mark.slow
def test_augment_dataset_output(posed, tmp_path):
    root, meshes, h = posed
    r = augment_dataset(root, tmp_path / "aug", AugmentConfig(ops=("scale",), scale_min=1.1, scale_max=1.1, copies=2),
                        object_meshes=meshes, progress=False)
    assert r.sequences == 2 and r.sources == 1 and r.per_minute > 0      # seqA is the only train sequence
    out = MotionDataset.open(r.path)
    assert [s.name for s in out.sequences] == ["seqA~aug0", "seqA~aug1"] and out.smplx is not None
    assert out.meta["source"] == "trumans+augmented" and out.meta["augmented"]["summary"]["contact_kept"] == 1.0
    new = [o for o, e in out.objects.items() if "~scale" in e["name"]]
    assert len(new) == 2 and out.object_mesh(new[0]).extents[1] == pytest.approx(1.1 * h, abs=1e-4)
    assert (out.vertex_contact().joint_target("left_wrist", slice(0, 40))[HOLD] == new[0]).all()
    assert set(out.scenes) == {3}


# ---------------------------------------------------------------------------------------
# CLI

def test_cli(posed, tmp_path, capsys):
    root, meshes, _ = posed
    assert main([f"root={root}", f"out={tmp_path / 'a'}", f"object_meshes={meshes}", "ops=[move]", "progress=false"]) == 0
    assert "1 augmented sequences" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:                              # out exists: left as it is
        main([f"root={root}", f"out={tmp_path / 'a'}", f"object_meshes={meshes}", "progress=false"])
    assert e.value.code == 2 and "exists" in capsys.readouterr().err
    assert json.loads((tmp_path / "a" / "meta.json").read_text())["augmented"]["sequences"][0]["op"] == "move"


@pytest.mark.parametrize("args, words", [
    (["ops=[bend]"], "ops"),
    (["scale_min=1.3", "scale_max=1.1"], "scale_min"),
    (["window=0"], ">= 1"),
    (["split=nosuch"], "no split named"),
    (["colour=red"], "unknown key"),
])
def test_cli_errors(posed, args, words, tmp_path, capsys):
    root, meshes, _ = posed
    with pytest.raises(SystemExit) as e:
        main([f"root={root}", f"out={tmp_path / 'o'}", f"object_meshes={meshes}", "progress=false"] + args)
    err = capsys.readouterr().err
    assert e.value.code == 2 and words in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists() and not list(tmp_path.glob("o.partial-*"))


def test_errors_without_objects_or_contacts(tmp_path, capsys):
    plain = make_dataset(tmp_path / "plain", scenes=(1,), seqs_per_scene=1, T=10)    # no objects at all
    with pytest.raises(SystemExit) as e:
        main([f"root={plain}", f"out={tmp_path / 'o'}", "progress=false"])
    assert e.value.code == 2 and "no objects" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["out=x"])
    assert e.value.code == 2 and "missing root" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------
# Training on the mix (data.augmented)

def test_mixing_into_training(tmp_path):
    from motiongen.data.windows import WindowConfig, WindowDataset

    base = make_dataset(tmp_path / "base", scenes=(1, 71, 91), seqs_per_scene=1, T=60)
    extra = make_dataset(tmp_path / "extra", scenes=(1, 71, 91), seqs_per_scene=2, T=60)   # stands in for augmented
    ds = open_dataset(DataConfig(source="dataset", root=str(base), augmented=[str(extra)]), verbose=False)
    assert ds.root != base and ds.meta["mixed"]["added_sequences"] == 2 and ds.meta["mixed"]["dropped_outside_train"] == 4
    names = [s.name for s in ds.split_sequences("train")]
    assert names == ["s1_0", "s1_0+", "s1_1"]                          # renamed on a clash
    assert [s.name for s in ds.split_sequences("val")] == ["s71_0"]    # val and test stay the source's
    assert np.array_equal(ds.joints[180:240], MotionDataset.open(extra).joints[:60])   # after the 3 source sequences
    w = WindowDataset(ds, "train", WindowConfig(scene=False))
    assert len(w) == 3 * len(WindowDataset(MotionDataset.open(base), "train", WindowConfig(scene=False)))
    stamp = (ds.root / "meta.json").stat().st_mtime_ns
    again = open_dataset(DataConfig(source="dataset", root=str(base), augmented=str(extra)), verbose=False)
    assert again.root == ds.root and (again.root / "meta.json").stat().st_mtime_ns == stamp     # cached
    other = make_dataset(tmp_path / "other", scenes=(1,), seqs_per_scene=1, T=60)
    (other / "meta.json").write_text((other / "meta.json").read_text().replace('"sit"', '"lie"'))
    with pytest.raises(ConfigError, match="actions"):
        open_dataset(DataConfig(source="dataset", root=str(base), augmented=[str(other)]), verbose=False)


def test_hydra_key():
    from hydra import compose, initialize_config_dir

    from motiongen.cli import CONFIG_DIR
    from motiongen.config import register_configs

    register_configs()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        cfg = compose("train", overrides=["data=small", "data.augmented=[/a,/b]"])
    assert list(cfg.data.augmented) == ["/a", "/b"]
    assert ContactConfig().threshold == 0.02 and AugmentConfig().window == W


@pytest.mark.slow
def test_synthetic_dataset_end_to_end(tmp_path):
    """Both tools on the embedded synthetic dataset (one sequence in which an object is picked
    up, to keep the test short): labels, then augmented sequences that keep the contacts."""
    from motiongen.data.dataset_writer import DatasetWriter
    from motiongen.synthetic import ACTIONS

    src = open_dataset(DataConfig(source="synthetic", size="small"), verbose=False)
    pick = ACTIONS.index("pick up")
    seq = next(s for s in src.split_sequences("train") if np.asarray(src.actions[s.start:s.end, pick]).any())
    w = DatasetWriter(tmp_path / "one", src.joint_set, src.action_names, src.fps, src.meta["num_object_slots"])
    w.add_scene(seq.scene, grid=src.grid(seq.scene), mesh=src.scene_mesh(seq.scene), name=src.scenes[seq.scene]["name"])
    # The pick-up and a second either side: the part of the sequence the tools have work in.
    held = np.flatnonzero(np.asarray(src.actions[seq.start:seq.end, pick]))
    a, b = seq.start + max(0, held[0] - 30), seq.start + min(seq.end - seq.start, held[-1] + 31)
    ids = np.asarray(src.object_ids[a:b])
    for oid in np.unique(ids[ids >= 0]).tolist():
        w.add_object(oid, src.objects[oid]["name"], src.objects[oid]["type"], mesh=src.object_mesh(oid))
    w.add_sequence(seq.name, seq.scene, src.joints[a:b], src.actions[a:b], src.contact[a:b], src.object_poses[a:b], ids)
    root = w.finish(splits=src.splits, source="synthetic")
    r = annotate_dataset(root, progress=False)
    vc = MotionDataset.open(root).vertex_contact()
    held = np.asarray(vc.joints)[:, [src.joint_set.index("left_wrist"), src.joint_set.index("right_wrist")]]
    assert r.body == "fitted" and (held >= 0).any()                  # a hand touches the picked-up object
    assert (np.asarray(vc.joints)[:, src.joint_set.index("left_foot")] == -2).mean() > 0.5   # toes on the floor
    a = augment_dataset(root, tmp_path / "aug", AugmentConfig(copies=2), progress=False)
    assert a.sequences == 2 and a.stats["contact_kept"] > 0.6 and a.stats["bone_cv"] < 1e-5
    assert a.stats["target_error_m"] < 0.02 and a.stats["away_m"] < 0.02
