"""Walkable floor and collision-free walking paths: a 2-D free-space map from the scene's
boxes dilated by a body radius, Dijkstra on its 8-connected cells, line-of-sight shortcuts and
corner rounding, then a root trajectory with a smooth speed profile and facing along the path.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse.csgraph import dijkstra

CELL = 0.05         # m
BODY_RADIUS = 0.3   # keep the pelvis this far from furniture and walls while walking


def minjerk(u):
    u = np.clip(u, 0.0, 1.0)
    return u ** 3 * (10 - 15 * u + 6 * u ** 2)


class FloorMap:
    def __init__(self, boxes: np.ndarray, size: tuple[float, float], radius: float = BODY_RADIUS):
        W, D = size
        self.origin = np.array([-W / 2, -D / 2])
        self.shape = (int(round(W / CELL)), int(round(D / CELL)))
        blocked = np.zeros(self.shape, bool)   # (X, Z)
        lo = np.floor((boxes[:, 0, [0, 2]] - self.origin) / CELL + 1e-6).astype(int)
        hi = np.ceil((boxes[:, 1, [0, 2]] - self.origin) / CELL - 1e-6).astype(int)
        for (i0, k0), (i1, k1) in zip(lo, hi):
            blocked[max(i0, 0):i1, max(k0, 0):k1] = True
        free = ndimage.distance_transform_edt(~blocked) * CELL > radius
        labels, n = ndimage.label(free, structure=np.ones((3, 3)))
        sizes = ndimage.sum(free, labels, range(1, n + 1)) if n else np.zeros(0)
        self.free = labels == (int(np.argmax(sizes)) + 1) if n else free  # largest component only
        self.graph = self._graph()

    def _graph(self) -> sparse.csr_matrix:
        X, Z = self.shape
        idx = np.arange(X * Z).reshape(X, Z)
        rows, cols, w = [], [], []
        for di, dk in ((1, 0), (0, 1), (1, 1), (1, -1)):
            ia, ka = slice(max(0, -di), X - max(0, di)), slice(max(0, -dk), Z - max(0, dk))
            ib, kb = slice(max(0, di), X + min(0, di) or None), slice(max(0, dk), Z + min(0, dk) if dk < 0 else None)
            ok = self.free[ia, ka] & self.free[ib, kb]
            u, v = idx[ia, ka][ok], idx[ib, kb][ok]
            rows += [u, v]
            cols += [v, u]
            w += [np.full(u.size, np.hypot(di, dk))] * 2
        return sparse.csr_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))), shape=(X * Z, X * Z))

    def cell(self, xz: np.ndarray) -> tuple[int, int]:
        i, k = np.floor((np.asarray(xz) - self.origin) / CELL).astype(int)
        return int(i), int(k)

    def is_free(self, xz: np.ndarray) -> bool:
        i, k = self.cell(xz)
        return 0 <= i < self.shape[0] and 0 <= k < self.shape[1] and bool(self.free[i, k])

    def centre(self, i, k) -> np.ndarray:
        return self.origin + (np.stack([i, k], -1) + 0.5) * CELL

    def random_free(self, rng, away_from: np.ndarray | None = None, min_dist: float = 0.0) -> np.ndarray | None:
        cells = np.argwhere(self.free)
        if away_from is not None:
            cells = cells[np.linalg.norm(self.centre(cells[:, 0], cells[:, 1]) - away_from, axis=1) >= min_dist]
        if len(cells) == 0:
            return None
        i, k = cells[int(rng.integers(len(cells)))]
        return self.centre(i, k)

    def line_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        n = int(np.ceil(np.linalg.norm(b - a) / (CELL / 2))) + 1
        return all(self.is_free(p) for p in np.linspace(a, b, n))

    def plan(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """A smooth polyline (P, 2) from start to goal through free space, or None."""
        if not (self.is_free(start) and self.is_free(goal)):
            return None
        Z = self.shape[1]
        s, g = np.ravel_multi_index(self.cell(start), self.shape), np.ravel_multi_index(self.cell(goal), self.shape)
        dist, pred = dijkstra(self.graph, indices=s, return_predecessors=True, limit=np.inf)
        if not np.isfinite(dist[g]):
            return None
        chain = [g]
        while chain[-1] != s:
            chain.append(pred[chain[-1]])
        cells = np.array(chain[::-1])
        pts = np.concatenate([[start], self.centre(cells // Z, cells % Z)[1:-1], [goal]])
        return _round_corners(self._shortcut(pts))

    def _shortcut(self, pts: np.ndarray) -> np.ndarray:
        """Greedy line-of-sight string pulling."""
        out, i = [pts[0]], 0
        while i < len(pts) - 1:
            j = len(pts) - 1
            while j > i + 1 and not self.line_free(pts[i], pts[j]):
                j -= 1
            out.append(pts[j])
            i = j
        return np.array(out)


def _round_corners(pts: np.ndarray, iters: int = 3) -> np.ndarray:
    """Chaikin corner cutting with fixed end points: turns become arcs, not spins."""
    for _ in range(iters):
        if len(pts) < 3:
            break
        q = 0.75 * pts[:-1] + 0.25 * pts[1:]
        r = 0.25 * pts[:-1] + 0.75 * pts[1:]
        pts = np.concatenate([pts[:1], np.stack([q, r], 1).reshape(-1, 2)[1:-1], pts[-1:]])
    return pts


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def path_trajectory(path: np.ndarray, yaw0: float, speed: float, fps: float, ramp_s: float = 0.8):
    """Root (x, z) (T, 2) and yaw (T,) walking `path` (P, 2) from rest to rest.

    Speed rises and falls with minimum-jerk ramps; facing follows the path tangent, blended in
    from `yaw0` while the walker sets off. Frame 0 is the start."""
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    length = arc[-1]
    ta = min(ramp_s, length / speed)
    total = length / speed + ta
    n = int(np.ceil(total * fps)) + 1
    t = np.arange(n) / fps
    vel = speed * np.minimum(minjerk(t / ta), minjerk((total - t) / ta))
    s = np.concatenate([[0.0], np.cumsum((vel[1:] + vel[:-1]) / 2) / fps])
    s *= length / max(s[-1], 1e-9)
    xz = np.stack([np.interp(s, arc, path[:, 0]), np.interp(s, arc, path[:, 1])], -1)
    # Tangent yaw on a fine resampling, smoothed so corners read as turns, not snaps.
    fine = np.linspace(0, length, max(int(length / 0.01), 2))
    fx, fz = np.interp(fine, arc, path[:, 0]), np.interp(fine, arc, path[:, 1])
    tang = np.unwrap(np.arctan2(np.gradient(fx), np.gradient(fz)))
    tang = ndimage.gaussian_filter1d(tang, sigma=15, mode="nearest")
    yaw_path = np.interp(s, fine, tang)
    d0 = wrap(yaw_path[0] - yaw0)
    blend = minjerk(t / (0.3 + abs(d0) / np.pi))
    yaw = yaw0 + d0 * blend + (yaw_path - yaw_path[0])
    return xz, yaw


def turn_trajectory(xz: np.ndarray, yaw0: float, yaw1: float, fps: float):
    """Turn on the spot from yaw0 to the nearest equivalent of yaw1: (T, 2), (T,)."""
    d = wrap(yaw1 - yaw0)
    n = int(np.ceil((0.4 + abs(d) / np.pi * 1.2) * fps)) + 1
    u = np.arange(n) / (n - 1)
    return np.repeat(np.asarray(xz, float)[None], n, 0), yaw0 + d * minjerk(u)
