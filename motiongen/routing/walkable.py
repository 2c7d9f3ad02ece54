"""Walkable floor: free (x, z) cells at a fixed cell size, with a body-radius clearance, so a
body can be planned as a point. Points are world (x, z) metres (y-up)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.ndimage as ndi


@dataclass
class WalkableMap:
    """Free floor cells. `free` (X, Z) bool at `cell` metres, cell (i, k) covering
    [origin + (i, k) * cell, origin + (i+1, k+1) * cell). `free` already excludes cells within
    `body_radius` of an obstacle; `open` is the same without that margin (raw obstacles)."""

    free: np.ndarray             # (X, Z) bool, clearance applied
    open: np.ndarray             # (X, Z) bool, no clearance
    origin: np.ndarray           # (2,) float64 world x, z of cell (0, 0)'s min corner
    cell: float
    body_radius: float = 0.0
    # Per coarsening factor f: (coarse free map, its sparse graphs by squeeze flag), built lazily.
    _coarse: dict = field(default_factory=dict, repr=False)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 2): [[x_min, z_min], [x_max, z_max]]."""
        return np.stack([self.origin, self.origin + np.asarray(self.free.shape) * self.cell])

    def in_bounds(self, xz) -> np.ndarray:
        xz = np.asarray(xz, np.float64)
        lo, hi = self.bounds
        return np.all((xz >= lo) & (xz < hi), axis=-1)

    def _cells(self, xz) -> tuple[np.ndarray, np.ndarray]:
        ik = np.floor((np.asarray(xz, np.float64) - self.origin) / self.cell).astype(np.int64)   # (..., 2)
        inside = np.all((ik >= 0) & (ik < np.asarray(self.free.shape)), axis=-1)
        return np.where(inside[..., None], ik, 0), inside

    def centres(self, cells) -> np.ndarray:
        """(..., 2) world centres of cells (..., 2) int."""
        return self.origin + (np.asarray(cells, np.float64) + 0.5) * self.cell

    def is_free(self, xz, clearance: bool = True) -> np.ndarray:
        """(...,) bool for points (..., 2); outside the map is not free."""
        ik, inside = self._cells(xz)
        m = self.free if clearance else self.open
        return inside & m[ik[..., 0], ik[..., 1]]

    def segment_free(self, a, b, clearance: bool = True) -> bool:
        """Every point of segment a-b (2,) lies on free floor (sampled at half a cell)."""
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        n = max(2, int(math.ceil(np.linalg.norm(b - a) / (0.5 * self.cell))) + 1)
        pts = np.linspace(a, b, n)                                                           # (n, 2)
        return bool(self.is_free(pts, clearance).all())

    def nearest_free(self, xz, max_dist: float = math.inf) -> np.ndarray | None:
        """The free cell centre (2,) nearest to xz, or None if none lies within max_dist."""
        ik, inside = self._cells(xz)
        if inside and self.free[ik[0], ik[1]]:
            return np.asarray(xz, np.float64)
        if not self.free.any():
            return None
        centres = self.centres(np.argwhere(self.free))                                      # (N, 2)
        d = np.linalg.norm(centres - np.asarray(xz, np.float64), axis=-1)
        i = int(np.argmin(d))
        return centres[i] if d[i] <= max_dist else None

    def coarse(self, cell: float) -> tuple[np.ndarray, np.ndarray, float]:
        """(free (Xc, Zc) bool, origin (2,), cell size): blocks of fine cells, free iff all are."""
        f = max(1, int(round(cell / self.cell)))
        if f not in self._coarse:
            X, Z = self.free.shape
            Xc, Zc = -(-X // f), -(-Z // f)
            pad = np.zeros((Xc * f, Zc * f), bool)
            pad[:X, :Z] = self.free
            self._coarse[f] = (pad.reshape(Xc, f, Zc, f).all(axis=(1, 3)), {})            # (Xc, Zc)
        return self._coarse[f][0], self.origin.copy(), self.cell * f

    def graph_cache(self, cell: float) -> dict:
        """The dict in which the planner keeps this coarsening's graphs."""
        self.coarse(cell)
        return self._coarse[max(1, int(round(cell / self.cell)))][1]



def open_floor(grid, body_height: tuple[float, float] = (0.1, 1.7),
               floor_y: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """The ground cells of an OccupancyGrid a body fits over: open (X, Z) bool, origin_xz (2,)
    (min corner of cell (0, 0)), cell size. A cell is open when no voxel whose centre lies
    between floor_y + body_height[0] and floor_y + body_height[1] is occupied; heights the grid
    does not cover count as open."""
    lo, hi = floor_y + body_height[0], floor_y + body_height[1]
    centres_y = grid.origin[1] + (np.arange(grid.shape[1]) + 0.5) * grid.voxel_size      # (Y,)
    rows = np.flatnonzero((centres_y >= lo) & (centres_y <= hi))
    blocked = np.zeros((grid.shape[0], grid.shape[2]), bool)                              # (X, Z)
    bits = np.asarray(grid.bits)
    for j in rows:  # one height slice at a time: never unpacks the whole grid
        blocked |= np.unpackbits(bits[:, j, :], axis=1, count=grid.shape[2], bitorder="big").astype(bool)
    return ~blocked, grid.origin[[0, 2]].copy(), float(grid.voxel_size)


def walkable_map(grid, body_radius: float = 0.25, body_height: tuple[float, float] = (0.1, 1.7),
                 floor_y: float = 0.0) -> WalkableMap:
    """The walkable map of an OccupancyGrid: free where nothing occupies the body's height band,
    and (for `free`) farther than `body_radius` from anything that does."""
    open_, origin, cell = open_floor(grid, tuple(body_height), floor_y)
    if body_radius > 0:
        # Distance transform instead of a disk dilation: O(cells) whatever the radius.
        dist = ndi.distance_transform_edt(open_) * cell                                      # to nearest blocked cell
        free = open_ & (dist > body_radius)
    else:
        free = open_.copy()
    # The map's border touches space the grid does not cover (walls or nothing): keep the
    # body off it too.
    r = int(math.ceil(body_radius / cell))
    if r > 0:
        free[:r], free[-r:], free[:, :r], free[:, -r:] = False, False, False, False
    return WalkableMap(free, open_, np.asarray(origin, np.float64), float(cell), float(body_radius))


def walkable_from_boxes(boxes: np.ndarray, size: tuple[float, float], cell: float, body_radius: float) -> WalkableMap:
    """The walkable map of a W x D room centred on the origin whose obstacles are boxes
    (B, 2, 3) [min corner, max corner]: free farther than `body_radius` from every box, and only
    the largest 8-connected free region (so any two free points are connected)."""
    W, D = size
    origin = np.array([-W / 2, -D / 2])
    shape = (int(round(W / cell)), int(round(D / cell)))
    blocked = np.zeros(shape, bool)                                                          # (X, Z)
    lo = np.floor((boxes[:, 0, [0, 2]] - origin) / cell + 1e-6).astype(int)
    hi = np.ceil((boxes[:, 1, [0, 2]] - origin) / cell - 1e-6).astype(int)
    for (i0, k0), (i1, k1) in zip(lo, hi):
        blocked[max(i0, 0):i1, max(k0, 0):k1] = True
    free = ndi.distance_transform_edt(~blocked) * cell > body_radius
    labels, n = ndi.label(free, structure=np.ones((3, 3)))
    if n:
        sizes = ndi.sum(free, labels, range(1, n + 1))
        free = labels == (int(np.argmax(sizes)) + 1)
    return WalkableMap(free, ~blocked, origin, float(cell), float(body_radius))
