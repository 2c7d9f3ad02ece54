"""Interactions the sampler makes happen on the body: a hand on the object it picks up, a
pelvis at the height of the seat or bed it sits or lies on."""

from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from motiongen.skeleton import BODY_JOINT_NAMES, BODY_PARENTS, FOOT_JOINTS, HAND_JOINTS, PELVIS
from motiongen.spans import ramp_weights, true_runs

# Every voxel face, edge and corner direction: (26, 3) in {-1, 0, 1}^3 less the zero vector.
_DIRECTIONS = np.array([d for d in itertools.product((-1, 0, 1), repeat=3) if any(d)], np.int64)
# A wrist candidate may sit this much (m) nearer an object than `palm`: floating-point slack only,
# so a candidate pushed out from one object but too close to another one's voxels is dropped.
_CLEARANCE_TOL = 1e-3
# Voxels looked at per candidate when measuring its distance to the objects: the nearest voxel
# box is among the nearest few voxel centres (a box's distance and its centre's differ by at
# most half a voxel diagonal).
_NEAREST = 16
# The hand beyond the wrist joint, as points along the forearm's direction (m): a flat SMPL-X
# hand reaches about 0.19 m from the wrist to the middle fingertip. Without a finger joint the
# solve leaves the hand in line with the forearm, so a wrist target whose hand would lie inside
# an object is no target: the fingers would be in the object (measured on the body mesh,
# docs/evaluation.md).
HAND_SPAN = (0.06, 0.12, 0.18)
# How far (m) those points must stay out of every object.
FINGER_CLEARANCE = 0.01
# How far (m) a wrist may be from the object when an episode gives it the hand goal: an arm's
# length and a lean from where the body stands at the goal (an object on the floor is ~0.8 m
# below a standing wrist); farther, the goal would pull the body off its pelvis target.
HAND_GOAL_REACH = 1.0


class ObjectSurface(NamedTuple):
    """One placed object's geometry as `wrist_candidates` needs it, in world coordinates."""

    skin: np.ndarray       # (M, 3) points on the object's surface: a surface voxel's face centre, edge or corner
    normals: np.ndarray    # (M, 3) unit outward normal at each skin point
    centres: np.ndarray    # (N, 3) every occupied voxel centre (the solid, for the clearance test)
    rot: np.ndarray        # (3, 3) object-to-world rotation: voxel boxes are axis-aligned in the object frame
    half: float            # half the voxel size (m)


def surface_directions(occ: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The outward directions of a solid's surface voxels: occ (X, Y, Z) bool -> (voxel index
    (M, 3), direction (M, 3) in {-1, 0, 1}). A voxel's direction has +1 on an axis whose + neighbour
    is free, -1 where the - neighbour is, 0 where neither is: the sum of its free 6-neighbour
    directions. Where both neighbours on an axis are free (a wall one voxel thin) their sum
    would cancel, so the voxel gets one direction per side instead; the grid's outside is free."""
    pad = np.pad(np.asarray(occ, bool), 1)
    core = (slice(1, -1),) * 3
    free_pos = [~np.roll(pad, -1, a)[core] for a in range(3)]                    # 3 x (X, Y, Z)
    free_neg = [~np.roll(pad, 1, a)[core] for a in range(3)]
    ijk, dirs = [], []
    for d in _DIRECTIONS:
        m = pad[core].copy()
        for a in range(3):
            m &= free_pos[a] if d[a] > 0 else free_neg[a] if d[a] < 0 else ~(free_pos[a] | free_neg[a])
        idx = np.argwhere(m)
        ijk.append(idx), dirs.append(np.broadcast_to(d, idx.shape))
    return np.concatenate(ijk), np.concatenate(dirs)


def object_surfaces(objects) -> list[ObjectSurface]:
    """Each placed object [(OccupancyGrid, pose (4, 4))] as an ObjectSurface."""
    out = []
    for grid, pose in objects:
        pose = np.asarray(pose, np.float64)
        rot, shift, h = pose[:3, :3], pose[:3, 3], grid.voxel_size / 2
        occ = np.asarray(grid.dense(), bool)
        ijk, d = surface_directions(occ)                                              # (M, 3) x 2
        # The skin point is where the direction leaves the voxel's box: the face centre, edge
        # midpoint or corner, so a wrist `palm` out along the normal is `palm` from this voxel.
        skin = grid.origin + (ijk + 0.5) * grid.voxel_size + h * d                    # (M, 3) local
        normals = d / np.linalg.norm(d, axis=-1, keepdims=True)                       # (M, 3) local
        out.append(ObjectSurface(skin @ rot.T + shift, normals @ rot.T, object_centres(grid, pose, occ), rot, h))
    return out


def object_centres(grid, pose, occ: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) world centres of a placed object's occupied voxels: its grid (OccupancyGrid) at
    `pose` (4, 4); occ: the grid's dense occupancy where the caller has it already."""
    pose = np.asarray(pose, np.float64)
    occ = np.asarray(grid.dense(), bool) if occ is None else occ
    return (grid.origin + (np.argwhere(occ) + 0.5) * grid.voxel_size) @ pose[:3, :3].T + pose[:3, 3]


def object_toward(xz, objects, max_dist: float = HAND_GOAL_REACH) -> np.ndarray | None:
    """(2,) the x, z centre of the placed object [(OccupancyGrid, pose)] whose voxels come
    nearest to the floor point xz (2,) across the floor, if within `max_dist`; else None: what
    a hand action at xz would be done to (a goal's `toward`, `goals.approach_leg`)."""
    best, out = max_dist, None
    for grid, pose in objects:
        floor = object_centres(grid, pose)[:, [0, 2]]                                # (N, 2)
        if not len(floor):
            continue
        d = float(np.min(np.linalg.norm(floor - np.asarray(xz, np.float64), axis=-1)))
        if d <= best:
            best, out = d, floor.mean(0)
    return out


def aim_at_objects(goals, objects, actions) -> None:
    """Give each goal whose action is one of `actions` (done with a hand: `loop.hand_actions`)
    and that has none the object it is done to (`object_toward`) as its `toward`, in place:
    what `approach=` walks at (`sample`, `serve`)."""
    for g in goals:
        if g.action in actions and g.toward is None:
            g.toward = object_toward(g.xz, objects)


def object_distance(points: np.ndarray, surfaces: list[ObjectSurface]) -> np.ndarray:
    """Distance (M,) of points (M, 3) to the nearest voxel box of any object (0 inside one)."""
    centres = np.concatenate([s.centres for s in surfaces])                          # (N, 3)
    owner = np.repeat(np.arange(len(surfaces)), [len(s.centres) for s in surfaces])   # (N,)
    rots = np.stack([s.rot for s in surfaces])                                        # (K, 3, 3)
    halves = np.array([s.half for s in surfaces])                                     # (K,)
    k = min(_NEAREST, len(centres))
    _, idx = cKDTree(centres).query(points, k=k)
    idx = idx.reshape(len(points), k)                                                 # (M, k)
    # The offset in each voxel's object frame, where its box is axis-aligned.
    local = np.einsum("mkji,mkj->mki", rots[owner[idx]], points[:, None] - centres[idx])   # (M, k, 3)
    gap = np.maximum(np.abs(local) - halves[owner[idx]][..., None], 0.0)
    return np.linalg.norm(gap, axis=-1).min(1)


def wrist_candidates(surfaces: list[ObjectSurface], palm: float, scene=None) -> np.ndarray:
    """Where a wrist may be (M, 3): each skin point pushed `palm` out along its own normal, less
    those nearer than `palm` to any object (an object's concave side, a neighbouring object: a
    wrist there would put the hand inside) or inside the scene (the furniture under the object)."""
    cand = np.concatenate([s.skin + palm * s.normals for s in surfaces])             # (M, 3)
    if len(cand) == 0:
        return cand
    cand = cand[object_distance(cand, surfaces) >= palm - _CLEARANCE_TOL]
    if scene is not None and len(cand):
        cand = cand[~scene.occupied(cand, outside=False)]
    return cand


def hand_clear(cand: np.ndarray, forearm: np.ndarray, surfaces: list[ObjectSurface]) -> np.ndarray:
    """(M,) bool: the wrist candidates (M, 3) whose hand, along the unit `forearm` direction (3,)
    (`HAND_SPAN`), stays `FINGER_CLEARANCE` out of every object."""
    if not len(cand) or not surfaces or not HAND_SPAN:
        return np.ones(len(cand), bool)
    pts = cand[:, None] + np.asarray(HAND_SPAN)[None, :, None] * forearm                  # (M, P, 3)
    return object_distance(pts.reshape(-1, 3), surfaces).reshape(len(cand), -1).min(1) >= FINGER_CLEARANCE


def forearm_direction(joints: np.ndarray, wrist: int) -> np.ndarray:
    """Unit elbow-to-wrist direction (3,) averaged over frames of joints (n, J, 3)."""
    d = joints[:, wrist] - joints[:, BODY_PARENTS[wrist]]                                 # (n, 3)
    d = (d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)).mean(0)
    return d / max(float(np.linalg.norm(d)), 1e-9)


def nearest_reach(joints: np.ndarray, hands, cand: np.ndarray, surfaces: list[ObjectSurface]):
    """Over the frames joints (n, J, 3): the hand (of the joint indices `hands`) whose mean
    position is closest to a wrist candidate (M, 3) clear for it (`hand_clear` along its own
    forearm), as (distance m, hand joint, candidate (3,)); None when no candidate is clear."""
    best = None
    for h in hands:
        mean = joints[:, h].mean(0)                                                        # (3,)
        ok = cand[hand_clear(cand, forearm_direction(joints, h), surfaces)]
        if not len(ok):
            continue
        d = np.linalg.norm(ok - mean, axis=-1)
        i = int(np.argmin(d))
        if best is None or d[i] < best[0]:
            best = (float(d[i]), int(h), ok[i])
    return best


def reach_targets(joints: np.ndarray, labels: np.ndarray, action: int, hands, cand: np.ndarray,
                  ramp: int = 8, max_dist: float = 0.5, surfaces: list[ObjectSurface] | None = None):
    """Where a hand must be for each run of frames labelled `action` (a hand interaction):
    joints (T, J, 3) the motion so far, labels (T,) action index per frame, hands: joint indices
    to choose from (wrists), cand (M, 3): where a wrist may be (`wrist_candidates`: `palm`
    metres out from an object's surface, out of every object and the scene).
    surfaces: the objects; given, a candidate where the hand along the run's forearm would be
    in one is dropped for that hand (`hand_clear`).
    Per run: the hand closest to a candidate, and that candidate (`nearest_reach`). Weights
    ramp in and out over `ramp` frames so the reach is a movement, not a jump. A hand farther
    than `max_dist` from every candidate is left alone: pulling it there would drag the whole
    body. Returns (frames, joints, points, weights) or None when nothing is in reach, or no
    wrist position is free."""
    if not len(cand):
        return None
    frames, js, ps, ws = [], [], [], []
    for a, b in true_runs(labels == action):
        best = nearest_reach(joints[a:b], hands, cand, surfaces or [])
        if best is None or best[0] > max_dist:
            continue
        _, h, target = best
        n = b - a
        frames.append(np.arange(a, b)), js.append(np.full(n, h)), ps.append(np.repeat(target[None], n, 0))
        ws.append(ramp_weights(n, ramp))
    if not frames:
        return None
    return np.concatenate(frames), np.concatenate(js), np.concatenate(ps), np.concatenate(ws)


class HandReach(NamedTuple):
    """Where a hand may go on the placed objects, fixed for one `generate` call: shared by the
    in-loop hand goal and the clean-up's hand reach."""

    cand: np.ndarray                   # (M, 3) `wrist_candidates` (M may be 0)
    surfaces: list[ObjectSurface]
    hands: tuple[int, ...]             # wrist joint indices
    actions: tuple[int, ...]           # action indices that get a hand, in the order named


def hand_reach(objects, scene, names, actions, hands, palm: float = 0.03) -> HandReach | None:
    """The `HandReach` of a call: objects [(OccupancyGrid, pose)], names the checkpoint's
    action vocabulary, actions the names that get a hand, a wrist `palm` metres out from an
    object's surface (the wrist joint sits that far from the palm's skin), out of every object
    and of `scene`. None without objects, hands or such an action."""
    acts = tuple(names.index(a) for a in actions if a in names)
    if not acts or not objects or not hands:
        return None
    surfaces = [s for s in object_surfaces(objects) if len(s.centres)]
    # The same for every sample and action: computed once (a k-d tree over every object's voxels).
    cand = wrist_candidates(surfaces, palm, scene) if surfaces else np.zeros((0, 3))       # (M, 3)
    return HandReach(cand, surfaces, tuple(hands), acts)


def hand_goals(reach: HandReach, joints: np.ndarray, labels: np.ndarray,
               max_dist: float = HAND_GOAL_REACH) -> tuple[np.ndarray, np.ndarray]:
    """Each sample's hand goal for an episode labelled `labels` (S,), from its last frames
    joints (S, k, J, 3) world: the hand nearer a clear wrist candidate and that candidate
    (`nearest_reach`), where the label is a hand action and the candidate within `max_dist`.
    Returns (joint (S,) int, -1 = no goal; point (S, 3) world, NaN where none)."""
    S = joints.shape[0]
    joint, point = np.full(S, -1, np.int64), np.full((S, 3), np.nan)
    for s in np.flatnonzero(np.isin(labels, list(reach.actions))):
        best = nearest_reach(joints[s], reach.hands, reach.cand, reach.surfaces)
        if best is not None and best[0] <= max_dist:
            joint[s], point[s] = best[1], best[2]
    return joint, point


def hand_targets(joints: np.ndarray, labels: np.ndarray, names, hand_actions, objects, scene=None,
                 palm: float = 0.03) -> list | None:
    """Per sample, the hand targets of the frames labelled with a hand action (None: none): a
    wrist where `hand_reach` allows one, for the hand nearer it over each run (`reach_targets`)."""
    reach = hand_reach(objects, scene, names, hand_actions, HAND_JOINTS, palm)
    if reach is None:
        return None
    out = []
    for s in range(joints.shape[0]):
        parts = [r for a in reach.actions
                 if (r := reach_targets(joints[s], labels[s], a, reach.hands, reach.cand,
                                        surfaces=reach.surfaces)) is not None]
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
