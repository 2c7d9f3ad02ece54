"""The video's adaptive camera (the TRUMANS supplement's ring camera): it never stands in the
scene, sees the body where the follow camera is behind a wall, turns as little as it can, and
joins keyframes without a jump where the angle wraps."""

import math

import numpy as np
import trimesh

from motiongen.export.adaptive_camera import (ARMS, GridRays, MeshRays, RingSettings, acting_hands, adaptive_path,
                                              best_sequence, interpolate_angles, visible)
from motiongen.export.camera import PinholeCamera
from motiongen.export.follow_camera import follow_path
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.skeleton import BODY_JOINT_NAMES, PELVIS

VOX = 0.05


def room(walls, size=(8.0, 3.0, 8.0), origin=(-4.0, 0.0, -4.0)) -> OccupancyGrid:
    """A grid of `size` metres with solid boxes walls [((x0, y0, z0), (x1, y1, z1))]."""
    shape = tuple(int(round(s / VOX)) for s in size)
    occ = np.zeros(shape, bool)
    o = np.asarray(origin)
    for lo, hi in walls:
        a = np.floor((np.asarray(lo) - o) / VOX + 1e-9).astype(int)
        b = np.ceil((np.asarray(hi) - o) / VOX - 1e-9).astype(int)
        occ[a[0]:b[0], a[1]:b[1], a[2]:b[2]] = True
    return OccupancyGrid.from_dense(occ, o, VOX)


def standing_body(T: int, start=(0.0, 0.0), velocity=(0.0, 0.0), facing=(0.0, 1.0)) -> np.ndarray:
    """(T, 22, 3) a rigid standing skeleton (hips across the facing direction) moving at
    `velocity` (m/frame) in x, z: enough joints in the right places for the camera."""
    names = BODY_JOINT_NAMES
    f = np.array([facing[0], 0.0, facing[1]]) / np.hypot(*facing)
    left = np.cross(np.array([0.0, 1.0, 0.0]), f)                      # the body's left, y up
    j = np.zeros((22, 3))
    for i, n in enumerate(names):
        side = 1.0 if n.startswith("left") else -1.0 if n.startswith("right") else 0.0
        h = 1.5 if "shoulder" in n or "collar" in n else 1.2 if "elbow" in n else 0.95 if "wrist" in n else \
            1.75 if n == "head" else 1.55 if n == "neck" else 0.5 if "knee" in n else 0.08 if "ankle" in n else \
            0.03 if "foot" in n else 1.2 if "spine" in n else 0.95
        j[i] = [0.0, h, 0.0] + side * (0.35 if any(k in n for k in ("elbow", "wrist")) else 0.12) * left
    t = np.arange(T)[:, None]
    xz = np.asarray(start)[None] + t * np.asarray(velocity)[None]                          # (T, 2)
    return j[None] + np.stack([xz[:, 0], np.zeros(T), xz[:, 1]], -1)[:, None]


def pelvis_seen(path, joints, rays) -> np.ndarray:
    return np.array([visible(rays, path.position[t][None], joints[t, [PELVIS]][None], [path.at(t)])[0, 0]
                     for t in range(len(joints))])


def test_a_wall_behind_the_body_hides_it_from_the_follow_camera_not_from_the_adaptive_one():
    # The body walks along +z with a wall 0.6 m behind it: the follow camera (3.2 m back) stands
    # behind the wall.
    grid = room([((-4.0, 0.0, -1.05), (4.0, 2.8, -0.95))])
    joints = standing_body(150, start=(0.0, -0.35), velocity=(0.0, 0.004))
    rays = GridRays(grid)
    follow = follow_path(joints, 30.0)
    adaptive = adaptive_path(joints, 30.0, rays)
    assert pelvis_seen(follow, joints, rays).mean() == 0.0
    assert pelvis_seen(adaptive, joints, rays).all()
    assert not grid.occupied(adaptive.position, outside=False).any()


def test_the_camera_never_stands_inside_the_scene():
    # A 3 x 3 m room with 0.2 m walls; the body walks from the middle into a corner, 0.3 m from both walls.
    walls = [((-1.7, 0, -1.7), (1.7, 2.8, -1.5)), ((-1.7, 0, 1.5), (1.7, 2.8, 1.7)),
             ((-1.7, 0, -1.7), (-1.5, 2.8, 1.7)), ((1.5, 0, -1.7), (1.7, 2.8, 1.7))]
    grid = room(walls)
    joints = standing_body(240, start=(0.0, 0.0), velocity=(1.2 / 240, 1.2 / 240), facing=(1.0, 1.0))
    rays = GridRays(grid)
    path = adaptive_path(joints, 30.0, rays)
    assert not grid.occupied(path.position, outside=False).any()
    # On the body's side of every wall: nothing between the camera and the ring's centre at its height.
    centre = path.target * np.array([1.0, 0.0, 1.0]) + np.array([0.0, RingSettings().height, 0.0])
    assert np.isinf(rays.first_hit(centre, path.position)).all()
    assert (np.linalg.norm((path.position - centre)[:, [0, 2]], axis=-1) <= RingSettings().radius + 1e-9).all()
    assert pelvis_seen(path, joints, rays).all()


def test_dynamic_programming_prefers_the_smaller_rotation_when_two_proposals_see_equally():
    angles = 2 * np.pi * np.arange(20) / 20
    cost = np.zeros((3, 20))
    cost[0, 3] = -5.0                        # the first keyframe: only proposal 3 sees the body
    cost[1:, [5, 15]] = -2.0                 # later: 5 and 15 see equally; 5 is 36 degrees away, 15 is 144
    assert list(best_sequence(cost, angles, 1.0)) == [3, 5, 5]
    # With rotation free the first of the cheapest is as good as any; with it dear, staying wins.
    assert list(best_sequence(cost, angles, 100.0)) == [3, 3, 3]


def test_keyframes_are_joined_without_a_jump_where_the_angle_wraps():
    keys = np.array([0, 30, 60, 90])
    key_angles = np.radians([340.0, 355.0, 10.0, 25.0])                 # passes through 0 / 360
    a = interpolate_angles(keys, key_angles, 100)
    step = np.degrees(np.abs(np.diff(a)))
    assert step.max() < 1.5                                               # 85 degrees over 90 frames, no 360 jump
    assert np.allclose(np.exp(1j * a[keys]), np.exp(1j * key_angles))     # through every keyframe
    assert np.all(np.diff(a[:91]) >= 0)                                   # monotone: no swing past a keyframe


def test_the_interacting_hand_is_the_one_near_a_dynamic_object():
    joints = standing_body(3)
    left_wrist = joints[0, ARMS[0][-1]]
    near_left = left_wrist + np.array([0.0, 0.0, 0.1])
    side, acting = acting_hands(joints, np.stack([near_left[None], near_left[None] + 5.0, near_left[None] + 5.0]))
    assert list(side) == [0, 1, 1] and list(acting) == [True, False, False]   # beyond 20 cm: the right hand
    side, acting = acting_hands(joints, None)
    assert list(side) == [1, 1, 1] and not acting.any()


def test_a_joint_is_seen_when_the_first_hit_is_within_10_cm_of_it():
    # A table top at 0.75-0.80 m; a hand 5 cm above it and one 30 cm below its far edge.
    grid = room([((-0.5, 0.75, -0.5), (0.5, 0.80, 0.5))])
    rays = GridRays(grid)
    eye = np.array([0.0, 1.6, -2.0])
    cam = PinholeCamera(eye, np.array([0.0, 0.8, 0.0]), 1.0)
    on_top = np.array([0.0, 0.85, 0.0])
    under = np.array([0.0, 0.45, 0.3])
    behind = np.array([0.0, 0.8, -3.0])                                   # behind the camera
    seen = visible(rays, eye[None], np.stack([on_top, under, behind])[None], [cam])[0]
    assert list(seen) == [True, False, False]


def test_mesh_rays_and_grid_rays_meet_a_wall_at_the_same_distance():
    box = trimesh.creation.box(extents=(4.0, 2.0, 0.2))
    box.apply_translation([0.0, 1.0, 1.0])                               # a wall from z = 0.9 to 1.1
    grid = room([((-2.0, 0.0, 0.9), (2.0, 2.0, 1.1))])
    o = np.array([[0.0, 1.0, -1.0], [0.5, 1.5, -1.0], [0.0, 1.0, -1.0]])
    e = np.array([[0.0, 1.0, 3.0], [0.5, 1.5, 3.0], [3.0, 1.0, -1.0]])   # the last one runs along the wall
    hm, hg = MeshRays(box).first_hit(o, e), GridRays(grid).first_hit(o, e)
    assert np.allclose(hm[:2], 1.9, atol=1e-6) and np.allclose(hg[:2], 1.9, atol=VOX)
    assert np.isinf(hm[2]) and np.isinf(hg[2])
    assert np.isinf(MeshRays(box).first_hit(o[2:], e[2:])).all()        # a batch that meets nothing


def test_the_adaptive_camera_turns_less_than_the_follow_camera_on_a_winding_walk():
    # A walk that turns through two full circles on an empty floor: the follow camera swings round
    # with the body; the ring camera, looking at the body from outside the circle, turns far less.
    T = 600
    theta = np.linspace(0, 4 * np.pi, T)
    xz = 1.5 * np.stack([np.sin(theta), np.cos(theta)], -1)
    joints = np.empty((T, 22, 3))
    for t in range(T):
        facing = np.array([math.cos(theta[t]), -math.sin(theta[t])])    # along the circle
        joints[t] = standing_body(1, start=tuple(xz[t]), facing=tuple(facing))[0]

    class Open:
        def first_hit(self, o, e):
            return np.full(len(o), np.inf)

    def turned(path):
        d = path.target - path.position
        return np.abs(np.diff(np.unwrap(np.arctan2(d[:, 0], d[:, 2])))).sum()

    assert turned(adaptive_path(joints, 30.0, Open())) < 0.5 * turned(follow_path(joints, 30.0))
