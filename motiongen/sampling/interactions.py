"""Interactions the sampler makes happen on the body: a hand on the object it picks up, a
pelvis at the height of the seat or bed it sits or lies on."""

from __future__ import annotations

import numpy as np

from motiongen.skeleton import BODY_JOINT_NAMES, FOOT_JOINTS, HAND_JOINTS, PELVIS
from motiongen.spans import ramp_weights, true_runs


def object_points(objects) -> list[np.ndarray]:
    """World points (N_k, 3) of each placed object [(OccupancyGrid, pose (4, 4))]: its occupied
    voxel centres."""
    out = []
    for grid, pose in objects:
        local = grid.origin + (np.argwhere(np.asarray(grid.dense())) + 0.5) * grid.voxel_size     # (N, 3)
        pose = np.asarray(pose, np.float64)
        out.append(local @ pose[:3, :3].T + pose[:3, 3])
    return out


def reach_targets(joints: np.ndarray, labels: np.ndarray, action: int, hands, points: list[np.ndarray],
                  scene=None, palm: float = 0.03, ramp: int = 8, max_dist: float = 0.5):
    """Where a hand must be for each run of frames labelled `action` (a hand interaction):
    joints (T, J, 3) the motion so far, labels (T,) action index per frame, hands: joint indices
    to choose from (wrists), points: the objects' surface points, scene: the OccupancyGrid the
    hand must stay out of (or None). Per run: the hand closest to an object, and the wrist
    position `palm` metres out from the object surface (the wrist joint sits that far from the
    palm's skin) that is nearest that hand and not inside the furniture the object stands on.
    Weights ramp in and out over `ramp` frames so the reach is a movement, not a jump. A hand
    farther than `max_dist` from every object is left alone: pulling it there would drag the
    whole body. Returns (frames, joints, points, weights) or None when nothing is in reach."""
    if not points:
        return None
    frames, js, ps, ws = [], [], [], []
    allp = np.concatenate(points)                                                         # (N, 3)
    centre = allp.mean(0)
    # Wrist candidates: every surface point pushed out from the objects' middle by `palm`.
    out_dir = allp - centre
    out_dir /= np.maximum(np.linalg.norm(out_dir, axis=-1, keepdims=True), 1e-9)
    cand = allp + palm * out_dir                                                           # (N, 3)
    if scene is not None:
        free = ~scene.occupied(cand, outside=False)
        cand = cand[free] if free.any() else cand
    for a, b in true_runs(labels == action):
        best = None
        for h in hands:
            mean = joints[a:b, h].mean(0)                                                  # (3,)
            d = np.linalg.norm(cand - mean, axis=-1)
            i = int(np.argmin(d))
            if best is None or d[i] < best[0]:
                best = (d[i], h, cand[i])
        dist, h, target = best
        if dist > max_dist:
            continue
        n = b - a
        w = ramp_weights(n, ramp)
        frames.append(np.arange(a, b)), js.append(np.full(n, h)), ps.append(np.repeat(target[None], n, 0))
        ws.append(w)
    if not frames:
        return None
    return np.concatenate(frames), np.concatenate(js), np.concatenate(ps), np.concatenate(ws)


def hand_targets(joints: np.ndarray, labels: np.ndarray, names, hand_actions, objects, scene=None) -> list | None:
    """Per sample, the hand targets of the frames labelled with a hand action (None: none)."""
    acts = [names.index(a) for a in hand_actions if a in names]
    if not acts or not objects:
        return None
    pts = object_points(objects)
    out = []
    for s in range(joints.shape[0]):
        parts = [r for a in acts if (r := reach_targets(joints[s], labels[s], a, HAND_JOINTS, pts, scene)) is not None]
        out.append(merge_targets(*parts))
    return out


def seat_height(grid, xz, radius: float = 0.1, max_height: float = 1.0) -> float:
    """Top (m) of the furniture under a ground point: the highest occupied voxel below
    `max_height` within `radius` of xz; NaN over bare floor (nothing to sit on)."""
    r = np.arange(-radius, radius + 1e-9, grid.voxel_size)
    ys = np.arange(grid.voxel_size / 2, max_height, grid.voxel_size)
    dx, dz, y = np.meshgrid(r, r, ys, indexing="ij")
    keep = dx ** 2 + dz ** 2 <= radius ** 2
    pts = np.stack([xz[0] + dx[keep], y[keep], xz[1] + dz[keep]], -1)                     # (N, 3)
    occ = grid.occupied(pts, outside=False)
    return float(pts[occ, 1].max() + grid.voxel_size / 2) if occ.any() else float("nan")


def seat_shift(joints: np.ndarray, labels: np.ndarray, actions: dict, targets: list, ramp: int = 8):
    """Put a seated or lying body on its furniture: joints (T, J, 3) of one sample, labels (T,)
    action index per frame, actions {action index: [goal index, ...]}, targets (G, 3) the
    pelvis targets (goal x, seat height, goal z; NaN rows: none). Per run of frames labelled
    with a seat action, the trunk, arms and head move by the offset from the run's median
    pelvis to the nearest target (ramped in and out over `ramp` frames), the knees by half,
    the feet not at all: the legs bend between a body on the seat and feet on the floor, which
    the final solve then makes one body, with the pelvis held at the target (the returned
    reach targets). Returns (moved joints (a copy), (frames, joints, points, weights) or None)."""
    out = np.array(joints, np.float64)
    frames, points, ws = [], [], []
    if not actions:
        return out, None
    knees = [i for i, n in enumerate(BODY_JOINT_NAMES) if n.endswith("_knee")]
    weight = np.ones(out.shape[1])
    weight[list(FOOT_JOINTS)] = 0.0
    weight[knees] = 0.5
    for a, goals in actions.items():
        tg = np.asarray([targets[g] for g in goals], np.float64)                            # (K, 3)
        for s, e in true_runs(labels == a):
            mid = np.median(out[s:e, PELVIS], axis=0)                                        # (3,)
            d = np.linalg.norm((tg - mid)[:, [0, 2]], axis=-1)
            if not np.isfinite(d).any():
                continue
            offset = tg[int(np.nanargmin(d))] - mid                                          # (3,)
            w = ramp_weights(e - s, ramp)                                                     # (n,)
            out[s:e] += w[:, None, None] * weight[None, :, None] * offset
            frames.append(np.arange(s, e)), points.append(out[s:e, PELVIS]), ws.append(w)
    if not frames:
        return out, None
    f = np.concatenate(frames)
    return out, (f, np.full(len(f), PELVIS), np.concatenate(points), np.concatenate(ws))


def merge_targets(*parts):
    """One (frames, joints, points, weights) tuple from several (None: skipped), or None."""
    parts = [p for p in parts if p is not None]
    return tuple(np.concatenate(x) for x in zip(*parts)) if parts else None
