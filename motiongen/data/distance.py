"""Distance to the occupied surface of an occupancy grid: the one distance field that metrics,
the evaluation protocol and sampling use (`OccupancyGrid.surface_distance()` builds it once per
grid and keeps it)."""

from __future__ import annotations

import numpy as np
import scipy.ndimage as ndi
from scipy.spatial import cKDTree

_FAR = 1e3   # an empty (or full) grid has no surface: 1 km stands in for "infinitely far"


class SurfaceDistance:
    """Signed distance (m) to the occupied surface: positive in free space, negative inside.

    Built from two KD-trees: the centres of occupied voxels with a free 6-neighbour, and of free
    voxels with an occupied one. A free point's distance is its distance to the nearest occupied
    surface voxel's centre less half a voxel (the surface lies between the two kinds), an
    occupied point's depth the same to the nearest free one; accurate to about half a voxel.
    Cheaper to build than distance transforms of the whole grid (about 8x on a room) and exact
    off the grid too: points outside the grid are free and get their distance to the nearest
    surface voxel. `floor_y`: also treat the half-space y < floor_y as solid (the floor of a
    grid that starts above it, or a scene without a floor voxel layer).
    """

    def __init__(self, grid, floor_y: float | None = None):
        occ = grid.dense()                                                                   # (X, Y, Z) bool
        self.grid, self.floor_y, vs = grid, floor_y, grid.voxel_size

        def centres(m):
            return grid.origin + (np.argwhere(m) + 0.5) * vs                                 # (N, 3)

        surf = occ & ~ndi.binary_erosion(occ, border_value=0)        # the grid's outside counts as free
        fsurf = ~occ & ~ndi.binary_erosion(~occ, border_value=1)
        self._occ = cKDTree(centres(surf)) if surf.any() else None
        self._free = cKDTree(centres(fsurf)) if fsurf.any() else None
        self._half = 0.5 * vs

    def with_floor(self, floor_y: float) -> "SurfaceDistance":
        """The same field with the floor half-space y < floor_y added (shares the trees)."""
        out = object.__new__(SurfaceDistance)
        out.__dict__.update(self.__dict__, floor_y=floor_y)
        return out

    def __call__(self, points) -> np.ndarray:
        """(...,) signed distances at points (..., 3)."""
        p = np.asarray(points, np.float64)
        flat = p.reshape(-1, 3)
        inside = self.grid.occupied(flat, outside=False)                                     # (N,)
        d = np.full(len(flat), _FAR)
        if self._occ is not None and (~inside).any():
            d[~inside] = np.maximum(self._occ.query(flat[~inside])[0] - self._half, 0.0)
        if inside.any():
            depth = self._free.query(flat[inside])[0] - self._half if self._free is not None else _FAR
            d[inside] = -np.maximum(depth, 0.0)
        if self.floor_y is not None:
            d = np.minimum(d, flat[:, 1] - self.floor_y)
        return d.reshape(p.shape[:-1])
