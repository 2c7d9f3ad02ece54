"""Walking paths for the generator: the room's walkable floor and collision-free paths on it
(`motiongen.routing`, the planner the sampler uses too), then a root trajectory with a smooth
speed profile and facing along the path.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from motiongen.routing import WalkableMap, plan_path, round_corners, walkable_from_boxes

CELL = 0.05         # m
BODY_RADIUS = 0.3   # keep the pelvis this far from furniture and walls while walking


def minjerk(u):
    u = np.clip(u, 0.0, 1.0)
    return u ** 3 * (10 - 15 * u + 6 * u ** 2)


def walkable_room(boxes: np.ndarray, size: tuple[float, float]) -> WalkableMap:
    """The room's walkable floor for the pelvis (largest connected region only)."""
    return walkable_from_boxes(boxes, size, CELL, BODY_RADIUS)


def random_free(fmap: WalkableMap, rng, away_from: np.ndarray | None = None, min_dist: float = 0.0) -> np.ndarray | None:
    """A random free cell centre (2,), at least `min_dist` from `away_from`, or None."""
    cells = np.argwhere(fmap.free)
    if away_from is not None:
        cells = cells[np.linalg.norm(fmap.centres(cells) - away_from, axis=1) >= min_dist]
    if len(cells) == 0:
        return None
    return fmap.centres(cells[int(rng.integers(len(cells)))])


def plan_walk(fmap: WalkableMap, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
    """A smooth polyline (P, 2) from start to goal through free space, or None. Diagonal steps
    may pass between two blocked corners (`squeeze`): the 0.3 m clearance already keeps the
    pelvis off them, and it is what the cached datasets were generated with."""
    if not (fmap.is_free(start) and fmap.is_free(goal)):
        return None
    path = plan_path(fmap, start, goal, squeeze=True)
    return None if path is None else round_corners(path)


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
