"""TRUMANS release adapter: a miniature fake release with the release's names, shapes and
dtypes (scene grids at the real (300, 100, 400) shape), converted and read back; and every
corrupt case giving a DataError / CLI exit 2 with nothing left at `out`."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from motiongen.data.format import MotionDataset
from motiongen.scene.occupancy import _ball_boxes, near_occupied
from motiongen.importers.trumans import convert_trumans, main
from motiongen.importers.trumans_release import TRUMANS_ACTIONS, interpret_object_flags, scene_ids_from_names
from motiongen.errors import ConfigError, DataError
from tests.helpers import GRID, SCENE_FILES, SEQS, SMALL, write_fake_release

FRAME_NAMES = ["human_joints", "human_orient", "idx_start", "action_label", "scene_flag", "object_flag",
               "object_mat", "seg_name", "frame_id", "human_pose", "human_transl"]


@pytest.fixture(scope="module")
def release(tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("rel") / "Data_release"
    return root, write_fake_release(root)


@pytest.fixture(scope="module")
def converted(release, tmp_path_factory) -> Path:
    root, _ = release
    return convert_trumans(root, tmp_path_factory.mktemp("out") / "ds", progress=False)


def _copy_release(src: Path, dst: Path) -> Path:
    """A release whose files are symlinks to `src` (cheap); corrupt one by replacing it."""
    dst.mkdir()
    (dst / "Scene").mkdir()
    for p in src.glob("*.npy"):
        (dst / p.name).symlink_to(p)
    for p in (src / "Scene").glob("*.npy"):
        (dst / "Scene" / p.name).symlink_to(p)
    return dst


def _replace(path: Path, a) -> None:
    path.unlink()
    np.save(path, a)


def _assert_clean(out: Path) -> None:
    assert not out.exists()
    assert not list(out.parent.glob(out.name + ".partial-*"))


# ---------------------------------------------------------------------------------------
# Round trip


def test_roundtrip_values(release, converted):
    _, a = release
    ds = MotionDataset.open(converted)
    assert ds.num_frames == 120 and ds.fps == 30.0 and ds.meta["source"] == "trumans"
    assert ds.action_names == list(TRUMANS_ACTIONS) and ds.joint_set.name == "body+index1"
    assert ds.smplx is not None
    starts = {n: sum(t for _, t, _ in SEQS[:i]) for i, (n, _, _) in enumerate(SEQS)}
    assert [(s.name, s.num_frames) for s in ds.sequences] == [(n, t) for n, t, _ in SEQS]
    for s in ds.sequences:
        r = slice(starts[s.name], starts[s.name] + s.num_frames)
        np.testing.assert_array_equal(ds.joints[s.start:s.end], a["human_joints"][r])
        np.testing.assert_array_equal(ds.actions[s.start:s.end], a["action_label"][r] >= 0.5)
        np.testing.assert_array_equal(ds.smplx["body_pose"][s.start:s.end], a["human_pose"][r])
        np.testing.assert_array_equal(ds.smplx["global_orient"][s.start:s.end], a["human_orient"][r])
        np.testing.assert_array_equal(ds.smplx["transl"][s.start:s.end], a["human_transl"][r])
    assert not ds.smplx["betas"].any()   # no human_betas.npy: mean shape


def test_roundtrip_objects(release, converted):
    _, a = release
    ds = MotionDataset.open(converted)
    assert ds.object_ids.shape == (120, 5) and len(ds.objects) == 35
    # seqA: slot 0 holds type 3, slot 2 holds type 17; seqB: slot 4 holds type 34; seqC: none
    np.testing.assert_array_equal(ds.object_ids[0], [3, -1, 17, -1, -1])
    np.testing.assert_array_equal(ds.object_ids[40:70], np.tile([-1, -1, -1, -1, 34], (30, 1)))
    assert (ds.object_ids[70:] == -1).all()
    np.testing.assert_array_equal(ds.object_poses[:40, 0], a["object_mat"][:40, 0])
    np.testing.assert_array_equal(ds.object_poses[:40, 2], a["object_mat"][:40, 2])
    np.testing.assert_array_equal(ds.object_poses[70:], np.broadcast_to(np.eye(4), (50, 5, 4, 4)))


def test_scenes_splits_and_grids(release, converted):
    root, _ = release
    ds = MotionDataset.open(converted)
    assert sorted(ds.scenes) == [3, 75, 95]
    assert {s.name: s.scene for s in ds.sequences} == {"seqA": 3, "seqB": 75, "seqC": 95}
    assert [s.name for s in ds.split_sequences("train")] == ["seqA"]
    assert [s.name for s in ds.split_sequences("val")] == ["seqB"]
    assert [s.name for s in ds.split_sequences("test")] == ["seqC"]
    g = ds.grid(3)
    assert g.shape == GRID.shape and g.voxel_size == 0.02
    np.testing.assert_allclose(g.origin, (-3, 0, -4))
    np.testing.assert_array_equal(g.dense(), np.load(root / "Scene" / "scene_003.npy"))
    assert ds.meta["trumans"]["scene_files"]["75"] == "scene_075.npy"


def test_contacts(converted):
    ds = MotionDataset.open(converted)
    c = np.asarray(ds.contact)                     # (120, 24)
    assert c[:, 10].all()                          # toe 2 cm above the floor
    assert c[:40, 20].all()                        # wrist 3 cm above the table in scene 3
    assert not c[40:, 20].any()                    # no table in the other scenes
    assert c.mean() < 0.2                          # random joints well away from geometry


def test_cli_body_joints_and_no_overwrite(release, converted, tmp_path, capsys):
    root, a = release
    out = tmp_path / "body"
    assert main([f"release={root}", f"out={out}", "joints=body", "progress=false"]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {out}"
    ds = MotionDataset.open(out)
    assert ds.joints.shape == (120, 22, 3) and ds.joint_set.name == "body"
    np.testing.assert_array_equal(ds.joints[:40], a["human_joints"][:40, :22])
    with pytest.raises(DataError, match="already exists"):
        convert_trumans(root, out, progress=False)
    with pytest.raises(ConfigError):
        convert_trumans(root, tmp_path / "x", joints="hands")
    _assert_clean(tmp_path / "x")


def test_release_variants(tmp_path):
    """A seg_name run that reappears later is its own sequence; per-frame betas with B > 10 keep
    the first 10; norm.npy (and a pickled seg_name) only with allow_pickle."""
    root = tmp_path / "rel"
    a = write_fake_release(root, grid=SMALL)
    betas = np.random.default_rng(1).normal(size=(120, 16)).astype(np.float32)
    np.save(root / "human_betas.npy", betas)
    seg = a["seg_name"].copy()
    seg[70:] = "seqA"                                  # seqC renamed to the first sequence's name
    _replace(root / "seg_name.npy", seg)
    np.save(root / "norm.npy", np.array({"(16, 3)": (np.zeros(72), np.ones(72))}, dtype=object), allow_pickle=True)
    ds = MotionDataset.open(convert_trumans(root, tmp_path / "o1", progress=False, grid=SMALL))
    assert [s.name for s in ds.sequences] == ["seqA", "seqB", "seqA~2"]
    assert ds.meta["trumans"]["norm"] is None          # not loaded without allow_pickle
    np.testing.assert_array_equal(ds.smplx["betas"][:40], betas[:40, :10])
    # allow_pickle also accepts a seg_name stored as an object array
    (root / "seg_name.npy").unlink()
    np.save(root / "seg_name.npy", seg.astype(object), allow_pickle=True)
    ds = MotionDataset.open(convert_trumans(root, tmp_path / "o2", progress=False, allow_pickle=True,
                                             grid=SMALL))
    assert ds.meta["trumans"]["norm"]["(16, 3)"]["max"] == [1.0] * 72
    assert [s.name for s in ds.sequences] == ["seqA", "seqB", "seqA~2"]


# ---------------------------------------------------------------------------------------
# Interpretation helpers


def test_scene_ids_rule():
    assert scene_ids_from_names(["scene_003.npy", "Scene12.npy"]) == ([3, 12], "number in file name")
    ids, rule = scene_ids_from_names(["0a76-18b9.npy", "1f2e-77aa.npy"])   # several digit runs
    assert ids == [1, 2] and "position" in rule
    assert scene_ids_from_names(["a_1.npy", "b_1.npy"])[0] == [1, 2]       # duplicate numbers


def test_ball_dilation_matches_distance():
    assert sorted(_ball_boxes(2.5)) == [(1, 1, 2), (1, 2, 1), (2, 1, 1)]
    occ = np.zeros((9, 9, 9), bool)
    occ[4, 4, 4] = True
    d2 = ((np.indices(occ.shape) - 4) ** 2).sum(0)
    for r in (1.0, 2.5, 3.2):
        np.testing.assert_array_equal(near_occupied(occ, r), d2 <= r * r)


def test_object_flag_conflicts():
    flag = np.full((2, 35), -1)
    flag[1, [4, 9]] = 3
    with pytest.raises(DataError, match=r"share pose slot 3 at frame 11"):
        interpret_object_flags(flag, np.zeros((2, 5, 4, 4)), Path("object_flag.npy"), 10)
    flag[1, 9] = 5
    with pytest.raises(DataError, match="out of range"):
        interpret_object_flags(flag, np.zeros((2, 5, 4, 4)), Path("object_flag.npy"), 10)


# ---------------------------------------------------------------------------------------
# Corrupt releases


def _truncate(p: Path) -> None:
    data = p.read_bytes()
    p.unlink()
    p.write_bytes(data[: len(data) - 100])


def _nan_joints(a):
    j = a["human_joints"].copy()
    j[7, 5, 1] = np.nan       # seqA: fails in the first scene converted
    return j


CORRUPT = {
    # case: (mutate(root, arrays), file named in the message, words in the message)
    "missing_file": (lambda r, a: (r / "object_mat.npy").unlink(), "object_mat.npy", "missing"),
    "missing_optional_pair": (lambda r, a: (r / "human_transl.npy").unlink(), "human_transl.npy", "need both"),
    "truncated": (lambda r, a: _truncate(r / "action_label.npy"), "action_label.npy", "not a readable"),
    "nan_joints": (lambda r, a: _replace(r / "human_joints.npy", _nan_joints(a)), "human_joints.npy", "frame 7"),
    "joints_shape": (lambda r, a: _replace(r / "human_joints.npy", a["human_joints"][:, :22]),
                     "human_joints.npy", "expected shape (N, 24, 3)"),
    "n_mismatch": (lambda r, a: _replace(r / "scene_flag.npy", a["scene_flag"][:-1]),
                   "scene_flag.npy", "expected shape (N=120)"),
    "dtype": (lambda r, a: _replace(r / "object_flag.npy", a["object_flag"].astype(np.float32)),
              "object_flag.npy", "expected dtype int"),
    "scene_flag_range": (lambda r, a: _replace(r / "scene_flag.npy", np.where(a["scene_flag"] == 2, 7, a["scene_flag"])),
                         "scene_flag.npy", "value 7 at frame 70"),
    "missing_scene_file": (lambda r, a: (r / "Scene" / SCENE_FILES[2]).unlink(), "scene_flag.npy", "Scene file missing"),
    "missing_scene_dir": (lambda r, a: [p.unlink() for p in (r / "Scene").iterdir()] and (r / "Scene").rmdir(),
                          "Scene", "folder is missing"),
    "scene_shape": (lambda r, a: _replace(r / "Scene" / SCENE_FILES[1], np.zeros((30, 10, 40), bool)),
                    SCENE_FILES[1], "expected bool (300, 100, 400)"),
    "scene_dtype": (lambda r, a: _replace(r / "Scene" / SCENE_FILES[1], np.zeros(GRID.shape, np.uint8)),
                    SCENE_FILES[1], "found uint8"),
    "scene_changes_inside_seq": (lambda r, a: _replace(r / "scene_flag.npy", np.r_[a["scene_flag"][:-1], 0]),
                                 "scene_flag.npy", "inside sequence 'seqC'"),
    "idx_start_range": (lambda r, a: _replace(r / "idx_start.npy", np.r_[a["idx_start"], 500]),
                        "idx_start.npy", "not a frame index"),
    "object_flag_range": (lambda r, a: _replace(r / "object_flag.npy", np.where(a["object_flag"] == 2, 5, a["object_flag"])),
                          "object_flag.npy", "out of range"),
    "pickled_seg_name": (lambda r, a: (r / "seg_name.npy").unlink() or
                         np.save(r / "seg_name.npy", a["seg_name"].astype(object), allow_pickle=True),
                         "seg_name.npy", "allow_pickle=true"),
}


@pytest.mark.parametrize("case", sorted(CORRUPT))
def test_corrupt_release(case, release, tmp_path, capsys):
    src, arrays = release
    mutate, fname, words = CORRUPT[case]
    root = _copy_release(src, tmp_path / "rel")
    mutate(root, arrays)
    out = tmp_path / "out"
    with pytest.raises(DataError) as e:
        convert_trumans(root, out, progress=False)
    msg = str(e.value)
    assert fname in msg and words in msg and "\n" not in msg
    _assert_clean(out)
    # same case through the CLI: one line on stderr, exit 2, no traceback
    with pytest.raises(SystemExit) as ex:
        main([f"release={root}", f"out={out}", "progress=false"])
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and fname in err and "Traceback" not in err
    _assert_clean(out)


def test_failure_keeps_existing_dataset(release, converted, tmp_path):
    src, arrays = release
    root = _copy_release(src, tmp_path / "rel")
    _replace(root / "human_joints.npy", _nan_joints(arrays))
    out = tmp_path / "ds"
    shutil.copytree(converted, out)
    with pytest.raises(DataError, match="frame 7$"):
        convert_trumans(root, out, overwrite=True, progress=False)
    ds = MotionDataset.open(out)                                  # the old dataset, intact
    np.testing.assert_array_equal(ds.joints, MotionDataset.open(converted).joints)
    assert not list(tmp_path.glob("ds.*"))


@pytest.mark.parametrize("argv, words", [
    (["release=/x"], "missing out="), (["release=/x", "out=/y", "color=red"], "unknown key 'color'"),
    (["/x"], "expected key=value"), (["release=/x", "out=/y", "overwrite=maybe"], "expected true or false"),
])
def test_cli_bad_arguments(argv, words, capsys):
    with pytest.raises(SystemExit) as ex:
        main(argv)
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1


def test_cli_subprocess(release, tmp_path):
    """The real `python -m` entry point: a corrupt release exits 2 with one line, no traceback."""
    src, _ = release
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    cmd = [sys.executable, "-m", "motiongen.importers.trumans"]
    bad = _copy_release(src, tmp_path / "rel")
    (bad / "frame_id.npy").unlink()
    r = subprocess.run(cmd + [f"release={bad}", f"out={tmp_path / 'o'}"], capture_output=True, text=True, env=env)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.strip().splitlines() == [r.stderr.strip()] and "frame_id.npy" in r.stderr
    assert "Traceback" not in r.stderr
    _assert_clean(tmp_path / "o")
