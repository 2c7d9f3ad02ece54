"""Batched local occupancy: what the scene encoder sees.

* `GridBank` / `TorchOccupancy`: grids as packed bits in one torch tensor (CPU or GPU);
  `query` looks up many points in a per-batch-item grid with one gather.
* `LocalGridSpec` + `local_occupancy`: the (B, Hy, Hx, Hz) body-frame occupancy the scene
  encoder sees, with dynamic objects OR-ed in. `local_occupancy_np` is the same for one
  window in numpy, for DataLoader workers.

Frames: the local grid is in the body frame of geometry.py — yaw θ faces (sin θ, 0, cos θ),
local +z is forward, local +x is the body's left, and p_world = R_y(θ) p_local + t.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np
import torch

from motiongen.scene.occupancy import OccupancyGrid
from motiongen.geometry import invert_rigid, local_to_world



class GridBank:
    """Several `OccupancyGrid`s as one flat packed-bits tensor, queried per batch item.

    A batch mixing scenes (or object types) is one gather: item b reads grid `index[b]`.
    Bits stay packed (8 voxels a byte), so a 2 cm room costs ~1.5 MB of device memory.
    """

    def __init__(self, grids: Sequence[OccupancyGrid], device: str | torch.device = "cpu",
                 dtype: torch.dtype = torch.float32):
        if not grids:
            raise ValueError("GridBank needs at least one grid")
        self.device, self.dtype = torch.device(device), dtype
        flat = [np.ascontiguousarray(g.bits, np.uint8).reshape(-1) for g in grids]
        offsets = np.cumsum([0] + [len(f) for f in flat[:-1]])
        self.bits = torch.from_numpy(np.concatenate(flat)).to(self.device)                 # (N_bytes,) uint8
        self.offset = torch.as_tensor(offsets, dtype=torch.long, device=self.device)       # (G,)
        self.shape = torch.tensor([g.shape for g in grids], dtype=torch.long, device=self.device)  # (G, 3)
        self.origin = torch.tensor(np.stack([g.origin for g in grids]), dtype=dtype, device=self.device)  # (G, 3)
        # Divide (not multiply by 1/size) so indices match OccupancyGrid.index_of bit for bit.
        self.voxel = torch.tensor([g.voxel_size for g in grids], dtype=dtype, device=self.device)  # (G,)

    def __len__(self) -> int:
        return len(self.offset)

    def query(self, points: torch.Tensor, index: torch.Tensor | int = 0, outside: bool = True) -> torch.Tensor:
        """Occupancy (B, N) bool of world points (B, N, 3), item b in grid index[b] (B,) (or one int).

        Nearest-voxel lookup (the voxel containing the point); points outside the grid get
        `outside`.
        """
        B = points.shape[0]
        idx = torch.as_tensor(index, dtype=torch.long, device=self.device).expand(B)     # (B,)
        rel = (points.to(self.dtype) - self.origin[idx, None, :]) / self.voxel[idx, None, None]
        i, j, k = torch.floor(rel).long().unbind(-1)                                     # (B, N) each
        X, Y, Z = self.shape[idx, None, :].unbind(-1)                                    # (B, 1) each
        inside = (i >= 0) & (i < X) & (j >= 0) & (j < Y) & (k >= 0) & (k < Z)           # (B, N)
        base = self.offset[idx, None]                                                    # (B, 1)
        byte_at = base + (i * Y + j) * ((Z + 7) >> 3) + (k >> 3)
        byte = self.bits[torch.where(inside, byte_at, base)].int()                       # (B, N); any valid byte
        bit = ((byte >> (7 - (k & 7)).int()) & 1).bool()                                 # big bit order along z
        return torch.where(inside, bit, torch.full_like(bit, outside))

    def query_columns(self, xz: torch.Tensor, y: torch.Tensor, index: torch.Tensor | int = 0,
                      outside: bool = True) -> torch.Tensor:
        """Occupancy (B, H, M) bool on the product of ground points xz (B, M, 2) (world x, z) and
        heights y (B, H): the same lookup as `query`, with the per-axis index maths done on
        M + H values instead of M * H points (the local grid of a yaw-only frame is such a product).
        """
        B = xz.shape[0]
        idx = torch.as_tensor(index, dtype=torch.long, device=self.device).expand(B)     # (B,)
        o, size = self.origin[idx], self.voxel[idx, None]                                # (B, 3), (B, 1)
        i = torch.floor((xz[..., 0].to(self.dtype) - o[:, None, 0]) / size).long()      # (B, M)
        k = torch.floor((xz[..., 1].to(self.dtype) - o[:, None, 2]) / size).long()      # (B, M)
        j = torch.floor((y.to(self.dtype) - o[:, None, 1]) / size).long()               # (B, H)
        X, Y, Z = self.shape[idx].unbind(-1)                                             # (B,) each
        X, Y, Z = X[:, None], Y[:, None], Z[:, None]
        zbytes = (Z + 7) >> 3
        in_xz = (i >= 0) & (i < X) & (k >= 0) & (k < Z)                                  # (B, M)
        in_y = (j >= 0) & (j < Y)                                                        # (B, H)
        base = self.offset[idx, None, None]                                              # (B, 1, 1)
        col = base + (i * Y * zbytes + (k >> 3))[:, None, :]                             # (B, 1, M)
        byte_at = col + (j * zbytes)[:, :, None]                                         # (B, H, M)
        inside = in_y[:, :, None] & in_xz[:, None, :]                                    # (B, H, M)
        byte = self.bits[torch.where(inside, byte_at, base)].int()
        bit = ((byte >> (7 - (k & 7)).int()[:, None, :]) & 1).bool()
        return torch.where(inside, bit, torch.full_like(bit, outside))


class TorchOccupancy(GridBank):
    """One grid on a device: `query(points (..., 3)) -> (...) bool`."""

    def __init__(self, grid: OccupancyGrid, device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32):
        super().__init__([grid], device, dtype)

    def query(self, points: torch.Tensor, outside: bool = True) -> torch.Tensor:  # type: ignore[override]
        lead = points.shape[:-1]
        flat = points.reshape(1, -1, 3)                                                  # (1, N, 3)
        return super().query(flat, 0, outside).reshape(lead)


# ---------------------------------------------------------------------------------------
# Local (body-frame) occupancy


@dataclass(frozen=True)
class LocalGridSpec:
    """The body-frame sampling grid. Samples sit at cell centres of `resolution` cells."""

    resolution: tuple[int, int, int] = (32, 32, 32)          # (x, y, z) cells
    x_range: tuple[float, float] = (-0.6, 0.6)               # body left/right, metres
    y_range: tuple[float, float] = (0.0, 1.2)                # height above the frame origin
    z_range: tuple[float, float] = (-0.6, 0.6)               # body back/forward

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell-centre coordinates along x (Hx,), y (Hy,), z (Hz,)."""
        return tuple(lo + (np.arange(n) + 0.5) * (hi - lo) / n
                     for n, (lo, hi) in zip(self.resolution, (self.x_range, self.y_range, self.z_range)))

    def points(self) -> np.ndarray:
        """Local sample points (Hy, Hx, Hz, 3) float64 — height first, like the output."""
        x, y, z = self.axes()
        yy, xx, zz = np.meshgrid(y, x, z, indexing="ij")
        return np.stack([xx, yy, zz], -1)

    def corners(self) -> np.ndarray:
        """(8, 3) local corners of the box the grid spans (every sample point lies inside it)."""
        return np.array([[x, y, z] for x in self.x_range for y in self.y_range for z in self.z_range], np.float64)

    @property
    def out_shape(self) -> tuple[int, int, int]:
        """(Hy, Hx, Hz)."""
        return (self.resolution[1], self.resolution[0], self.resolution[2])


def frames_from_pose(position, yaw):
    """Local → world transforms (B, 4, 4) from positions (B, 2) ground (x, z) or (B, 3) (x, y, z)
    and yaws (B,). A (B, 3) position also lifts the local grid's y = 0 to world y."""
    position = torch.as_tensor(position)
    yaw = torch.as_tensor(yaw, dtype=position.dtype if position.is_floating_point() else torch.float64)
    position = position.to(yaw.dtype)
    T = local_to_world(yaw, position[..., [0, -1]])
    if position.shape[-1] == 3:
        T[..., 1, 3] = position[..., 1]
    elif position.shape[-1] != 2:
        raise ValueError(f"positions must be (B, 2) or (B, 3), got {tuple(position.shape)}")
    return T


@dataclass
class DynamicObjects:
    """Movable objects for a batch: K slots per item, each an object grid under a pose.

    bank: object grids in object-local coordinates; ids (B, K) long, -1 = empty slot;
    poses (B, K, 4, 4) object → world.
    """

    bank: GridBank
    ids: torch.Tensor
    poses: torch.Tensor

    @classmethod
    def single(cls, bank: GridBank, poses: torch.Tensor, valid: torch.Tensor | None = None,
               object_index: int = 0) -> "DynamicObjects":
        """One object slot: poses (B, 4, 4), valid (B,) bool (False = no object for that item)."""
        B = poses.shape[0]
        ids = torch.full((B, 1), object_index, dtype=torch.long, device=poses.device)
        if valid is not None:
            ids[~valid.bool().to(poses.device), 0] = -1
        return cls(bank, ids, poses[:, None])

    def overlaps(self, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
        """(B, K) bool: slot k's grid box, posed in the world, meets the world box [lo, hi] (B, 3)
        of item b (False for an empty slot)."""
        dev, dt = self.bank.device, self.bank.dtype
        ids = self.ids.to(dev)
        g = ids.clamp(min=0)
        o, size = self.bank.origin[g], self.bank.shape[g].to(dt) * self.bank.voxel[g][..., None]   # (B, K, 3)
        unit = torch.tensor([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=dt, device=dev)
        corners = o[:, :, None] + unit * size[:, :, None]                                        # (B, K, 8, 3)
        poses = self.poses.to(dev, dt)
        world = corners @ poses[..., :3, :3].transpose(-1, -2) + poses[:, :, None, :3, 3]               # (B, K, 8, 3)
        lo, hi = lo.to(dev, dt)[:, None], hi.to(dev, dt)[:, None]                                 # (B, 1, 3)
        return (ids >= 0) & torch.all((world.amin(2) <= hi) & (world.amax(2) >= lo), -1)

    def query(self, points: torch.Tensor, near: torch.Tensor | None = None) -> torch.Tensor:
        """(B, N) bool: some object occupies the world point (B, N, 3). Outside an object's grid is
        free; near (B, K) bool, when given, names the slots that can be hit at all (`overlaps`)."""
        dev = self.bank.device
        points = points.to(dev, self.bank.dtype)
        occ = torch.zeros(points.shape[:2], dtype=torch.bool, device=dev)
        ids = self.ids.to(dev)
        to_obj = invert_rigid(self.poses.to(dev, self.bank.dtype))                      # (B, K, 4, 4)
        for k in range(ids.shape[1]):
            valid = (ids[:, k] >= 0) & (True if near is None else near[:, k].to(dev))   # (B,)
            if not valid.any():
                continue
            R, t = to_obj[:, k, :3, :3], to_obj[:, k, :3, 3]
            local = points @ R.transpose(-1, -2) + t[:, None, :]                         # (B, N, 3)
            hit = self.bank.query(local, ids[:, k].clamp(min=0), outside=False)
            occ |= hit & valid[:, None]
        return occ


def local_occupancy(scene: GridBank, to_world: torch.Tensor, spec: LocalGridSpec = LocalGridSpec(),
                    scene_index: torch.Tensor | int = 0, objects: DynamicObjects | None = None,
                    outside: bool = True) -> torch.Tensor:
    """Body-frame occupancy (B, Hy, Hx, Hz) bool for frames to_world (B, 4, 4) (local → world).

    scene_index (B,) picks each item's grid in `scene` (a TorchOccupancy has one).
    Out-of-grid samples get `outside`; dynamic objects are OR-ed in.
    """
    dev, dt = scene.device, scene.dtype
    T = to_world.to(dev, dt)
    B = T.shape[0]
    Hy, Hx, Hz = spec.out_shape
    local = torch.as_tensor(spec.points(), dtype=dt, device=dev)                         # (Hy, Hx, Hz, 3)
    if _is_yaw_only(T):
        # R_y keeps heights: the grid is (ground points) x (heights), looked up per axis.
        ground = local[0].reshape(-1, 3)[:, [0, 2]]                                      # (Hx*Hz, 2) local x, z
        R2 = T[:, [0, 2]][:, :, [0, 2]]                                                  # (B, 2, 2) xz block
        xz = ground @ R2.transpose(-1, -2) + T[:, None, [0, 2], 3]                       # (B, Hx*Hz, 2)
        y = local[:, 0, 0, 1] + T[:, 1:2, 3]                                             # (B, Hy)
        occ = scene.query_columns(xz, y, scene_index, outside)                           # (B, Hy, Hx*Hz)
        occ = occ.reshape(B, -1)
        world = None
    else:
        world = _to_world(T, local.reshape(-1, 3))
        # The batched base form, also when `scene` is a TorchOccupancy (whose query is per point).
        occ = GridBank.query(scene, world, scene_index, outside)                         # (B, V)
    if objects is not None:
        # Objects far from the body (most of them, most of the time) are skipped: their grid box
        # misses the local grid's box, and outside its grid an object is free.
        box = _to_world(T, torch.as_tensor(spec.corners(), dtype=dt, device=dev))       # (B, 8, 3)
        near = objects.overlaps(box.amin(1), box.amax(1))                               # (B, K)
        if bool(near.any()):
            occ |= objects.query(world if world is not None else _to_world(T, local.reshape(-1, 3)), near)
    return occ.reshape(B, Hy, Hx, Hz)


def _to_world(T: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """Points p (V, 3) under transforms T (B, 4, 4) -> (B, V, 3)."""
    return p @ T[:, :3, :3].transpose(-1, -2) + T[:, None, :3, 3]


YAW_TOL = 1e-6   # how far a frame's y axis may be from world y and still count as yaw-only


def _is_yaw_only(T: torch.Tensor) -> bool:
    """All rotations in T (B, 4, 4) are about y (the contract for body frames)."""
    e = torch.tensor([0.0, 1.0, 0.0], dtype=T.dtype, device=T.device)
    return bool(torch.all((T[:, 1, :3] - e).abs() < YAW_TOL) & torch.all((T[:, :3, 1] - e).abs() < YAW_TOL))


def local_occupancy_at(scene: GridBank, position, yaw, spec: LocalGridSpec = LocalGridSpec(), **kw) -> torch.Tensor:
    """`local_occupancy` for positions (B, 2)/(B, 3) and yaws (B,): (B, Hy, Hx, Hz) bool."""
    return local_occupancy(scene, frames_from_pose(position, yaw), spec, **kw)


def local_occupancy_np(grid: OccupancyGrid, to_world: np.ndarray, spec: LocalGridSpec = LocalGridSpec(),
                       objects: Sequence[tuple[OccupancyGrid, np.ndarray]] = (), outside: bool = True) -> np.ndarray:
    """One window on the CPU (DataLoader workers): to_world (4, 4) → (Hy, Hx, Hz) bool.

    objects: (object grid, pose (4, 4) object → world) pairs. Uses the memory-mapped grid
    directly, so workers share the page cache instead of copying grids. Training is bound by
    this function on small models, so per-spec constants are cached and objects are culled by
    their boxes before any per-point work.
    """
    T = np.asarray(to_world, np.float64)
    local = _spec_points(spec)                                                           # (Hy, Hx, Hz, 3)
    if _is_yaw_only_np(T):
        occ = _columns_np(grid, local, T, outside)
        world = None
    else:
        world = local @ T[:3, :3].T + T[:3, 3]                                           # (Hy, Hx, Hz, 3)
        occ = grid.occupied(world, outside=outside)
    if len(objects):
        to_local = invert_rigid(T)
        axes = _spec_axes(spec)                                                          # x (Hx,), y (Hy,), z (Hz,)
    for obj, pose in objects:
        pose = np.asarray(pose, np.float64)
        # Cull in the body frame: the object's box there bounds a block of the regular local
        # grid. Points of the block outside the object's grid read False (outside=False), so
        # any block containing the object gives the same answer as testing every point.
        M = to_local @ pose                                                              # object -> local
        c = obj.bounds[_CORNERS, _AXES] @ M[:3, :3].T + M[:3, 3]                         # (8, 3) local
        lo, hi = c.min(0) - _CULL_MARGIN, c.max(0) + _CULL_MARGIN
        (i0, i1), (j0, j1), (k0, k1) = (np.searchsorted(ax, [lo[d], hi[d]], side="left")
                                        for d, ax in enumerate(axes))
        if i0 >= i1 or j0 >= j1 or k0 >= k1:
            continue                       # small objects are usually nowhere near the window goal
        block = local[j0:j1, i0:i1, k0:k1]                                               # (hy, hx, hz, 3)
        world = block @ T[:3, :3].T + T[:3, 3]
        inv = invert_rigid(pose)
        hit = obj.occupied(world @ inv[:3, :3].T + inv[:3, 3], outside=False)           # (hy, hx, hz)
        occ[j0:j1, i0:i1, k0:k1] |= hit
    return occ


# Index arrays picking the 8 corners (8, 3) out of a (2, 3) [lo, hi] box: b[_CORNERS, _AXES].
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])        # (8, 3)
_AXES = np.arange(3)[None].repeat(8, 0)                                                 # (8, 3)
_CULL_MARGIN = 1e-6   # metres; rounding of the two transforms must not cut a point of the object


@lru_cache(maxsize=8)
def _spec_points(spec: LocalGridSpec) -> np.ndarray:
    """spec.points(), computed once per spec (read-only)."""
    p = spec.points()
    p.flags.writeable = False
    return p


@lru_cache(maxsize=8)
def _spec_axes(spec: LocalGridSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """spec.axes(), computed once per spec."""
    return spec.axes()


def _is_yaw_only_np(T: np.ndarray) -> bool:
    """numpy twin of `_is_yaw_only` for one (4, 4) frame (no tensor round trip in the workers)."""
    e = (0.0, 1.0, 0.0)
    return all(abs(T[1, i] - e[i]) < YAW_TOL and abs(T[i, 1] - e[i]) < YAW_TOL for i in range(3))


def _columns_np(grid: OccupancyGrid, local: np.ndarray, T: np.ndarray, outside: bool) -> np.ndarray:
    """numpy twin of `GridBank.query_columns` for one yaw-only frame: (Hy, Hx, Hz) bool.

    Same float64 arithmetic per axis as `OccupancyGrid.index_of`, so results match it exactly.
    """
    (ox, oy, oz), v, (X, Y, Z) = grid.origin, grid.voxel_size, grid.shape
    ground = local[0] @ T[:3, :3].T + T[:3, 3]                                           # (Hx, Hz, 3); y unused
    i = np.floor((ground[..., 0] - ox) / v).astype(np.int64)                             # (Hx, Hz)
    k = np.floor((ground[..., 2] - oz) / v).astype(np.int64)                             # (Hx, Hz)
    j = np.floor((local[:, 0, 0, 1] + T[1, 3] - oy) / v).astype(np.int64)                # (Hy,)
    in_xz = (i >= 0) & (i < X) & (k >= 0) & (k < Z)
    in_y = (j >= 0) & (j < Y)
    inside = in_y[:, None, None] & in_xz[None]                                           # (Hy, Hx, Hz)
    i, k, j = np.where(in_xz, i, 0), np.where(in_xz, k, 0), np.where(in_y, j, 0)
    byte = np.asarray(grid.bits)[i[None], j[:, None, None], (k >> 3)[None]]              # (Hy, Hx, Hz)
    bit = ((byte >> (7 - (k & 7))[None]) & 1).astype(bool)
    return np.where(inside, bit, outside)
