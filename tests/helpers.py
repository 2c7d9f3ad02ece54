"""Small hand-made datasets and motions with known answers for tests."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from motiongen.body.model import BodyModel
from motiongen.body.procedural import ensure_procedural_model
from motiongen.body.random_motion import sample_motion
from motiongen.data.dataset_writer import DatasetWriter
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.importers.trumans_release import GridSpec
from motiongen.geometry import transform_points, local_to_world
from motiongen.skeleton import BODY

# A rest pose facing +z (left hip at +x), y-up, metres: (22, 3).
REST = np.array([
    [0, .95, 0], [.09, .88, 0], [-.09, .88, 0], [0, 1.05, 0], [.1, .5, 0], [-.1, .5, 0], [0, 1.18, 0],
    [.1, .08, 0], [-.1, .08, 0], [0, 1.24, 0], [.1, .02, .12], [-.1, .02, .12], [0, 1.45, 0],
    [.08, 1.38, 0], [-.08, 1.38, 0], [0, 1.6, .02], [.18, 1.38, 0], [-.18, 1.38, 0], [.45, 1.38, 0],
    [-.45, 1.38, 0], [.7, 1.38, 0], [-.7, 1.38, 0]], np.float32)


def walking_sequence(T: int, start_xz, yaw0: float, turn_rate: float, speed: float) -> np.ndarray:
    """(T, 22, 3): the rest pose carried along a curved path at `speed` m/s (30 fps)."""
    yaw = yaw0 + turn_rate * np.arange(T) / 30.0
    pos = np.zeros((T, 2))
    pos[0] = start_xz
    for t in range(1, T):
        pos[t] = pos[t - 1] + speed / 30.0 * np.array([np.sin(yaw[t]), np.cos(yaw[t])])
    return np.stack([transform_points(local_to_world(yaw[t], pos[t]), REST) for t in range(T)]).astype(np.float32)


def make_dataset(root, scenes=(1, 71, 91), seqs_per_scene=2, T=120, obstacle=True):
    """A dataset with one 4 x 2 x 4 m scene per id (a 0.4 m box at (1, *, 1) when `obstacle`)."""
    w = DatasetWriter(root, BODY, ["walk", "sit"], 30.0)
    rng = np.random.default_rng(0)
    for sid in scenes:
        occ = np.zeros((200, 100, 200), bool)               # 2 cm, origin (-2, 0, -2)
        if obstacle:
            occ[140:160, 0:40, 140:160] = True              # x, z in [0.8, 1.2), y in [0, 0.8)
        w.add_scene(sid, grid=OccupancyGrid.from_dense(occ, [-2.0, 0.0, -2.0], 0.02))
        for k in range(seqs_per_scene):
            j = walking_sequence(T, rng.uniform(-1, 0, 2), rng.uniform(-np.pi, np.pi), rng.uniform(-0.5, 0.5), 1.0)
            acts = np.zeros((T, 2), bool)
            acts[:, 0] = True
            w.add_sequence(f"s{sid}_{k}", sid, j, acts, np.zeros((T, 22), bool))
    return w.finish(splits={"train": [1], "val": [71], "test": [91]}, source="test")


# ---------------------------------------------------------------------------------------
# A miniature TRUMANS release (Data_release/ names, shapes and dtypes)

GRID = GridSpec()
SEQS = [("seqA", 40, 0), ("seqB", 30, 1), ("seqC", 50, 2)]   # name, frames, scene index
SCENE_FILES = ["scene_003.npy", "scene_075.npy", "scene_095.npy"]  # ids 3 / 75 / 95: train / val / test
TABLE_TOP = 0.74  # the table slab's top face (m), in scene 0 only

SMALL = GridSpec(shape=(30, 10, 40), voxel_size=0.2)   # same extent, coarse: for tests that ignore grids


def _voxel(p, grid):
    return tuple(np.floor((np.asarray(p) - grid.origin) / grid.voxel_size).astype(int))


def write_fake_release(root: Path, seed: int = 0, grid: GridSpec = GRID) -> dict:
    """A release of 3 sequences (120 frames) in 3 scenes; returns the arrays written."""
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True)
    N = sum(t for _, t, _ in SEQS)
    joints = np.empty((N, 24, 3), np.float32)
    joints[..., 0] = rng.uniform(-2.5, 2.5, (N, 24))
    joints[..., 1] = rng.uniform(0.3, 1.6, (N, 24))     # away from the floor...
    joints[..., 2] = rng.uniform(-3.5, 3.5, (N, 24))
    joints[:, 10, 1] = 0.02                              # ...except the left toe: floor contact
    joints[:, 20] = (0.5, TABLE_TOP + 0.03, 0.5)          # left wrist 3 cm above the table (scene 0)
    seg = np.concatenate([np.full(t, n) for n, t, _ in SEQS])
    flag = np.concatenate([np.full(t, s) for _, t, s in SEQS]).astype(np.int64)
    labels = (rng.random((N, 10)) < 0.3).astype(np.float32)
    obj_flag = np.full((N, 35), -1, np.int64)
    obj_flag[:40, 3] = 0          # seqA: object type 3 in slot 0, type 17 in slot 2
    obj_flag[:40, 17] = 2
    obj_flag[40:70, 34] = 4       # seqB: type 34 in slot 4
    obj_mat = rng.normal(size=(N, 5, 4, 4)).astype(np.float32)
    obj_mat[:, :, 3] = (0, 0, 0, 1)
    obj_mat[70:, :] = np.nan     # seqC has no objects: garbage in empty slots must not leak
    arrays = {
        "human_joints": joints, "human_orient": rng.normal(size=(N, 3)).astype(np.float32),
        "idx_start": np.arange(0, N - 48, 3, dtype=np.int64), "action_label": labels, "scene_flag": flag,
        "object_flag": obj_flag, "object_mat": obj_mat, "seg_name": seg,
        "frame_id": np.arange(N, dtype=np.int64),
        "human_pose": rng.normal(size=(N, 63)).astype(np.float32),
        "human_transl": rng.normal(size=(N, 3)).astype(np.float32),
    }
    for k, v in arrays.items():
        np.save(root / f"{k}.npy", v)
    (root / "Scene").mkdir()
    for i, name in enumerate(SCENE_FILES):
        occ = np.zeros(grid.shape, bool)
        occ[:, 0, :5] = True                                       # a wall strip, everywhere
        if i == 0:
            lo, hi = _voxel((0.2, TABLE_TOP - 0.04, 0.2), grid), _voxel((0.8, TABLE_TOP - 0.0001, 0.8), grid)
            occ[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1] = True  # table slab
        np.save(root / "Scene" / name, occ)
    return arrays


def write_posed_release(root: Path, mesh_dir: Path | None = None, grid: GridSpec = SMALL) -> dict:
    """`write_fake_release` with a real body: SMPL-X parameters of the body model in use (rest
    pose, standing on the floor at x = -1, z = 1.5), joints = their kinematics (body + index1),
    and every present object pose rigid. In seqA object type 3 (`object_03`) is a box standing on
    the floor under the left hand, whose palm rests 3 mm above its top in frames HOLD and is lifted
    (shoulder raised) elsewhere. mesh_dir: gets object_03.ply (that box), object_17.ply (a box 10 %
    lower) and object_34.ply (boxes, local frames centred on the origin; all of type "object").
    Returns the arrays written, with "box_height"."""
    import torch
    import trimesh

    from motiongen.body.model import load_body_model
    from motiongen.body.rotations import axis_angle_to_matrix
    from motiongen.body.solve import MotionBody
    from motiongen.skeleton import get_joint_set

    arrays = write_fake_release(root, grid=grid)
    bm = load_body_model()
    N = len(arrays["human_joints"])
    with torch.no_grad():
        rest = bm.vertices(torch.zeros(3), torch.zeros(63), torch.zeros(3), torch.zeros(bm.num_betas)).double().numpy()
    hand = rest[np.asarray(bm.skinning_weights).argmax(1) == 20]                  # left wrist part
    transl = np.tile([-1.0, 0.002 - rest[:, 1].min(), 1.5], (N, 1))
    lift = np.ones(N)
    lift[HOLD] = 0.0
    lift[HOLD.start - 5:HOLD.start] = np.linspace(1, 0, 7)[1:-1]
    lift[HOLD.stop:HOLD.stop + 5] = np.linspace(0, 1, 7)[1:-1]
    pose = np.zeros((N, 63))
    pose[:, 15 * 3 + 2] = 0.25 * lift                                             # left shoulder about +z: arm up
    orient = np.zeros((N, 3))
    js = get_joint_set("body+index1")
    R = torch.cat([torch.eye(3).expand(N, 1, 3, 3).double(),
                   axis_angle_to_matrix(torch.as_tensor(pose).reshape(N, 21, 3))], 1)
    with torch.no_grad():
        joints = MotionBody(bm.double(), js, torch.zeros(1, bm.num_betas, dtype=torch.float64)).pose(
            R[None], torch.as_tensor(transl)[None], slice(0, 1))[0].numpy()
    bm.float()
    palm = hand[:, 1].min() + transl[0, 1]
    h = float(palm - 0.003)
    centre = np.array([hand[:, 0].mean() + transl[0, 0], h / 2, hand[:, 2].mean() + transl[0, 2]])
    mat = np.tile(np.eye(4, dtype=np.float32), (N, 5, 1, 1))
    mat[:, 0, :3, 3] = centre                                                     # type 3 in slot 0 (seqA)
    mat[:, 2, :3, 3] = (2.0, 0.1, -2.0)                                           # type 17 in slot 2, far away
    mat[:, 4, :3, 3] = (-2.0, 0.1, -2.0)                                          # type 34 in slot 4 (seqB)
    arrays.update(human_joints=joints.astype(np.float32), human_orient=orient.astype(np.float32),
                  human_pose=pose.astype(np.float32), human_transl=transl.astype(np.float32), object_mat=mat)
    for k in ("human_joints", "human_orient", "human_pose", "human_transl", "object_mat"):
        np.save(root / f"{k}.npy", arrays[k])
    if mesh_dir is not None:
        mesh_dir.mkdir(parents=True, exist_ok=True)
        trimesh.creation.box(extents=(0.3, h, 0.3)).export(mesh_dir / "object_03.ply")
        trimesh.creation.box(extents=(0.25, 0.9 * h, 0.25)).export(mesh_dir / "object_17.ply")
        trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(mesh_dir / "object_34.ply")
    arrays["box_height"] = h
    return arrays


HOLD = slice(12, 30)   # frames of seqA in which the left hand rests on the box (write_posed_release)


def user_error(capsys, main, argv) -> str:
    """Run a tool's `main(argv)` that must refuse: exit status 2 and one line `error: ...` on
    stderr, no traceback. Returns that line."""
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and "Traceback" not in err
    return err


def standing_body_motion(root: Path, T: int):
    """(body model, body parameters (a namespace: global_orient, body_pose, transl, betas),
    joints (1, T, 22, 3)) of the procedural body standing in place for T frames (seed 4),
    the model written under `root`."""
    bm = BodyModel(ensure_procedural_model(Path(root) / "SMPLX_NEUTRAL.npz"))
    m = sample_motion(T, 30.0, np.random.default_rng(4), gait=False)
    with torch.no_grad():
        joints = bm.joints(*(torch.as_tensor(m[k]) for k in ("global_orient", "body_pose", "transl", "betas")))
    return bm, SimpleNamespace(**m), joints.numpy()[None]
