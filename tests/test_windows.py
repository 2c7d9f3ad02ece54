import numpy as np
import torch

from motiongen.data.format import MotionDataset
from motiongen.data.windows import NormStats, WindowConfig, WindowDataset, canonicalize
from motiongen.geometry import facing_yaw, transform_points
from tests.helpers import make_dataset


def _ds(tmp_path, **kw):
    return MotionDataset.open(make_dataset(tmp_path / "ds", **kw))


def test_canonical_first_frame_at_origin_facing_z(tmp_path):
    ds = _ds(tmp_path)
    w = ds.joints[10:58:3].astype(np.float64)                 # (16, 22, 3)
    local, T = canonicalize(w)
    assert np.allclose(local[0, 0, [0, 2]], 0, atol=1e-6)
    assert abs(facing_yaw(local[0])) < 1e-6
    assert np.allclose(local[:, :, 1], w[:, :, 1], atol=1e-6)  # heights untouched
    assert np.allclose(transform_points(T, local), w, atol=1e-5)


def test_window_count_and_frames(tmp_path):
    ds = _ds(tmp_path, T=100)
    cfg = WindowConfig(length=16, stride=3, hop=2, scene=False)
    wd = WindowDataset(ds, "train", cfg)
    span = 15 * 3 + 1
    per_seq = len(range(0, 100 - span + 1, 2))
    assert len(wd) == 2 * per_seq
    assert (np.diff(wd.window_frames(0)) == 3).all()


def test_normalisation_is_min_max_on_train(tmp_path):
    ds = _ds(tmp_path)
    cfg = WindowConfig(scene=False)
    wd = WindowDataset(ds, "train", cfg)
    x = torch.stack([wd[i]["motion"] for i in range(len(wd))])  # (W, L, D)
    flat = x.reshape(-1, x.shape[-1])
    P = wd.layout.pose_channels
    # stance channels are labels in {-1, +1}, kept as they are
    assert wd.layout.num_contacts == 4 and set(flat[:, P:].unique().tolist()) <= {-1.0, 1.0}
    flat = flat[:, :P]
    varying = torch.as_tensor(wd.stats.half_range[:P] > 0.0100001)
    assert torch.allclose(flat.max(0).values[varying], torch.ones(int(varying.sum())), atol=1e-5)
    assert torch.allclose(flat.min(0).values[varying], -torch.ones(int(varying.sum())), atol=1e-5)
    s = NormStats.from_state_dict(wd.stats.state_dict())
    assert np.allclose(s.denormalize(s.normalize(np.ones(70, np.float32))), 1)
    # val windows use the train statistics
    val = WindowDataset(ds, "val", cfg, wd.stats)
    assert np.array_equal(val.stats.center, wd.stats.center)


def test_item_contents_and_goal(tmp_path):
    ds = _ds(tmp_path)
    wd = WindowDataset(ds, "train", WindowConfig())
    it = wd[5]
    assert it["motion"].shape == (16, 66 + 4) and it["actions"].shape == (16, 2)
    assert it["scene"].shape == (32, 32, 32) and it["scene"].dtype == torch.float32
    local, _ = wd.layout.decode(wd.stats.denormalize(it["motion"]))                     # (16, 22, 3)
    assert torch.allclose(it["goal"], local[-1, 0], atol=1e-4)
    # the goal maps back to the world pelvis of the window's last frame
    world_goal = transform_points(it["to_world"].numpy(), it["goal"].numpy()[None])[0]
    assert np.allclose(world_goal, ds.joints[wd.window_frames(5)[-1], 0], atol=1e-4)


def test_local_scene_matches_brute_force(tmp_path):
    ds = _ds(tmp_path)
    cfg = WindowConfig()
    wd = WindowDataset(ds, "train", cfg)
    grid = ds.grid(1)
    for i in (0, len(wd) // 2, len(wd) - 1):
        it = wd[i]
        occ = it["scene"].numpy()                                  # (Hy, Hx, Hz)
        T, goal = it["to_world"].numpy().astype(np.float64), it["goal"].numpy()
        n = 32
        for (a, b, c) in [(0, 0, 0), (5, 17, 30), (31, 31, 31), (10, 3, 22)]:
            local = np.array([-0.6 + (b + 0.5) * 1.2 / n + goal[0], (a + 0.5) * 1.2 / n, -0.6 + (c + 0.5) * 1.2 / n + goal[2]])
            world = transform_points(T, local[None])[0]
            assert occ[a, b, c] == float(grid.occupied(world[None], outside=True)[0])


def test_obstacle_appears_in_front(tmp_path):
    """A window whose goal stands 0.3 m in front of (facing) the obstacle sees it in local +z."""
    from motiongen.scene.local_occupancy import local_occupancy_np
    from motiongen.geometry import local_to_world
    ds = _ds(tmp_path)
    wd = WindowDataset(ds, "train", WindowConfig())
    T = local_to_world(np.array(0.0), np.array([1.0, 0.5]))        # at (1, 0.5) facing +z: box at z 0.8..1.2
    low = local_occupancy_np(ds.grid(1), T, wd.spec)[:10]          # heights below 0.375 m: (10, Hx, Hz)
    # box x in [0.8, 1.2) -> local x in [-0.2, 0.2): cells 11..20; z in [0.8, 1.2) -> local z 0.3..0.6: cells 24..31
    assert low[:, 11:21, 25:32].all()
    assert low[:, :10, :].sum() == 0 and low[:, 22:, :].sum() == 0 and low[:, :, :24].sum() == 0


def test_dynamic_object_enters_the_local_grid(tmp_path):
    """An object slot posed at the goal shows up in the window's occupancy."""
    import trimesh
    from motiongen.data.dataset_writer import DatasetWriter
    from motiongen.scene.occupancy import OccupancyGrid
    from motiongen.skeleton import BODY
    from tests.helpers import walking_sequence
    w = DatasetWriter(tmp_path / "obj", BODY, ["walk"], 30.0, num_object_slots=1)
    w.add_scene(1, grid=OccupancyGrid.from_dense(np.zeros((200, 100, 200), bool), [-2.0, 0, -2.0], 0.02))
    w.add_object(0, name="crate", type="box", mesh=trimesh.creation.box([0.2, 0.2, 0.2]))
    j = walking_sequence(60, [0.0, -1.5], 0.0, 0.0, 1.0)            # walks along +z, well inside the grid
    poses = np.tile(np.eye(4, dtype=np.float32), (60, 1, 1, 1))
    poses[:, 0, :3, 3] = j[45, 0] * [1, 0, 1] + [0, 0.5, 0.3]       # crate 0.3 m ahead of the goal (frame 45) pelvis
    ids = np.zeros((60, 1), np.int32)
    w.add_sequence("a", 1, j, np.ones((60, 1), bool), np.zeros((60, 22), bool), object_poses=poses, object_ids=ids)
    w.finish(splits={"train": [1]})
    ds = MotionDataset.open(tmp_path / "obj")
    wd = WindowDataset(ds, "train", WindowConfig(hop=100))
    item = wd[0]
    occ = item["scene"].numpy()                                     # (Hy, Hx, Hz)
    assert occ.sum() > 0
    ys, xs, zs = np.nonzero(occ)
    cell = 1.2 / 32
    # occupied cells sit 0.3 m ahead of the goal (local z) at heights 0.4..0.6 m
    assert abs((zs.mean() + 0.5) * cell - 0.6 - 0.3) < 0.05 and abs((ys.mean() + 0.5) * cell - 0.5) < 0.05
    no_obj = WindowDataset(ds, "train", WindowConfig(hop=100, objects=False), wd.stats)
    assert no_obj[0]["scene"].sum() == 0
