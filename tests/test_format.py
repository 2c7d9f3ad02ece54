"""The motiongen on-disk format: round trips through DatasetWriter / MotionDataset.open,
OccupancyGrid storage and queries, atomic publishing, and one-line DataErrors naming the file
and field for every corrupt-file case."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from motiongen.data.format import DEFAULT_SPLITS, MotionDataset
from motiongen.data.dataset_writer import DatasetWriter
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.errors import DataError
from motiongen.skeleton import BODY, JOINT_SETS

ACTIONS = ["walk", "sit", "grab"]
LENGTHS = [(12, 1), (7, 75), (9, 1)]   # (frames, scene id): scene 1 is train, 75 is val
K = 2


def _grid(seed: int, shape=(10, 6, 13)) -> OccupancyGrid:
    occ = np.random.default_rng(seed).random(shape) < 0.3
    return OccupancyGrid.from_dense(occ, origin=(-1.0, 0.0, -1.3), voxel_size=0.1)


def _sequences(seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for i, (T, scene) in enumerate(LENGTHS):
        J = BODY.num_joints
        ids = np.full((T, K), -1, np.int32)
        ids[:, 0] = i % 2                                   # object 0 or 1 in slot 0
        out.append(dict(
            name=f"seq{i}", scene=scene,
            joints=rng.normal(size=(T, J, 3)).astype(np.float32),
            actions=rng.random((T, len(ACTIONS))) < 0.5,
            contact=rng.random((T, J)) < 0.2,
            object_poses=rng.normal(size=(T, K, 4, 4)).astype(np.float32),
            object_ids=ids,
            smplx={"global_orient": rng.normal(size=(T, 3)), "body_pose": rng.normal(size=(T, 63)),
                   "transl": rng.normal(size=(T, 3)), "betas": rng.normal(size=10)},  # betas (10,) broadcast
        ))
    return out


def write_dataset(root: Path, seqs=None, overwrite: bool = False) -> Path:
    seqs = _sequences() if seqs is None else seqs
    w = DatasetWriter(root, BODY, ACTIONS, fps=30, num_object_slots=K, has_smplx=True, overwrite=overwrite)
    w.add_scene(1, grid=_grid(1), mesh=trimesh.creation.box((1.0, 2.0, 3.0)), name="room")
    w.add_scene(75, grid=_grid(75))
    w.add_object(0, name="cup_0", type="cup", mesh=trimesh.creation.icosphere(subdivisions=1, radius=0.05))
    w.add_object(1, name="book_0", type="book")
    for s in seqs:
        w.add_sequence(**s)
    return w.finish(splits=DEFAULT_SPLITS, source="test", extra={"note": "hi"})


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("fmt") / "ds")


def _copy(src: Path, dst: Path) -> Path:
    import shutil
    shutil.copytree(src, dst)
    return dst


# ---------------------------------------------------------------------------------------
# Round trip


def test_roundtrip_arrays(clean):
    seqs = _sequences()
    ds = MotionDataset.open(clean)
    assert ds.num_frames == sum(T for T, _ in LENGTHS) and ds.fps == 30.0
    assert ds.joint_set is BODY and ds.action_names == ACTIONS and ds.meta["note"] == "hi"
    assert ds.meta["up"] == "y" and ds.meta["units"] == "m"
    for s, ref in zip(ds.sequences, seqs):
        assert (s.name, s.scene, s.num_frames) == (ref["name"], ref["scene"], len(ref["joints"]))
        sl = slice(s.start, s.end)
        np.testing.assert_array_equal(ds.joints[sl], ref["joints"])
        np.testing.assert_array_equal(ds.actions[sl], ref["actions"])
        np.testing.assert_array_equal(ds.contact[sl], ref["contact"])
        np.testing.assert_array_equal(ds.object_poses[sl], ref["object_poses"])
        np.testing.assert_array_equal(ds.object_ids[sl], ref["object_ids"])
        assert (ds.scene_id[sl] == ref["scene"]).all()
        for k in ("global_orient", "body_pose", "transl"):
            np.testing.assert_allclose(ds.smplx[k][sl], ref["smplx"][k].astype(np.float32))
        np.testing.assert_allclose(ds.smplx["betas"][sl], np.broadcast_to(ref["smplx"]["betas"], (s.num_frames, 10)),
                                   rtol=1e-6)
    assert isinstance(ds.joints, np.memmap) and not ds.joints.flags.writeable
    got = [(s.name, j.shape) for s, j in ds.iter_sequences("train")]
    assert got == [("seq0", (12, 22, 3)), ("seq2", (9, 22, 3))]
    assert [s.name for s in ds.split_sequences("val")] == ["seq1"] and ds.split_of_scene(75) == "val"
    with pytest.raises(DataError, match="no split named 'dev'"):
        ds.split_sequences("dev")


def test_roundtrip_scenes_and_objects(clean):
    ds = MotionDataset.open(clean)
    assert ds.scenes[1]["name"] == "room" and ds.scenes[75]["mesh"] is None
    np.testing.assert_array_equal(ds.grid(1).dense(), _grid(1).dense())
    np.testing.assert_array_equal(ds.grid(75).dense(), _grid(75).dense())
    assert ds.grid(1) is ds.grid(1)                        # cached
    np.testing.assert_allclose(ds.scene_mesh(1).extents, (1, 2, 3))
    assert ds.scene_mesh(75) is None
    assert ds.objects[0]["type"] == "cup" and len(ds.object_mesh(0).vertices) == 42
    assert ds.object_mesh(1) is None
    with pytest.raises(DataError, match="no occupancy grid"):
        ds.grid(2)


def test_minimal_dataset_without_objects_or_smplx(tmp_path):
    w = DatasetWriter(tmp_path / "d", JOINT_SETS["body+index1"], ["a"], fps=10)
    w.add_scene(3)
    w.add_sequence("s", scene=3, joints=np.zeros((4, 24, 3)), actions=np.zeros((4, 1), bool),
                   contact=np.zeros((4, 24), bool))
    ds = MotionDataset.open(w.finish())
    assert ds.object_poses is None and ds.object_ids is None and ds.smplx is None
    assert ds.joints.dtype == np.float32 and ds.joints.shape == (4, 24, 3) and ds.fps == 10.0


def test_splits_override(clean):
    ds = MotionDataset.open(clean, splits={"all": [1, 75]})
    assert [s.name for s in ds.split_sequences("all")] == ["seq0", "seq1", "seq2"]


# ---------------------------------------------------------------------------------------
# OccupancyGrid


@pytest.mark.parametrize("shape", [(5, 4, 8), (6, 3, 13)])      # z a multiple of 8, and not
def test_occupancy_roundtrip_and_queries(tmp_path, shape):
    rng = np.random.default_rng(0)
    occ = rng.random(shape) < 0.4
    g = OccupancyGrid.from_dense(occ, origin=(-0.3, 0.0, 0.2), voxel_size=0.05)
    assert g.bits.shape == (shape[0], shape[1], (shape[2] + 7) // 8) and g.bits.dtype == np.uint8
    g.save(tmp_path / "g")
    h = OccupancyGrid.load(tmp_path / "g")
    assert h.shape == shape and h.voxel_size == 0.05 and isinstance(h.bits, np.memmap)
    np.testing.assert_array_equal(h.dense(), occ)
    np.testing.assert_allclose(h.bounds, [[-0.3, 0, 0.2], np.array([-0.3, 0, 0.2]) + np.array(shape) * 0.05])
    # every voxel centre reads its own dense value
    centres = h.origin + (np.indices(shape).reshape(3, -1).T + 0.5) * h.voxel_size   # (V, 3)
    np.testing.assert_array_equal(h.occupied(centres), occ.reshape(-1))
    # random points inside, batch-shaped
    pts = rng.uniform(h.bounds[0], h.bounds[1], (4, 50, 3))
    ijk = np.floor((pts - h.origin) / h.voxel_size).astype(int)
    np.testing.assert_array_equal(h.occupied(pts), occ[ijk[..., 0], ijk[..., 1], ijk[..., 2]])
    # outside the grid: the `outside` value
    far = np.array([[-10.0, 0.1, 0.3], [0, -0.01, 0.3], [0, 0.1, 99]])
    assert h.occupied(far).all() and not h.occupied(far, outside=False).any()


def test_occupancy_load_errors(tmp_path):
    _grid(0).save(tmp_path / "g")
    (tmp_path / "g.occ.json").write_text('{"shape": [10, 6], "origin": [0, 0, 0], "voxel_size": 0.1}')
    with pytest.raises(DataError, match="g.occ.json.*expected 3-D shape"):
        OccupancyGrid.load(tmp_path / "g")
    (tmp_path / "g.occ.json").write_text('{"shape": [10, 6, 13], "origin": [0, 0, 0], "voxel_size": 0.1}')
    np.save(tmp_path / "g.occ.npy", np.zeros((10, 6, 13), np.uint8))
    with pytest.raises(DataError, match=r"\[occupancy\].*expected uint8 \(10, 6, 2\)"):
        OccupancyGrid.load(tmp_path / "g.occ.npy")
    (tmp_path / "g.occ.json").unlink()
    with pytest.raises(DataError, match="g.occ.json: occupancy grid file is missing"):
        OccupancyGrid.load(tmp_path / "g")


# ---------------------------------------------------------------------------------------
# Atomic writing


def test_aborted_writer_leaves_nothing(tmp_path):
    root = tmp_path / "ds"
    w = DatasetWriter(root, BODY, ACTIONS, fps=30, num_object_slots=K, has_smplx=True)
    w.add_scene(1, grid=_grid(1))
    w.add_sequence(**_sequences()[0])
    w.abort()
    assert list(tmp_path.iterdir()) == []


def test_writer_refuses_existing_root_and_overwrite_replaces(clean, tmp_path):
    root = _copy(clean, tmp_path / "ds")
    with pytest.raises(DataError, match="already exists"):
        DatasetWriter(root, BODY, ACTIONS, fps=30)
    seqs = _sequences(seed=1)[:1]
    w = DatasetWriter(root, BODY, ACTIONS, fps=30, num_object_slots=K, has_smplx=True, overwrite=True)
    w.add_scene(1, grid=_grid(1))
    w.add_object(0, "cup_0", "cup")
    w.add_object(1, "book_0", "book")
    w.add_sequence(**seqs[0])
    assert MotionDataset.open(root).num_frames == 28      # the old dataset is live until finish
    w.finish()
    ds = MotionDataset.open(root)
    assert ds.num_frames == 12 and list(ds.scenes) == [1]
    np.testing.assert_array_equal(ds.joints, seqs[0]["joints"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]   # no .partial / .old left over


def test_overwrite_refuses_foreign_directory(tmp_path):
    (tmp_path / "stuff").mkdir()
    (tmp_path / "stuff" / "thesis.tex").write_text("precious")
    with pytest.raises(DataError, match="refusing to overwrite"):
        DatasetWriter(tmp_path / "stuff", BODY, ACTIONS, fps=30, overwrite=True)
    assert (tmp_path / "stuff" / "thesis.tex").read_text() == "precious"
    (tmp_path / "empty").mkdir()
    w = DatasetWriter(tmp_path / "empty", BODY, ACTIONS, fps=30, overwrite=True)  # empty: fine
    w.abort()


def test_bad_sequence_rows_rejected(tmp_path):
    w = DatasetWriter(tmp_path / "ds", BODY, ACTIONS, fps=30)
    s = _sequences()[0]
    with pytest.raises(ValueError, match="contact"):
        w.add_sequence(s["name"], 1, s["joints"], s["actions"], s["contact"][:-1])
    w.abort()
    assert not (tmp_path / "ds").exists()


# ---------------------------------------------------------------------------------------
# Corrupt datasets: one line naming the file and the field


def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[:-50])


def _npy(name, fn):
    def mutate(root: Path):
        a = np.load(root / f"{name}.npy")
        np.save(root / f"{name}.npy", fn(a))
    return mutate


def _json(name, fn):
    def mutate(root: Path):
        p = root / name
        p.write_text(json.dumps(fn(json.loads(p.read_text()))))
    return mutate


def _nan(a):
    a = a.copy()
    a[15, 3, 1] = np.nan
    return a


def _set(a, idx, v):
    a = a.copy()
    a[idx] = v
    return a


def _meta(**kw):
    return _json("meta.json", lambda m: {**m, **kw})


def _drop_meta(key):
    return _json("meta.json", lambda m: {k: v for k, v in m.items() if k != key})


CORRUPT = {
    # case: (mutate(root), file in the message, field in the message, words in the message)
    "truncated_npy": (lambda r: _truncate(r / "joints.npy"), "joints.npy", "[joints]", "not a readable .npy"),
    "empty_npy": (lambda r: (r / "contact.npy").write_bytes(b""), "contact.npy", "[contact]", "not a readable"),
    "missing_npy": (lambda r: (r / "actions.npy").unlink(), "actions.npy", "[actions]", "missing"),
    "nan_joints": (_npy("joints", _nan), "joints.npy", "[joints]", "non-finite value (NaN or inf) at frame 15"),
    "inf_smplx": (_npy("smplx_transl", lambda a: _set(a, (3, 0), np.inf)), "smplx_transl.npy", "[smplx_transl]",
                  "at frame 3"),
    "wrong_shape": (_npy("contact", lambda a: a[:, :20]), "contact.npy", "[contact]", "expected shape (28, 22)"),
    "wrong_rows": (_npy("object_ids", lambda a: a[:-1]), "object_ids.npy", "[object_ids]", "expected shape (28, 2)"),
    "wrong_dtype": (_npy("actions", lambda a: a.astype(np.uint8)), "actions.npy", "[actions]",
                    "expected dtype bool, found uint8"),
    "wrong_dtype_f64": (_npy("joints", lambda a: a.astype(np.float64)), "joints.npy", "[joints]", "found float64"),
    "missing_grid_file": (lambda r: (r / "scenes" / "scene_075.occ.npy").unlink(), "scene_075.occ.npy",
                          "[scene 75 grid]", "missing"),
    "missing_grid_meta": (lambda r: (r / "scenes" / "scene_075.occ.json").unlink(), "scene_075.occ.json",
                          "[scene 75 grid]", "missing"),
    "missing_scene_mesh": (lambda r: (r / "scenes" / "scene_001.ply").unlink(), "scene_001.ply", "[scene 1 mesh]",
                           "missing"),
    "missing_object_mesh": (lambda r: (r / "objects" / "cup_0.ply").unlink(), "cup_0.ply", "[object 0]", "missing"),
    "not_tiling_gap": (_json("sequences.json", lambda s: [s[0], {**s[1], "start": s[1]["start"] + 1}, s[2]]),
                       "sequences.json", "[seq1]", "must tile the frames"),
    "not_tiling_short": (_json("sequences.json", lambda s: s[:2]), "sequences.json", "", "cover 19 frames"),
    "sequence_entry": (_json("sequences.json", lambda s: [{"name": "x"}]), "sequences.json", "", "each entry needs"),
    "scene_id_range": (_npy("scene_id", lambda a: _set(a, 15, 9)), "scene_id.npy", "[scene_id]",
                       "frame 15 has scene id 9"),
    "sequence_scene_unknown": (_json("sequences.json", lambda s: [s[0], {**s[1], "scene": 9}, s[2]]),
                               "sequences.json", "[seq1]", "scene id 9 is not in scenes.json"),
    "object_id_unknown": (_npy("object_ids", lambda a: _set(a, (5, 1), 7)), "object_ids.npy", "[object_ids]",
                          "object id 7 is not in objects.json"),
    "meta_syntax": (lambda r: (r / "meta.json").write_text('{"format": '), "meta.json", "", "malformed JSON"),
    "meta_missing": (lambda r: (r / "meta.json").unlink(), "meta.json", "", "missing"),
    "meta_not_dict": (lambda r: (r / "meta.json").write_text("[1, 2]"), "meta.json", "[format]", "found 'list'"),
    "meta_format": (_meta(format="npz-motion"), "meta.json", "[format]", "expected 'motiongen-dataset'"),
    "meta_version": (_meta(version=2), "meta.json", "[version]", "expected 1, found 2"),
    "meta_key": (_drop_meta("actions"), "meta.json", "[actions]", "required key is missing"),
    "meta_fps": (_meta(fps=-3), "meta.json", "[fps]", "positive number"),
    "meta_joint_names": (_meta(joint_names=["pelvis"]), "meta.json", "[joint_names]", "match no known joint set"),
    "meta_num_frames_type": (_meta(num_frames="many"), "meta.json", "[num_frames]", "non-negative integer"),
    "meta_actions_type": (_meta(actions=3), "meta.json", "[actions]", "list of strings"),
    "meta_slots_type": (_meta(num_object_slots=None), "meta.json", "[num_object_slots]", "non-negative integer"),
    "meta_has_smplx": (_meta(has_smplx="no"), "meta.json", "[has_smplx]", "expected true or false"),
    "meta_splits": (_meta(splits=[1, 2]), "meta.json", "[splits]", "expected an object"),
    "scenes_not_dict": (lambda r: (r / "scenes.json").write_text("[1]"), "scenes.json", "", "expected an object"),
    "scenes_bad_key": (_json("scenes.json", lambda s: {"one": s["1"]}), "scenes.json", "[one]", "integer"),
    "objects_bad_entry": (_json("objects.json", lambda o: {**o, "0": "cup"}), "objects.json", "[0]", "expected an object"),
    "objects_syntax": (lambda r: (r / "objects.json").write_text("{"), "objects.json", "", "malformed JSON"),
}


@pytest.mark.parametrize("case", sorted(CORRUPT))
def test_corrupt_dataset(case, clean, tmp_path):
    mutate, fname, fld, words = CORRUPT[case]
    root = _copy(clean, tmp_path / "ds")
    mutate(root)
    with pytest.raises(DataError) as e:
        MotionDataset.open(root)
    msg = str(e.value)
    assert "\n" not in msg and fname in msg and fld in msg and words in msg, msg


def test_missing_dataset_dir(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        MotionDataset.open(tmp_path / "nope")


def test_check_values_false_skips_value_scans(clean, tmp_path):
    root = _copy(clean, tmp_path / "ds")
    _npy("joints", _nan)(root)
    ds = MotionDataset.open(root, check_values=False)     # fast open: headers only
    assert np.isnan(ds.joints[15, 3, 1])
