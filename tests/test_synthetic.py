"""Physical sanity of the embedded synthetic dataset (generated once, `small` size)."""

import json

import numpy as np
import pytest

from motiongen.data.format import DEFAULT_SPLITS, MotionDataset
from motiongen.synthetic import ACTIONS, SIZES, _scene_job, generate
from motiongen.commands.synthetic_command import main as cli_main
from motiongen.errors import ConfigError, DataError
from motiongen.skeleton import BODY, FOOT_JOINTS, HAND_JOINTS
from tests.helpers import user_error

FPS = 30
A = {name: i for i, name in enumerate(ACTIONS)}


@pytest.fixture(scope="session")
def ds(tmp_path_factory):
    root = generate(tmp_path_factory.mktemp("synthetic") / "small", size="small", seed=0)
    return MotionDataset.open(root)


def _seqs(ds):
    for s in ds.sequences:
        yield s, slice(s.start, s.end)


def _runs(mask: np.ndarray):
    """(start, end) of each run of True in a 1-D bool array."""
    d = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.where(d == 1)[0], np.where(d == -1)[0]))


def test_opens_with_splits_and_vocabulary(ds):
    assert ds.action_names == ACTIONS and ds.fps == FPS and ds.joint_set == BODY
    assert sorted(ds.scenes) == SIZES["small"]["scenes"]
    assert ds.splits == {k: list(v) for k, v in DEFAULT_SPLITS.items()}
    for split in ("train", "val", "test"):
        assert ds.split_sequences(split), split
    assert len(ds.split_sequences("train")) > len(ds.split_sequences("val"))
    minutes = ds.num_frames / FPS / 60
    assert 2.0 <= minutes <= 4.5
    assert min(s.num_frames for s in ds.sequences) >= 4 * FPS
    # every action occurs somewhere
    assert ds.actions.any(0).all()


def test_scene_grid_and_mesh(ds):
    g = ds.grid(1)
    assert g.voxel_size == pytest.approx(0.02) and g.shape[1] == 100 and g.origin[1] == 0.0
    lo, hi = g.bounds
    assert hi[0] - lo[0] <= 6.0 + 1e-9 and hi[2] - lo[2] <= 8.0 + 1e-9
    dense = g.dense()
    assert dense[0, :, :].all() and dense[:, :, -1].all()       # walls
    assert 0.5 < 1 - dense[:, 0, :].mean() < 0.95                # the floor layer is mostly free
    mesh = ds.scene_mesh(1)
    assert mesh.bounds[0][1] < 0 < mesh.bounds[1][1]             # floor slab below y = 0
    types = {o["type"] for o in ds.objects.values()}
    assert types <= {"cup", "bottle", "book"} and types
    assert all(ds.object_mesh(i) is not None for i in ds.objects)


def test_no_joint_below_floor(ds):
    assert np.asarray(ds.joints[..., 1]).min() > -0.02


def test_bone_lengths_constant_and_heights_human(ds):
    par = np.array(BODY.parents)
    heights = ds.meta["body_heights"]
    for s, sl in _seqs(ds):
        j = np.asarray(ds.joints[sl], np.float64)
        bones = np.linalg.norm(j[:, 1:] - j[:, par[1:]], axis=-1)
        assert (bones.max(0) - bones.min(0)).max() < 1e-4, s.name
        assert 1.55 <= heights[s.name] <= 1.90
        standing = np.asarray(ds.actions[sl, A["stand"]])
        head = j[standing, BODY.index("head"), 1]
        assert 1.3 < np.median(head) < 1.85  # head joint ~0.13 m below the crown
    assert np.ptp(list(heights.values())) > 0.1


def test_stance_feet_do_not_slide(ds):
    speeds = []
    for s, sl in _seqs(ds):
        j = np.asarray(ds.joints[sl])[:, FOOT_JOINTS]
        c = np.asarray(ds.contact[sl])[:, FOOT_JOINTS]
        v = np.linalg.norm(np.diff(j[..., [0, 2]], axis=0), axis=-1) * FPS
        speeds.append(v[c[1:] & c[:-1]])
    assert np.median(np.concatenate(speeds)) < 0.05


def test_feet_contacts_come_from_geometry(ds):
    j, c = np.asarray(ds.joints), np.asarray(ds.contact)
    walking = np.asarray(ds.actions[:, A["walk"]])
    ankle = BODY.index("left_ankle")
    assert 0.3 < c[walking, ankle].mean() < 0.95          # stance and swing alternate
    assert j[c[:, ankle] & walking, ankle, 1].max() < 0.25  # no floor contact high above it
    assert j[~c[:, ankle] & walking, ankle, 1].min() > 0.09 * 0.9  # swing feet clear the floor


def test_walking_speed_and_collisions(ds):
    checked = 0
    for s, sl in _seqs(ds):
        pelvis = np.asarray(ds.joints[sl, 0], np.float64)
        walking = np.asarray(ds.actions[sl, A["walk"]])
        grid = ds.grid(s.scene)
        assert not grid.occupied(pelvis[walking], outside=True).any(), s.name
        v = np.linalg.norm(np.diff(pelvis[:, [0, 2]], axis=0), axis=-1) * FPS
        v = np.convolve(v, np.ones(FPS) / FPS, mode="same")  # over a stride
        for a, b in _runs(walking):
            travelled = np.linalg.norm(np.diff(pelvis[a:b, [0, 2]], axis=0), axis=-1).sum()
            if travelled > 2.0:
                assert 0.8 <= np.percentile(v[a:b - 1], 90) <= 1.5, s.name
                checked += 1
        assert v.max() < 1.6
    assert checked >= 3


def test_sit_and_lie_rest_on_furniture(ds):
    pel = BODY.index("pelvis")
    seen = {"sit": 0, "lie down": 0}
    for s, sl in _seqs(ds):
        j = np.asarray(ds.joints[sl], np.float64)
        grid = ds.grid(s.scene)
        for action in seen:
            for a, b in _runs(np.asarray(ds.actions[sl, A[action]])):
                f = a + int(np.argmin(j[a:b, pel, 1]))  # the settled pose
                p = j[f, pel]
                assert 0.25 < p[1] < 0.9
                below = p + np.array([0.0, -1.0, 0.0]) * np.linspace(0.0, 0.25, 13)[:, None]
                assert grid.occupied(below).any(), (s.name, action, f)
                assert ds.contact[s.start + f, pel]
                seen[action] += 1
    assert seen["sit"] and seen["lie down"]


def test_held_objects_follow_the_hand(ds):
    carried = 0
    for s, sl in _seqs(ds):
        poses, ids = np.asarray(ds.object_poses[sl]), np.asarray(ds.object_ids[sl])
        j = np.asarray(ds.joints[sl])
        moved = (np.abs(poses - poses[:1]).reshape(len(poses), poses.shape[1], -1).max(-1) > 1e-5) & (ids >= 0)
        carry = np.asarray(ds.actions[sl, A["carry"]])
        assert not moved[~carry].any(), s.name        # objects move only while carried
        if not carry.any():
            continue
        slots = np.nonzero(moved.any(0))[0]
        assert len(slots) == 1, s.name                # one object, picked up once
        held = poses[carry, slots[0], :3, 3]           # (n, 3) from the grasp on
        d = np.linalg.norm(j[carry][:, list(HAND_JOINTS)] - held[:, None], axis=-1).min(1)
        assert d.max() < 0.12, s.name
        carried += 1
    assert carried


def test_deterministic_by_seed(ds):
    spec = SIZES["small"]
    first = ds.sequences[0]
    again = _scene_job((first.scene, 0, spec["train_frames"], spec["seconds"]))
    name, arrays, _ = again["sequences"][0]
    assert name == first.name
    np.testing.assert_array_equal(arrays["joints"], ds.joints[first.start:first.end])
    np.testing.assert_array_equal(arrays["contact"], ds.contact[first.start:first.end])
    np.testing.assert_array_equal(again["grid"].bits, ds.grid(first.scene).bits)
    other = _scene_job((first.scene, 1, spec["train_frames"], spec["seconds"]))
    a, b = other["sequences"][0][1]["joints"], arrays["joints"]
    assert a.shape != b.shape or not np.array_equal(a, b)


def test_generate_rejects_bad_values(tmp_path):
    with pytest.raises(ConfigError):
        generate(tmp_path / "x", size="huge")
    with pytest.raises(ConfigError):
        generate(tmp_path / "x", seed=-1)
    with pytest.raises(DataError):
        generate(tmp_path, size="small")  # exists


def test_cli_errors_exit_2(tmp_path, capsys):
    a = f"out={tmp_path / 'a'}"
    (tmp_path / "file").write_text("")
    for argv, words in ([[a, "size=huge"], "size must be one of"], [[a, "seed=x"], "expected an integer"],
                        [["size=small"], "missing out="], [[f"out={tmp_path}"], "already exists"],
                        [["bogus"], "bogus"], [[a, "workers=-3"], "workers: expected an integer >= 1"],
                        [[a, "workers=0"], "workers: expected an integer >= 1"],
                        [["out=/proc/ds", "size=small"], "out: cannot write under /proc"],
                        [[f"out={tmp_path / 'file'}", "size=small"], "exists and is not a directory"],
                        [[f"out={tmp_path / 'file' / 'ds'}", "size=small"], "is a file, not a directory"]):
        assert words in user_error(capsys, cli_main, argv), argv
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]             # nothing written, no partial
    assert json.dumps(ACTIONS)  # vocabulary is plain strings
