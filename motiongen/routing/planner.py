"""Collision-free polylines on a `WalkableMap`: the shortest 8-connected cell path (Dijkstra on
a sparse grid graph, built once per map and coarsening), then greedy line-of-sight shortening on
the fine map, so paths are short polylines rather than staircases."""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import dijkstra

from motiongen.routing.walkable import WalkableMap


def grid_graph(free: np.ndarray, squeeze: bool = False) -> sparse.csr_matrix:
    """Undirected 8-connected graph (X*Z, X*Z) over free cells (X, Z), edge weights 1 and √2.
    squeeze=False allows a diagonal move only when both cells beside it are free (no slipping
    between two blocked corners); squeeze=True only asks for its two ends to be free."""
    X, Z = free.shape
    idx = np.arange(X * Z).reshape(X, Z)
    rows, cols, w = [], [], []
    for di, dk in ((1, 0), (0, 1), (1, 1), (1, -1)):
        ia, ka = slice(max(0, -di), X - max(0, di)), slice(max(0, -dk), Z - max(0, dk))
        ib, kb = slice(max(0, di), X + min(0, di) or None), slice(max(0, dk), Z + min(0, dk) if dk < 0 else None)
        ok = free[ia, ka] & free[ib, kb]
        if di and dk and not squeeze:
            ok &= free[ib, ka] & free[ia, kb]          # the two orthogonal neighbours of the move
        u, v = idx[ia, ka][ok], idx[ib, kb][ok]
        rows += [u, v]
        cols += [v, u]
        w += [np.full(u.size, np.hypot(di, dk))] * 2
    return sparse.csr_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))), shape=(X * Z, X * Z))


def shortcut(path: np.ndarray, fmap: WalkableMap) -> np.ndarray:
    """Greedy line-of-sight shortening of a polyline (N, 2) -> (M, 2), M <= N, same ends."""
    out = [path[0]]
    i = 0
    while i < len(path) - 1:
        j = len(path) - 1
        while j > i + 1 and not fmap.segment_free(path[i], path[j]):
            j -= 1
        out.append(path[j])
        i = j
    return np.asarray(out)


def round_corners(pts: np.ndarray, iters: int = 3) -> np.ndarray:
    """Chaikin corner cutting with fixed end points: turns become arcs, not spins."""
    for _ in range(iters):
        if len(pts) < 3:
            break
        q = 0.75 * pts[:-1] + 0.25 * pts[1:]
        r = 0.25 * pts[:-1] + 0.75 * pts[1:]
        pts = np.concatenate([pts[:1], np.stack([q, r], 1).reshape(-1, 2)[1:-1], pts[-1:]])
    return pts


def _snap(fmap: WalkableMap, cfree: np.ndarray, origin: np.ndarray, cell: float, p: np.ndarray):
    """(cell index, whether p lies in it): the coarse cell containing p, or else the nearest free
    coarse cell reachable in a straight free line (p may sit in a partly blocked coarse cell near
    a wall), or (None, False)."""
    ik = tuple(np.clip(np.floor((p - origin) / cell).astype(int), 0, np.asarray(cfree.shape) - 1))
    if cfree[ik]:
        return ik, True
    cand = np.argwhere(cfree)
    if not len(cand):
        return None, False
    centres = origin + (cand + 0.5) * cell
    for o in np.argsort(np.linalg.norm(centres - p, axis=-1))[:64]:
        if fmap.segment_free(p, centres[o]):
            return tuple(cand[o]), False
    return None, False


def plan_path(fmap: WalkableMap, start, goal, plan_cell: float | None = None,
              squeeze: bool = False) -> np.ndarray | None:
    """A collision-free polyline (N, 2) from start to goal, or None when none exists.

    Plans on cells of `plan_cell` metres (default: the map's own; a coarse cell is free only if
    all of its fine cells are), then shortens the route by line of sight on the fine map. An end
    point in a blocked coarse cell is joined to the nearest free one it sees.
    """
    start, goal = np.asarray(start, np.float64), np.asarray(goal, np.float64)
    if fmap.segment_free(start, goal):
        return np.stack([start, goal])
    plan_cell = fmap.cell if plan_cell is None else plan_cell
    cfree, origin, cell = fmap.coarse(plan_cell)
    (s, s_in), (g, g_in) = _snap(fmap, cfree, origin, cell, start), _snap(fmap, cfree, origin, cell, goal)
    if s is None or g is None:
        return None
    graphs = fmap.graph_cache(plan_cell)
    if squeeze not in graphs:
        graphs[squeeze] = grid_graph(cfree, squeeze)
    si, gi = np.ravel_multi_index(s, cfree.shape), np.ravel_multi_index(g, cfree.shape)
    dist, pred = dijkstra(graphs[squeeze], indices=si, return_predecessors=True)
    if not np.isfinite(dist[gi]):
        return None
    chain = [gi]
    while chain[-1] != si:
        chain.append(pred[chain[-1]])
    cells = np.stack(np.unravel_index(np.array(chain[::-1]), cfree.shape), -1)              # (N, 2)
    # The end cells' centres add nothing when the end points lie in them.
    cells = cells[int(s_in): len(cells) - int(g_in)]
    mid = origin + (cells + 0.5) * cell
    return shortcut(np.concatenate([start[None], mid, goal[None]]), fmap)
