"""Hands out of objects, on the body's own mesh, after the final solve.

The hand reach puts a wrist 3 cm out from an object (`interactions.hand_targets`), but a hand is
wider and longer than a wrist joint: posed on the body, its fingers or its side can end up in
the object. After the final solve, each run of a hand target is checked on the mesh: the hand's
vertices against every placed object (its exact surface where its grid carries one, as `sample`
and `evaluate` give it; else its voxels, whose surface is off by up to half a voxel: 1 cm at
2 cm voxels, most of a hand's depth in a cup); where one is inside, the target moves along
the inside vertices' mean way out until none is inside (`clearing_push`), and the sample is
solved again (at most `ROUNDS` times). For a solve that puts a wrist on its target exactly,
the pushes are spread over the neighbouring frames (`smooth_pushes`, `PUSH_SMOOTHING`): a hand
inside on one frame and not on the next would otherwise get a target that jumps by
centimetres from one frame to the next, which such a solve follows as a wrist shaking at
10-15 Hz.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from motiongen.scene.distance_field import surface_distance
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.skeleton import HAND_JOINTS

ROUNDS = 3               # re-solves per sample at most
# Past the surface by this much more than the depth: the grid's surface is exact to half a
# voxel, the object's own surface somewhere inside that.
EXTRA_MARGIN = 0.005     # m, beyond half a voxel
GROWTH = 1.5             # a step that leaves the hand in the object grows by this much (`clearing_step`)
MAX_PUSH = 0.15          # m: a hand is at most this far through an object (a palm and fingers)
# Time over which a push fades in and out around the frames that need it (the Gaussian's sigma),
# per final solve: a hand takes about a tenth of a second to move a few centimetres out of an
# object. The joint-space solve (and `refined`, which starts from it) puts a wrist on its target
# exactly, so per-frame pushes shook it at 10-15 Hz; the L-BFGS solve's rotation terms filter
# them already, and spreading them there cost contact and left more hands inside
# (docs/results.md, "Hand pushes in time").
PUSH_SMOOTHING = {"lbfgs": 0.0, "joint-space": 0.1, "refined": 0.1}     # s
# Frames whose push has faded below this share of full weight get no target of their own.
PUSH_CUTOFF = 0.01


def settle_hands(bodies: list, reach: list, objects, bm, resolve: Callable[[int, tuple], object],
                 rounds: int | None = None, sigma: float = 0.0) -> list:
    """bodies: one solved BodyMotion per sample; reach: per sample the final solve's targets
    (frames, joints, points, weights) or None; objects [(OccupancyGrid, pose (4, 4))]; bm the
    body model; resolve(s, reach) solves sample s again with new targets; sigma (frames): how
    far the pushes spread in time (`push_out`; PUSH_SMOOTHING times the frame rate). Returns the
    bodies, those whose hands were in an object solved again (`reach` is updated in place)."""
    rounds = ROUNDS if rounds is None else rounds             # read here: benchmarks set ROUNDS = 0
    if not objects or not rounds:
        return bodies
    fields = object_fields(objects)
    ids = {h: bm.part_vertices(h) for h in HAND_JOINTS}
    out = list(bodies)
    for s, r in enumerate(reach):
        for _ in range(rounds if r is not None else 0):
            moved = push_out(out[s], r, fields, ids, bm, sigma)
            if moved is None:
                break
            reach[s] = r = moved
            out[s] = resolve(s, r)
    return out


def object_fields(objects) -> list:
    """[(signed distance field, pose (4, 4), margin m, grid)] of placed objects [(grid, pose)]:
    the object's exact surface where its grid carries one (`OccupancyGrid.exact_surface`; the
    margin beyond it EXTRA_MARGIN), else its voxels, the grid padded by one free voxel (a tight
    grid of a box is all occupied, and the field then knows no way out), the margin half a
    voxel more."""
    out = []
    for grid, pose in objects:
        pose = np.asarray(pose, np.float64)
        if grid.exact_surface is not None:
            out.append((grid.exact_surface, pose, EXTRA_MARGIN, grid))
            continue
        v = grid.voxel_size
        padded = OccupancyGrid.from_dense(np.pad(np.asarray(grid.dense(), bool), 1), np.asarray(grid.origin) - v, v)
        out.append((surface_distance(padded), pose, 0.5 * v + EXTRA_MARGIN, grid))
    return out


def push_out(body, reach: tuple, fields, ids: dict, bm, sigma: float = 0.0) -> tuple | None:
    """The targets with every hand-action frame where a hand is inside an object moved: that
    frame's target for that hand becomes the wrist where the solve put it, moved clear of the
    object (`clearing_push`), at full weight — a ramp
    frame too (the network's hand may pass through the object on its way there), and the other
    hand too (it gets a target on those frames). sigma > 0 (frames): the pushes fade in and out
    over the neighbouring frames (`smooth_pushes`) instead of stopping at the frames that need
    them. None when no hand is in an object."""
    frames, joints, points, weights = reach
    acting = np.unique(frames[np.isin(joints, list(ids))])                                  # frames of a hand action
    if not len(acting):
        return None
    wrists = body_joints(bm, body, acting)                                                  # (F, 22, 3)
    new = {(int(f), int(j)): i for i, (f, j) in enumerate(zip(frames, joints))}
    points, weights, add, changed = np.array(points, np.float64), np.array(weights, np.float64), [], False
    for h, vids in ids.items():
        verts = bm.motion_vertices(body, acting, vids)                                      # (F, K, 3)
        push, inside = np.zeros((len(acting), 3)), np.zeros(len(acting), bool)
        for i in range(len(acting)):
            p = clearing_push(np.asarray(verts[i], np.float64), fields)                    # (3,) or None
            if p is not None:
                push[i], inside[i] = p, True
        if not inside.any():
            continue
        changed = True
        push, cover = smooth_pushes(acting, push, inside, sigma)                            # (F, 3), (F,)
        for i in np.flatnonzero(cover >= PUSH_CUTOFF):
            f, target = int(acting[i]), wrists[i, h] + push[i]
            if (f, h) in new:
                k = new[f, h]
                points[k] = (1 - cover[i]) * points[k] + cover[i] * target
                weights[k] = max(weights[k], cover[i])
            else:
                add.append((f, h, target, cover[i]))
    if not changed:
        return None
    if add:
        frames = np.concatenate([frames, [a[0] for a in add]])
        joints = np.concatenate([joints, [a[1] for a in add]])
        points = np.concatenate([points, [a[2] for a in add]])
        weights = np.concatenate([weights, [a[3] for a in add]])
    return frames, joints, points, weights


def smooth_pushes(frames: np.ndarray, push: np.ndarray, inside: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Pushes (F, 3) needed on the `inside` frames (F,) bool of `frames` (F,) int, spread over
    time: (pushes (F, 3), cover (F,) in [0, 1]). With Gaussian weights g over the frame distance
    (sigma frames) to each inside frame, cover = 1 − Π(1 − g): 1 on an inside frame, fading out
    smoothly away from them, the weight a frame's target gets; a frame's push is cover times
    the g-weighted mean of the inside frames' pushes: an inside frame alone keeps its own push,
    a run of them their local mean. Where that mean falls short of a frame's own push along its
    way out, what is missing is added the same way over the frames still short, a few rounds.
    sigma = 0: the pushes where they are."""
    if sigma <= 0:
        return np.where(inside[:, None], push, 0.0), inside.astype(np.float64)
    d = frames[:, None] - frames[inside][None, :]                                           # (F, n)
    g = np.exp(-0.5 * (d / sigma) ** 2)
    need = np.linalg.norm(push[inside], axis=-1)                                           # (n,)
    way = push[inside] / np.maximum(need, 1e-12)[:, None]
    out, cover = _spread(g, push[inside])
    for _ in range(SMOOTH_ROUNDS):
        missing = np.maximum(need - (out[inside] * way).sum(-1), 0.0)                      # (n,)
        short = missing > 1e-4
        if not short.any():
            break
        out += _spread(g[:, short], missing[short, None] * way[short])[0]
    return out, cover


def _spread(g: np.ndarray, push: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cover (F,) times the g-weighted mean of push (n, 3): (F, 3), cover = 1 − Π(1 − g) over
    g's columns (F,))."""
    cover = 1.0 - np.prod(1.0 - g, axis=1)                                                 # (F,)
    return cover[:, None] * (g @ push) / np.maximum(g.sum(1), 1e-12)[:, None], cover


SMOOTH_ROUNDS = 8     # top-ups of `smooth_pushes`


def clearing_push(hand: np.ndarray, fields) -> np.ndarray | None:
    """A move (3,) that takes a hand's vertices (K, 3) out of every object (`clearing_step`),
    None when none is inside: along the inside vertices' mean way out, each weighted by its
    depth, unless no move of up to MAX_PUSH that way does it (a plate through the hand: half
    its vertices leave up, half down, and their mean points nowhere); then along the deepest
    vertex's way out. The deepest vertex alone misleads where a hand holds an object's edge:
    it leaves through one face while the vertices that went in through the other stay in, and
    the next round's deepest vertex points elsewhere again, so the hand never gets out
    (docs/results.md, "Hands out of objects along their mean way out")."""
    inside = list(_inside(hand, fields))                  # one query of the objects for both ways
    if not inside:
        return None
    depth, way_out, margin = _deepest(inside)
    mean = _mean_way_out(inside)
    if mean is not None:
        step = clearing_step(hand, mean, depth, margin, fields)
        # clearing_step stops short of MAX_PUSH only once the hand is out
        if step < MAX_PUSH or deepest(hand + step * mean, fields)[0] < 0:
            return step * mean
    return clearing_step(hand, way_out, depth, margin, fields) * way_out


def clearing_step(hand: np.ndarray, way_out: np.ndarray, depth: float, margin: float, fields) -> float:
    """How far (m) to move a hand's vertices (K, 3) along way_out (3,) for none to be inside
    an object: the deepest vertex's depth and margin where that does it, else that step grown
    by GROWTH until it does (at most MAX_PUSH). The deepest vertex alone says too little where
    an object is thinner than the hand is deep in it: moved out of one face, the hand is still
    through the object (a plate, a book)."""
    step = depth + margin
    while step < MAX_PUSH and deepest(hand + step * way_out, fields)[0] >= 0:
        step *= GROWTH
    return min(step, MAX_PUSH)


def body_joints(bm, body, frames: np.ndarray) -> np.ndarray:
    """(F, 22, 3) float64 body joints of SMPL-X parameters at `frames`."""
    t = lambda a: torch.as_tensor(np.asarray(a)[frames], dtype=bm.J_template.dtype)      # noqa: E731
    with torch.no_grad():
        J = bm.joints(t(body.global_orient), t(body.body_pose), t(body.transl),
                      torch.as_tensor(np.asarray(body.betas), dtype=bm.J_template.dtype))
    return J.double().numpy()


def deepest(points: np.ndarray, fields) -> tuple[float, np.ndarray, float]:
    """(depth m, unit direction out (3,), margin m) of the point deepest inside any object (its
    exact surface, or its voxels; depth -1: none inside). A point in an occupied voxel less
    than half a voxel from a free one has depth 0 and still moves out by the margin."""
    return _deepest(_inside(points, fields))


def _deepest(inside) -> tuple[float, np.ndarray, float]:
    """`deepest` of `_inside`'s per-object (depths, ways out, margin)."""
    best = (-1.0, np.zeros(3), 0.0)
    for depth, way, margin in inside:
        i = int(np.argmax(depth))
        if depth[i] > best[0]:
            best = (float(depth[i]), way[i], margin)
    return best


def _mean_way_out(inside) -> np.ndarray | None:
    """Unit (3,) mean of the ways out of `_inside`'s points, each weighted by its depth (and a
    millimetre, so that points on a surface count); None where they cancel exactly."""
    total = np.zeros(3)
    for depth, way, _ in inside:
        total += ((depth + 1e-3)[:, None] * way).sum(0)
    norm = np.linalg.norm(total)
    return total / norm if norm > 1e-9 else None


def _inside(points: np.ndarray, fields):
    """Per object with points (N, 3) inside it: (depths (n,) m ≥ 0, unit ways out (n, 3),
    margin m). Inside: behind the exact surface, or in an occupied voxel (depth 0 within half
    a voxel of a free one)."""
    for field, pose, margin, grid in fields:
        local = (points - pose[:3, 3]) @ pose[:3, :3]                                       # Rᵀ(p − t)
        exact = grid.exact_surface is field
        # Cull first: the exact surface is queried only within the grid's box (the mesh's bounds
        # and a voxel), the voxels only where they are occupied.
        lo, hi = grid.bounds
        near = np.all((local >= lo) & (local <= hi), -1) if exact else field.grid.occupied(local, outside=False)
        inside = np.flatnonzero(near)
        if not len(inside):
            continue
        q = field.query(points[inside], pose=pose)
        keep = q.distance < 0 if exact else np.ones(len(inside), bool)
        if keep.any():
            yield np.maximum(-q.distance[keep], 0.0), q.direction[keep], margin
