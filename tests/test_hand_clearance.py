"""Hands out of objects after the final solve (`motiongen.sampling.hand_clearance`), on known
geometry: the rest-pose body's right hand with its fingers 5 cm deep in a box."""

import dataclasses

import numpy as np
import pytest
import trimesh

from motiongen.body.model import BodyParams
from motiongen.sampling.hand_clearance import (EXTRA_MARGIN, clearing_push, deepest, object_fields, push_out,
                                               settle_hands, smooth_pushes)
from motiongen.scene.distance_field import MeshField
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.scene.voxelize import voxelize_mesh
from motiongen.skeleton import HAND_JOINTS

T, VOX, DEPTH = 3, 0.01, 0.05
RIGHT = HAND_JOINTS[1]


def standing() -> BodyParams:
    """The rest pose (arms out along x, the right hand at -x), pelvis 1 m up."""
    tr = np.zeros((T, 3))
    tr[:, 1] = 1.0
    return BodyParams(np.zeros((T, 3)), np.zeros((T, 63)), tr, np.zeros(10))


def box_over_fingers(bm, body):
    """A box of 1 cm voxels from 20 cm beyond the right fingertips to DEPTH into the hand."""
    tip = bm.motion_vertices(body, slice(0, 1), bm.part_vertices(RIGHT))[0, :, 0].min()
    n = int(round((0.2 + DEPTH) / VOX))
    grid = OccupancyGrid.from_dense(np.ones((n, 40, 40), bool), [tip - 0.2, 0.9, -0.2], VOX)
    return grid, np.eye(4)


def hand_inside(bm, body, objects) -> bool:
    pts = bm.motion_vertices(body, slice(None), bm.part_vertices(RIGHT)).reshape(-1, 3)
    return any(g.occupied(p, outside=False).any() for g, _ in objects for p in [pts])


def wrist_target(bm, body):
    J = bm.joints(*[__import__("torch").as_tensor(x, dtype=__import__("torch").float32)
                    for x in (body.global_orient, body.body_pose, body.transl)]).numpy()
    return (np.arange(T), np.full(T, RIGHT), J[:, RIGHT].astype(np.float64), np.ones(T))


def test_the_hand_part_is_the_hand(bm):
    right, left = bm.part_vertices(RIGHT), bm.part_vertices(HAND_JOINTS[0])
    v = bm.motion_vertices(standing(), slice(0, 1))[0]
    assert len(right) > 500 and not set(right) & set(left)
    assert v[right, 0].max() < v[:, 0].min() + 0.25 and v[left, 0].min() > v[:, 0].max() - 0.25   # the hands are the ends


def test_push_out_moves_the_target_by_the_depth_along_the_way_out(bm):
    body = standing()
    objects = [box_over_fingers(bm, body)]
    fields = object_fields(objects)                    # the box's tight grid: all occupied
    ids = {h: bm.part_vertices(h) for h in HAND_JOINTS}
    depth, way, margin = deepest(bm.motion_vertices(body, np.arange(T), ids[RIGHT]).reshape(-1, 3), fields)
    assert depth == pytest.approx(DEPTH, abs=VOX) and margin == pytest.approx(VOX / 2 + EXTRA_MARGIN)
    assert way @ np.array([1.0, 0, 0]) > 0.95                                           # back towards the body
    f, j, p, _ = wrist_target(bm, body)
    reach = (f, j, p, np.array([0.3, 1.0, 0.3]))                    # ramping in and out: the hand is in the box on every frame
    moved = push_out(body, reach, fields, ids, bm)
    shift = moved[2] - reach[2]
    assert moved[3].tolist() == [1.0, 1.0, 1.0]                     # held out on the ramp frames too
    assert np.allclose(shift, shift[0]) and np.linalg.norm(shift[0]) == pytest.approx(depth + margin)
    # the body moved by that shift has its hand out of the box: nothing left to push
    out = dataclasses.replace(body, transl=body.transl + shift[0])
    assert not hand_inside(bm, out, objects) and push_out(out, moved, fields, ids, bm) is None


def test_settle_solves_again_until_the_hand_is_out(bm):
    """With a solve that puts the wrist on its target, one round takes the hand out; a hand
    already out, or no object, costs no solve."""
    body = standing()
    objects = [box_over_fingers(bm, body)]
    start = wrist_target(bm, body)
    calls = []

    def resolve(s, r):
        calls.append(s)
        return dataclasses.replace(body, transl=body.transl + (r[2][0] - start[2][0]))

    reach = [start, None]
    settled = settle_hands([body, body], reach, objects, bm, resolve)
    assert calls == [0] and not hand_inside(bm, settled[0], objects) and settled[1] is body
    assert reach[0][2][0, 0] > start[2][0, 0]                                             # updated in place
    assert settle_hands([settled[0]], [reach[0]], objects, bm, resolve) == [settled[0]] and calls == [0]
    assert settle_hands([body], [start], [], bm, resolve) == [body]


def test_the_other_hand_in_an_object_gets_a_target_too(bm):
    """The reach targets the left hand; the right one is in the box on those frames: it gets
    targets there, moved out; the left hand's are left as they were."""
    body = standing()
    fields = object_fields([box_over_fingers(bm, body)])
    ids = {h: bm.part_vertices(h) for h in HAND_JOINTS}
    f, _, p, w = wrist_target(bm, body)
    left = (f, np.full(T, HAND_JOINTS[0]), p, w)
    moved = push_out(body, left, fields, ids, bm)
    new = moved[1] == RIGHT
    assert new.sum() == T and sorted(moved[0][new].tolist()) == list(range(T))
    assert np.array_equal(moved[2][~new], p) and (moved[2][new][:, 0] > p[:, 0].min()).all()


def test_an_object_with_its_exact_surface_is_measured_on_it_not_on_its_voxels(bm):
    """The fingertips 4 mm into a box whose 4 cm voxels say nothing of millimetres: with the
    box's exact surface on its grid, the depth is 4 mm, the margin only EXTRA_MARGIN, and the
    hand moved by them is out of the box itself."""
    body = standing()
    verts = bm.motion_vertices(body, np.arange(T), bm.part_vertices(RIGHT)).reshape(-1, 3)
    tip = verts[:, 0].min()
    box = trimesh.creation.box(extents=(0.2, 0.4, 0.4))
    box.apply_translation([tip + 0.004 - 0.1, 1.1, 0.0])
    grid = voxelize_mesh(box, voxel_size=0.04)
    grid.exact_surface = MeshField(box, voxel_size=0.01)
    fields = object_fields([(grid, np.eye(4))])
    depth, way, margin = deepest(verts, fields)
    assert depth == pytest.approx(0.004, abs=5e-4) and margin == EXTRA_MARGIN and way @ [1.0, 0, 0] > 0.99
    moved = verts + (depth + margin) * way
    assert grid.exact_surface.query(moved).distance.min() > 0.004                       # out, with the margin
    assert deepest(moved, fields)[0] == -1.0


def test_a_hand_through_a_thin_plate_is_pushed_clear_of_it(bm):
    """A 1 cm plate through the middle of the right hand (palm and fingers above and below
    it): the deepest vertex is at most 5 mm in, and moving the hand by that leaves it through
    the plate. The push grows until no vertex is inside (`clearing_step`): the body moved by
    the new target's shift has its hand out, and the push is no longer than the hand is thick
    plus a step."""
    body = standing()
    ids = {h: bm.part_vertices(h) for h in HAND_JOINTS}
    verts = bm.motion_vertices(body, np.arange(T), ids[RIGHT]).reshape(-1, 3)
    mid = 0.5 * (verts[:, 1].min() + verts[:, 1].max())
    plate = trimesh.creation.box(extents=(0.4, 0.01, 0.4))
    plate.apply_translation([verts[:, 0].min() + 0.1, mid, 0.0])
    grid = voxelize_mesh(plate, voxel_size=0.01)
    grid.exact_surface = MeshField(plate, voxel_size=0.005)
    objects = [(grid, np.eye(4))]
    fields = object_fields(objects)
    depth, way, margin = deepest(verts, fields)
    assert depth <= 0.0055 and abs(way[1]) > 0.99                                      # out through a face
    assert deepest(verts + (depth + margin) * way, fields)[0] >= 0                     # the deepest vertex's push: still through
    moved = push_out(body, wrist_target(bm, body), fields, ids, bm)
    shift = moved[2][0] - wrist_target(bm, body)[2][0]
    out = dataclasses.replace(body, transl=body.transl + shift)
    out_verts = bm.motion_vertices(out, np.arange(T), ids[RIGHT]).reshape(-1, 3)
    assert deepest(out_verts, fields)[0] == -1.0
    thick = np.ptp(verts[:, 1])
    assert np.linalg.norm(shift) < 1.5 * (thick / 2 + 0.005) + margin


def test_a_hand_over_an_edge_moves_along_the_mean_way_out(bm):
    """A box's edge through the right hand: the fingertips 4 cm in through its side (+x face),
    the palm's lower half 1 cm below its top. Each inside vertex's way out is its nearest
    face's normal and its depth the distance to it (a box's closed form); the push is along
    their depth-weighted mean (within the exact surface's error; the deepest vertex's way is
    13° off it) and takes every vertex out."""
    body = standing()
    verts = np.asarray(bm.motion_vertices(body, slice(0, 1), bm.part_vertices(RIGHT))[0], np.float64)   # (K, 3)
    lo = np.array([verts[:, 0].min() - 0.2, 0.0, -0.2])
    hi = np.array([verts[:, 0].min() + 0.04, np.median(verts[:, 1]) + 0.01, 0.2])
    box = trimesh.creation.box(extents=hi - lo)
    box.apply_translation(0.5 * (lo + hi))
    grid = voxelize_mesh(box, voxel_size=0.02)
    grid.exact_surface = MeshField(box, voxel_size=0.005)
    fields = object_fields([(grid, np.eye(4))])
    inside = np.all((verts > lo) & (verts < hi), 1)
    gaps = np.concatenate([verts[inside] - lo, hi - verts[inside]], 1)                   # (n, 6) to each face
    normals = np.concatenate([-np.eye(3), np.eye(3)])                                    # (6, 3) outward
    face = gaps.argmin(1)
    mean = ((gaps.min(1) + 1e-3)[:, None] * normals[face]).sum(0)
    assert len(set(face.tolist())) >= 2                                                  # out through two faces
    push = clearing_push(verts, fields)
    assert push @ mean / (np.linalg.norm(push) * np.linalg.norm(mean)) > np.cos(np.radians(3))
    assert deepest(verts + push, fields)[0] == -1.0


def test_smooth_pushes_fade_around_a_single_frame_and_keep_its_push():
    """One frame inside among 21: it keeps its own push at full cover; the others get the
    Gaussian's share of it, push and cover alike, fading to nothing; sigma 0 leaves the pushes
    where they are."""
    frames = np.arange(21)
    push, inside = np.zeros((21, 3)), np.zeros(21, bool)
    push[10], inside[10] = [0.04, 0.0, 0.0], True
    out, cover = smooth_pushes(frames, push, inside, 3.0)
    g = np.exp(-0.5 * ((frames - 10) / 3.0) ** 2)
    assert np.allclose(out[:, 0], 0.04 * g) and np.allclose(out[:, 1:], 0) and np.allclose(cover, g)
    assert np.abs(np.diff(out[:, 0])).max() < 0.04 * 0.2                  # no frame-to-frame jump of the push
    raw, raw_cover = smooth_pushes(frames, push, inside, 0.0)
    assert np.array_equal(raw, push) and np.array_equal(raw_cover, inside.astype(float))


def test_smooth_pushes_give_every_inside_frame_at_least_its_push():
    """A run of inside frames needing 2 and 6 cm in turn along the same way out: the smoothed
    push is about the run's mean, topped up until each frame has what it needs, and still
    changes by less than the alternation from one frame to the next."""
    frames = np.arange(30)
    inside = (frames >= 10) & (frames < 20)
    push = np.zeros((30, 3))
    push[inside, 2] = np.where(frames[inside] % 2, 0.06, 0.02)
    out, cover = smooth_pushes(frames, push, inside, 3.0)
    assert (out[inside, 2] >= push[inside, 2] - 1e-4).all() and (cover[inside] == 1).all()
    assert np.abs(np.diff(out[:, 2])).max() < 0.02 and out[0, 2] < 0.005 and out[-1, 2] < 0.005


def test_push_out_spreads_a_one_frame_push_to_its_neighbours(bm):
    """The hand in the box on the middle frame only (the body 10 cm back on the others): with
    sigma the middle frame's target moves by its push at full weight, as without, and the frames
    beside it are pulled the same way by the Gaussian's share, their weight raised to it."""
    n, sigma = 5, 1.5
    body = standing()
    body = BodyParams(np.zeros((n, 3)), np.zeros((n, 63)), np.repeat(body.transl[:1], n, 0), np.zeros(10))
    objects = [box_over_fingers(bm, body)]
    body.transl[[0, 1, 3, 4], 0] += 0.1                                                 # hand out of the box
    fields = object_fields(objects)
    ids = {h: bm.part_vertices(h) for h in HAND_JOINTS}
    J = bm.joints(*[__import__("torch").as_tensor(x, dtype=__import__("torch").float32)
                    for x in (body.global_orient, body.body_pose, body.transl)]).numpy().astype(np.float64)
    reach = (np.arange(n), np.full(n, RIGHT), J[:, RIGHT], np.full(n, 0.5))
    sharp = push_out(body, reach, fields, ids, bm)
    smooth = push_out(body, reach, fields, ids, bm, sigma)
    p = sharp[2][2] - J[2, RIGHT]                                                       # the middle frame's push
    assert np.allclose(smooth[2][2], sharp[2][2], atol=1e-6) and smooth[3][2] == 1.0
    assert np.array_equal(sharp[2][[0, 1, 3, 4]], reach[2][[0, 1, 3, 4]])              # without sigma: untouched
    for f in (1, 3):
        g = np.exp(-0.5 * (1 / sigma) ** 2)
        assert np.allclose(smooth[2][f], J[f, RIGHT] + g * g * p, atol=1e-6) and smooth[3][f] == pytest.approx(g)
    assert len(smooth[0]) == n                                                          # no target for the left hand
