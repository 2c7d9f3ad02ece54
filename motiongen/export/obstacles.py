"""Obstacles for the video's panels: columns of the scene's occupancy (or of a walkable map's
blocked cells) on a coarse lattice, and the box faces that show them."""

from __future__ import annotations

import numpy as np


def obstacle_columns(walkable=None, grid=None, cell: float = 0.1) -> np.ndarray:
    """(N, 3) obstacle columns (x, z, top height) on a `cell`-metre lattice, from an
    OccupancyGrid (`grid`) or, lacking it, a WalkableMap's blocked cells (height 1 m)."""
    if grid is not None:
        dense = np.asarray(grid.dense())                                                     # (X, Y, Z)
        f = max(1, int(round(cell / grid.voxel_size)))
        X, Y, Z = dense.shape
        Xc, Zc = X // f, Z // f
        if Xc == 0 or Zc == 0:
            return np.zeros((0, 3))
        ys = grid.origin[1] + (np.arange(Y) + 1) * grid.voxel_size                          # (Y,) voxel tops
        occ = dense[:Xc * f, :, :Zc * f].reshape(Xc, f, Y, Zc, f).any(axis=(1, 4))          # (Xc, Y, Zc)
        occ[:, ys <= 0.02, :] = False                                                       # ignore a floor slab
        top = np.where(occ.any(1), ys[np.argmax(np.where(occ, np.arange(Y)[None, :, None], -1), axis=1)], 0.0)
        i, k = np.nonzero(occ.any(1))
        x = grid.origin[0] + (i + 0.5) * f * grid.voxel_size
        z = grid.origin[2] + (k + 0.5) * f * grid.voxel_size
        return np.stack([x, z, top[i, k]], -1)
    if walkable is not None:
        f = max(1, int(round(cell / walkable.cell)))
        X, Z = walkable.open.shape
        blocked = ~walkable.open[: X // f * f, : Z // f * f].reshape(X // f, f, Z // f, f).all(axis=(1, 3))
        i, k = np.nonzero(blocked)
        return np.stack([walkable.origin[0] + (i + 0.5) * f * walkable.cell,
                         walkable.origin[1] + (k + 0.5) * f * walkable.cell, np.ones(len(i))], -1)
    return np.zeros((0, 3))


def obstacle_faces(columns: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Box faces of obstacle columns (N, 3) (x, z, top) on a `cell` lattice: the top of every
    column and the sides not hidden by an equally tall neighbour.
    Returns corners (F, 4, 3), outward normals (F, 3) and a brightness (F,) for flat shading."""
    if not len(columns):
        return np.zeros((0, 4, 3)), np.zeros((0, 3)), np.zeros(0)
    h = cell / 2
    key = {(round(x / cell), round(z / cell)): top for x, z, top in columns}
    corners, normals, shade = [], [], []
    for x, z, top in columns:
        corners.append([[x - h, top, z - h], [x + h, top, z - h], [x + h, top, z + h], [x - h, top, z + h]])
        normals.append([0.0, 1.0, 0.0])
        shade.append(1.0)
        i, k = round(x / cell), round(z / cell)
        for (di, dk), quad, lum in (((1, 0), [[x + h, 0, z - h], [x + h, 0, z + h], [x + h, top, z + h], [x + h, top, z - h]], 0.72),
                                    ((-1, 0), [[x - h, 0, z - h], [x - h, 0, z + h], [x - h, top, z + h], [x - h, top, z - h]], 0.72),
                                    ((0, 1), [[x - h, 0, z + h], [x + h, 0, z + h], [x + h, top, z + h], [x - h, top, z + h]], 0.85),
                                    ((0, -1), [[x - h, 0, z - h], [x + h, 0, z - h], [x + h, top, z - h], [x - h, top, z - h]], 0.85)):
            if key.get((i + di, k + dk), 0.0) < top:                       # exposed side
                corners.append(quad)
                normals.append([di, 0.0, dk])
                shade.append(lum)
    return np.asarray(corners, np.float64), np.asarray(normals, np.float64), np.asarray(shade)


def quad_triangles(quads: np.ndarray) -> np.ndarray:
    """The quads (F, 4, 3) of `obstacle_faces` split into triangles (2F, 3, 3) (for OpenGL)."""
    return np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]) if len(quads) else np.zeros((0, 3, 3))
