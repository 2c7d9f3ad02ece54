"""Scenes: voxelisation against brute force, the grid cache, and local occupancy queries."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from motiongen.scene import mesh_files as scene_mod
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.scene.local_occupancy import (DynamicObjects, GridBank, LocalGridSpec, TorchOccupancy,
                                            frames_from_pose, local_occupancy, local_occupancy_at,
                                            local_occupancy_np)
from motiongen.scene.mesh_files import load_scene_grid, load_scene_mesh
from motiongen.routing import walkable_map
from motiongen.routing.walkable import open_floor
from motiongen.scene.voxelize import voxelize_mesh
from motiongen.errors import DataError


def centres(grid: OccupancyGrid) -> np.ndarray:
    """World voxel centres (X, Y, Z, 3)."""
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in grid.shape], indexing="ij"), -1)
    return grid.origin + (idx + 0.5) * grid.voxel_size


def box(lo, hi) -> trimesh.Trimesh:
    return trimesh.creation.box(bounds=[lo, hi])


def open_box(size=0.4) -> trimesh.Trimesh:
    """A box without its top: not watertight."""
    m = box([0, 0, 0], [size] * 3)
    m.update_faces(m.face_normals[:, 1] < 0.5)
    m.remove_unreferenced_vertices()
    assert not m.is_watertight
    return m


# ---------------------------------------------------------------------------------------
# Voxelisation


def test_grid_aligned_box_is_exact():
    g = voxelize_mesh(box([0, 0, 0], [0.4, 0.2, 0.3]), 0.02)
    expected = np.zeros(g.shape, bool)
    lo = np.round(-g.origin / 0.02).astype(int)                      # voxel index of world 0
    expected[lo[0]:lo[0] + 20, lo[1]:lo[1] + 10, lo[2]:lo[2] + 15] = True
    assert np.array_equal(g.dense(), expected)
    # one voxel of padding on every side
    assert np.allclose(g.bounds, [[-0.02] * 3, [0.42, 0.22, 0.32]])


def test_rotated_box_and_sphere_match_contains():
    rot = box([-0.2, -0.1, -0.15], [0.2, 0.1, 0.15])
    rot.apply_transform(trimesh.transformations.rotation_matrix(0.7, [1, 2, 0.5]))
    sphere = trimesh.creation.icosphere(2, radius=0.25)
    sphere.apply_translation([0.013, 0.5, -0.021])
    for mesh in (rot, sphere):
        g = voxelize_mesh(mesh, 0.04)
        ref = mesh.contains(centres(g).reshape(-1, 3)).reshape(g.shape)
        agree = (ref == g.dense()).mean()
        assert agree > 0.99, agree
        assert g.dense().sum() > 0.9 * ref.sum()


def test_overlapping_solids_are_unioned_not_cancelled():
    # Ray parity would leave the overlap empty; the winding rule fills it.
    m = trimesh.util.concatenate([box([0, 0, 0], [0.4, 0.4, 0.4]), box([0.2, 0.2, 0.2], [0.6, 0.6, 0.6])])
    g = voxelize_mesh(m, 0.05)
    assert g.occupied(np.array([[0.3, 0.3, 0.3], [0.1, 0.1, 0.1], [0.5, 0.5, 0.5]])).all()


def test_open_box_gives_thickened_shell_and_empty_interior():
    thin = voxelize_mesh(open_box(), 0.02, shell_thickness=0).dense()
    thick = voxelize_mesh(open_box(), 0.02, shell_thickness=2).dense()
    g = voxelize_mesh(open_box(), 0.02, shell_thickness=2)
    inside = np.array([[0.2, 0.2, 0.2], [0.1, 0.3, 0.1], [0.25, 0.1, 0.3]])
    assert not g.occupied(inside).any()
    on_walls = np.array([[0.0, 0.2, 0.2], [0.4, 0.1, 0.1], [0.2, 0.0, 0.2], [0.2, 0.3, 0.4]])
    assert g.occupied(on_walls).all()
    assert thick.sum() > 2 * thin.sum()
    # the shell is 2 voxels deep on each side of the wall plane x = 0
    assert g.occupied(np.array([[-0.03, 0.2, 0.2], [0.03, 0.2, 0.2]])).all()
    assert not g.occupied(np.array([[0.07, 0.2, 0.2]]), outside=False).any()


def test_inverted_closed_shell_is_not_filled():
    # A closed room box with inward normals: the room is free space, the walls are not.
    room = box([0, 0, 0], [1.0, 0.6, 1.0])
    room.invert()
    g = voxelize_mesh(room, 0.05)
    assert not g.occupied(np.array([[0.5, 0.3, 0.5]])).any()
    assert g.occupied(np.array([[0.5, 0.0, 0.5], [0.0, 0.3, 0.5]])).all()


def test_explicit_bounds_and_mode_solid_vs_shell():
    m = box([0, 0, 0], [0.4, 0.4, 0.4])
    g = voxelize_mesh(m, 0.1, bounds=[[-0.2, -0.2, -0.2], [0.6, 0.6, 0.6]])
    assert g.shape == (8, 8, 8) and np.allclose(g.origin, -0.2)
    assert g.dense().sum() == 4 ** 3
    shell = voxelize_mesh(m, 0.05, mode="shell", shell_thickness=0)
    assert not shell.occupied(np.array([[0.2, 0.2, 0.2]])).any()


# ---------------------------------------------------------------------------------------
# Loading files


def test_glb_scene_folder_and_z_up(tmp_path):
    sc = trimesh.Scene()
    sc.add_geometry(box([0, 0, 0], [0.2, 0.2, 0.2]), node_name="a")
    sc.add_geometry(box([0, 0, 0], [0.2, 0.2, 0.2]), node_name="b",
                    transform=trimesh.transformations.translation_matrix([1.0, 0, 0]))
    sc.export(tmp_path / "s.glb")
    m = load_scene_mesh(tmp_path / "s.glb")
    assert np.allclose(m.bounds, [[0, 0, 0], [1.2, 0.2, 0.2]], atol=1e-6)

    folder = tmp_path / "room"
    folder.mkdir()
    box([0, 0, 0], [0.2, 0.2, 0.2]).export(folder / "a.ply")
    box([1, 0, 0], [1.2, 0.3, 0.2]).export(folder / "b.stl")
    (folder / "notes.txt").write_text("not a mesh")
    g = load_scene_grid(folder, 0.05, cache_dir=tmp_path / "cache")
    assert g.occupied(np.array([[0.1, 0.1, 0.1], [1.1, 0.25, 0.1]])).all()

    # z-up input: a box tall along z becomes tall along y, and +z-up maps to +y.
    box([0, 0, 0], [0.2, 0.2, 1.0]).export(tmp_path / "tall.obj")
    m = load_scene_mesh(tmp_path / "tall.obj", up="z")
    assert np.allclose(m.bounds, [[0, 0, -0.2], [0.2, 1.0, 0]], atol=1e-6)


def test_bad_files_raise_data_error_naming_the_file(tmp_path):
    cases = {"missing.obj": None, "garbage.glb": b"\x00\x01 not a glb", "empty.obj": b"# nothing\n",
             "broken.ply": b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n"}
    for name, content in cases.items():
        p = tmp_path / name
        if content is not None:
            p.write_bytes(content)
        with pytest.raises(DataError, match=name):
            load_scene_grid(p, cache_dir=tmp_path / "cache")
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(DataError, match="empty_dir"):
        load_scene_grid(tmp_path / "empty_dir", cache_dir=tmp_path / "cache")


# ---------------------------------------------------------------------------------------
# Cache


def test_cache_hit_skips_voxelisation_and_key_tracks_content(tmp_path, monkeypatch):
    mesh_path = tmp_path / "b.ply"
    box([0, 0, 0], [0.2, 0.2, 0.2]).export(mesh_path)
    cache = tmp_path / "cache"
    g1 = load_scene_grid(mesh_path, 0.05, cache_dir=cache)
    (npy,) = cache.glob("*.occ.npy")
    mtime = npy.stat().st_mtime_ns

    def fail(*a, **k):
        raise AssertionError("re-voxelised on a cache hit")

    monkeypatch.setattr(scene_mod, "voxelize_mesh", fail)
    g2 = load_scene_grid(mesh_path, 0.05, cache_dir=cache)
    assert isinstance(g2.bits, np.memmap) and npy.stat().st_mtime_ns == mtime
    assert np.array_equal(g1.dense(), g2.dense())
    monkeypatch.undo()

    load_scene_grid(mesh_path, 0.1, cache_dir=cache)                     # new params: new entry
    box([0, 0, 0], [0.3, 0.2, 0.2]).export(mesh_path)                    # new content: new entry
    g3 = load_scene_grid(mesh_path, 0.05, cache_dir=cache)
    assert len(list(cache.glob("*.occ.npy"))) == 3
    assert g3.dense().sum() > g1.dense().sum()
    assert not list(cache.glob("*.tmp*"))

    monkeypatch.setenv("MOTIONGEN_CACHE", str(tmp_path / "envcache"))
    load_scene_grid(mesh_path, 0.05)
    assert len(list((tmp_path / "envcache" / "grids").glob("*.occ.json"))) == 1


# ---------------------------------------------------------------------------------------
# Local occupancy


def random_grid(seed=0, shape=(60, 30, 70), p=0.3) -> OccupancyGrid:
    rng = np.random.default_rng(seed)
    return OccupancyGrid.from_dense(rng.random(shape) < p, origin=[-0.6, -0.093, -0.7], voxel_size=0.02)


SMALL = LocalGridSpec(resolution=(6, 5, 7))


def loop_reference(grid, T, spec, outside=True):
    """Point-by-point lookup with OccupancyGrid.occupied: (Hy, Hx, Hz) for one frame T (4, 4)."""
    x, y, z = spec.axes()
    out = np.zeros(spec.out_shape, bool)
    for a, yy in enumerate(y):
        for b, xx in enumerate(x):
            for c, zz in enumerate(z):
                p = T[:3, :3] @ np.array([xx, yy, zz]) + T[:3, 3]
                out[a, b, c] = grid.occupied(p[None], outside=outside)[0]
    return out


def test_torch_query_equals_point_loop():
    grid = random_grid()
    bank = TorchOccupancy(grid, dtype=torch.float64)
    rng = np.random.default_rng(1)
    B = 6
    pos = rng.uniform([-0.8, -0.9], [0.8, 0.9], (B, 2))                  # some frames reach past the grid
    yaw = rng.uniform(-math.pi, math.pi, B)
    T = frames_from_pose(torch.from_numpy(pos), torch.from_numpy(yaw))
    # a tilted frame takes the general (non-separable) path
    tilt = torch.from_numpy(trimesh.transformations.rotation_matrix(0.3, [1, 0, 0]))
    T = torch.cat([T, (T[:1] @ tilt)])
    occ = local_occupancy(bank, T, SMALL)
    assert occ.shape == (B + 1, 5, 6, 7) and occ.dtype == torch.bool
    for b in range(B + 1):
        ref = loop_reference(grid, T[b].numpy(), SMALL)
        assert np.array_equal(occ[b].numpy(), ref), b
        assert np.array_equal(local_occupancy_np(grid, T[b].numpy(), SMALL), ref), b
    # the float32 default agrees except possibly on exact voxel boundaries
    occ32 = local_occupancy(TorchOccupancy(grid), T.float(), SMALL)
    assert (occ32 == occ).float().mean() > 0.999


def test_query_points_any_shape_and_grid_bank_per_item():
    grids = [random_grid(0), random_grid(1, shape=(40, 20, 33))]
    pts = np.random.default_rng(2).uniform(-0.8, 0.8, (3, 50, 3))
    one = TorchOccupancy(grids[1], dtype=torch.float64)
    assert np.array_equal(one.query(torch.from_numpy(pts)).numpy(), grids[1].occupied(pts))
    bank = GridBank(grids, dtype=torch.float64)
    pick = torch.tensor([1, 0, 1])
    got = bank.query(torch.from_numpy(pts), pick, outside=False).numpy()
    for b in range(3):
        assert np.array_equal(got[b], grids[pick[b]].occupied(pts[b], outside=False))


def obstacle_grid() -> OccupancyGrid:
    """An obstacle x∈[1.4,1.6], y∈[0,0.5], z∈[1.9,2.1] in an otherwise empty 2 cm grid."""
    return voxelize_mesh(box([1.4, 0, 1.9], [1.6, 0.5, 2.1]), 0.02, bounds=[[-1, -0.1, -1], [3, 2, 5]])


def expected_obstacle_cells() -> np.ndarray:
    # 32 cells over 1.2 m: centres at -0.6 + (i + .5) * 0.0375. The obstacle is 0.4..0.6 m ahead
    # (local z: cells 27..31), 0.1 m either side (local x: cells 13..18), below 0.5 m (y: 0..12).
    exp = np.zeros((32, 32, 32), bool)
    exp[0:13, 13:19, 27:32] = True
    return exp


def test_obstacle_in_front_lands_in_forward_cells():
    bank = TorchOccupancy(obstacle_grid())
    # Facing +x (yaw = π/2) from (1.0, 2.0): the obstacle is 0.4 m ahead, on local +z.
    occ = local_occupancy_at(bank, torch.tensor([[1.0, 2.0]]), torch.tensor([math.pi / 2]))
    assert np.array_equal(occ[0].numpy(), expected_obstacle_cells())
    # Facing +z (yaw 0) from (1.5, 1.5): the same obstacle is again 0.4 m straight ahead.
    occ = local_occupancy_at(bank, torch.tensor([[1.5, 1.5]]), torch.tensor([0.0]))
    assert np.array_equal(occ[0].numpy(), expected_obstacle_cells())
    # From (2.0, 2.0) facing −x it is ahead again; facing +x it is behind (local −z, cells 0..4).
    occ = local_occupancy_at(bank, torch.tensor([[2.0, 2.0]] * 2), torch.tensor([-math.pi / 2, math.pi / 2]))
    assert np.array_equal(occ[0].numpy(), expected_obstacle_cells())
    assert np.array_equal(occ[1].numpy(), expected_obstacle_cells()[:, :, ::-1])


def test_body_left_is_local_plus_x():
    # Facing +z, the SMPL-X left hip is at +x: an obstacle at world +x is at local +x.
    bank = TorchOccupancy(voxelize_mesh(box([0.3, 0, -0.1], [0.5, 0.5, 0.1]), 0.02,
                                        bounds=[[-1, -0.1, -1], [1, 2, 1]]))
    occ = local_occupancy_at(bank, torch.zeros(1, 2), torch.zeros(1))[0]    # (Hy, Hx, Hz)
    assert occ[:, 24:, :].any() and not occ[:, :16, :].any()


def test_position_with_height_lifts_the_grid():
    bank = TorchOccupancy(obstacle_grid())
    occ = local_occupancy_at(bank, torch.tensor([[1.0, 0.3, 2.0]]), torch.tensor([math.pi / 2]))[0]
    exp = np.zeros((32, 32, 32), bool)
    exp[0:5, 13:19, 27:32] = True                                        # only 0.2 m of it is above y = 0.3
    assert np.array_equal(occ.numpy(), exp)


def test_out_of_bounds_counts_as_occupied():
    grid = OccupancyGrid.from_dense(np.zeros((50, 100, 80), bool), origin=[-0.5, 0, -0.8], voxel_size=0.02)
    bank = TorchOccupancy(grid)
    # At (0.3, 0) facing +z, local x > 0.2 falls outside the grid (x ≥ 0.5).
    pos, yaw = torch.tensor([[0.3, 0.0]]), torch.zeros(1)
    occ = local_occupancy_at(bank, pos, yaw)[0]
    x = LocalGridSpec().axes()[0]
    assert occ[:, x > 0.2, :].all() and not occ[:, x < 0.2, :].any()
    assert not local_occupancy_at(bank, pos, yaw, outside=False).any()


def test_dynamic_object_follows_its_pose():
    empty = OccupancyGrid.from_dense(np.zeros((50, 25, 50), bool), origin=[-2, -0.1, -2], voxel_size=0.1)
    cube = voxelize_mesh(box([-0.1, 0, -0.1], [0.1, 0.5, 0.1]), 0.02)       # object-local frame
    objs = GridBank([cube])
    scene = TorchOccupancy(empty)
    # Body at (1, 2) facing +x; the object posed at world (1.5, 0, 2) = 0.4..0.6 m ahead.
    pose = torch.eye(4).repeat(3, 1, 1)
    pose[:, 0, 3], pose[:, 2, 3] = 1.5, 2.0
    pose[2] = pose[2] @ torch.from_numpy(trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0])).float()
    valid = torch.tensor([True, False, True])
    T = frames_from_pose(torch.tensor([[1.0, 2.0]] * 3), torch.full((3,), math.pi / 2)).float()
    occ = local_occupancy(scene, T, objects=DynamicObjects.single(objs, pose, valid))
    exp = expected_obstacle_cells()
    assert np.array_equal(occ[0].numpy(), exp)
    assert not occ[1].any()                                               # empty slot skipped
    assert np.array_equal(occ[2].numpy(), exp)                            # a square cube turned 90°
    # K slots with ids: -1 is empty; same answer as the numpy path
    ids = torch.tensor([[-1, 0]])
    poses = torch.stack([torch.eye(4), pose[0]])[None]
    occ = local_occupancy(scene, T[:1], objects=DynamicObjects(objs, ids, poses))
    assert np.array_equal(occ[0].numpy(), exp)
    np_occ = local_occupancy_np(empty, T[0].numpy(), objects=[(cube, pose[0].numpy())])
    assert np.array_equal(np_occ, exp)


def test_objects_whose_box_misses_the_local_grid_are_skipped_with_the_same_answer():
    """`local_occupancy` looks objects up only where their posed grid box meets the local grid's
    box: the answer equals querying every object at every sample point."""
    empty = OccupancyGrid.from_dense(np.zeros((60, 25, 60), bool), origin=[-3, -0.1, -3], voxel_size=0.1)
    objs = GridBank([voxelize_mesh(box([-0.1, 0, -0.1], [0.1, 0.5, 0.1]), 0.02),
                     voxelize_mesh(box([-0.3, 0, -0.2], [0.3, 0.8, 0.2]), 0.04)])
    rng = np.random.default_rng(3)
    B, K = 6, 3
    poses = torch.eye(4).repeat(B, K, 1, 1)
    for b in range(B):
        for k in range(K):
            poses[b, k] = torch.from_numpy(trimesh.transformations.rotation_matrix(rng.uniform(0, 6.3), [0, 1, 0]))
            poses[b, k, [0, 2], 3] = torch.from_numpy(rng.uniform(-1.5, 1.5, 2)).float()
    ids = torch.from_numpy(rng.integers(-1, 2, (B, K)))
    objects = DynamicObjects(objs, ids, poses)
    T = frames_from_pose(torch.from_numpy(rng.uniform(-1, 1, (B, 2))), torch.from_numpy(rng.uniform(0, 6.3, B))).float()
    spec = LocalGridSpec(resolution=(16, 16, 16))
    occ = local_occupancy(TorchOccupancy(empty), T, spec, objects=objects)
    world = spec.points().reshape(-1, 3) @ T[:, :3, :3].double().numpy().transpose(0, 2, 1) + T[:, None, :3, 3].numpy()
    every = objects.query(torch.from_numpy(world).float()).reshape(occ.shape)
    assert torch.equal(occ, every) and 0 < int(every.sum())
    near = objects.overlaps(torch.full((B, 3), -0.6), torch.full((B, 3), 0.6))
    assert not near[ids < 0].any() and 0 < int(near.sum()) < int((ids >= 0).sum())   # some skipped, some not


# ---------------------------------------------------------------------------------------
# Floor map


def test_open_floor_blocks_furniture_not_floor_or_high_shelves():
    parts = [trimesh.Trimesh([[0, 0, 0], [2, 0, 0], [2, 0, 2], [0, 0, 2]], [[0, 2, 1], [0, 3, 2]]),   # floor
             box([0.5, 0, 0.5], [0.9, 0.7, 0.9]),                                                  # table
             box([1.2, 1.8, 1.2], [1.8, 1.9, 1.8])]                                                # high shelf
    grid = voxelize_mesh(trimesh.util.concatenate(parts), 0.05)
    free, origin, cell = open_floor(grid)
    assert free.shape == (grid.shape[0], grid.shape[2]) and cell == 0.05

    def at(x, z, f=free):
        return f[int((x - origin[0]) / cell), int((z - origin[1]) / cell)]

    assert not at(0.7, 0.7) and at(0.3, 0.3) and at(1.5, 1.5)
    free_c = walkable_map(grid, body_radius=0.3).free                                  # 0.3 m clearance
    assert not free_c[int((0.3 - origin[0]) / cell), int((0.7 - origin[1]) / cell)]
    assert at(1.5, 1.5, free_c)
