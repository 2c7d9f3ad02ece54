"""Hand and seat interactions (`motiongen.sampling.interactions`) on hand-made geometry with
known answers: a voxelised cup on a table, a book near it or far away, a seat under a goal."""

import numpy as np
import pytest

from motiongen.sampling.interactions import hand_goals, hand_reach, hand_targets, object_toward, seat_height, seat_shift
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.skeleton import FOOT_JOINTS, HAND_JOINTS, PELVIS
from tests.helpers import REST

VOX = 0.01            # object voxel size (m)
R_CUP = 0.04          # cup radius (m)
H_CUP = 0.10          # cup height (m)
PALM = 0.03           # hand_targets' default wrist-to-skin distance
TABLE = np.array([1.0, 0.75, 0.5])      # where the cup's base centre stands (table top)
NAMES = ["walk", "pick up"]
T, RUN = 40, (10, 30)                    # frames; the run labelled "pick up"


def pose(t, yaw=0.0):
    """(4, 4) world transform: a turn `yaw` about +y, then a shift t."""
    c, s = np.cos(yaw), np.sin(yaw)
    p = np.eye(4)
    p[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    p[:3, 3] = t
    return p


def cup():
    """A cylinder r = 4 cm, h = 10 cm in 1 cm voxels, its axis at local x = z = 0, base at y = 0."""
    n = int(round(2 * R_CUP / VOX))
    c = (np.arange(n) + 0.5) * VOX - R_CUP
    x, z = np.meshgrid(c, c, indexing="ij")
    disk = x ** 2 + z ** 2 <= R_CUP ** 2
    occ = np.repeat(disk[:, None, :], int(round(H_CUP / VOX)), axis=1)
    return OccupancyGrid.from_dense(occ, [-R_CUP, 0.0, -R_CUP], VOX)


def book(size=(0.15, 0.03, 0.20)):
    """A flat box, its min corner at the local origin."""
    occ = np.ones([int(round(s / VOX)) for s in size], bool)
    return OccupancyGrid.from_dense(occ, [0.0, 0.0, 0.0], VOX)


def distance_to(obj, p):
    """Exact distance (m) from world point p (3,) to the union of an object's voxel boxes (0 inside)."""
    grid, pose_ = obj
    local = (np.asarray(p) - pose_[:3, 3]) @ pose_[:3, :3]                                   # (3,)
    lo = grid.origin + np.argwhere(grid.dense()) * grid.voxel_size                           # (N, 3)
    gap = np.maximum(np.maximum(lo - local, local - lo - grid.voxel_size), 0.0)              # (N, 3)
    return float(np.linalg.norm(gap, axis=-1).min())


def axis_distance(p, cup_pose):
    """Horizontal distance (m) from p to the cup's axis."""
    return float(np.linalg.norm((np.asarray(p) - cup_pose[:3, 3])[[0, 2]]))


def body_with_wrist_at(wrist, hand=HAND_JOINTS[1]):
    """(1, T, 22, 3) the rest pose standing still with joint `hand` at `wrist`; labels (1, T)."""
    j = np.repeat((REST + (np.asarray(wrist) - REST[hand]))[None], T, 0)
    labels = np.zeros(T, int)
    labels[RUN[0]:RUN[1]] = NAMES.index("pick up")
    return j[None], labels[None]


def target(objects, wrist, scene=None):
    """The single hand target of the run (joint, point (3,)), or None."""
    j, labels = body_with_wrist_at(wrist)
    out = hand_targets(j, labels, NAMES, ("pick up",), objects, scene)
    assert out is not None and len(out) == 1
    if out[0] is None:
        return None
    frames, joints, points, weights = out[0]
    assert frames.tolist() == list(range(*RUN))
    assert len(set(joints.tolist())) == 1 and np.allclose(points, points[0])
    assert weights.max() == 1.0 and weights.min() > 0
    return int(joints[0]), points[0]


CUP_POSE = pose(TABLE, yaw=0.5)
NEAR_WRIST = TABLE + [0.10, 0.05, 0.02]      # the right wrist hovering 10 cm off the cup's side


def assert_on_cup(p):
    assert axis_distance(p, CUP_POSE) >= R_CUP + 0.02
    assert abs(distance_to((cup(), CUP_POSE), p) - PALM) <= VOX


def test_cup_alone_target_is_palm_out_from_its_side():
    hand, p = target([(cup(), CUP_POSE)], NEAR_WRIST)
    assert hand == HAND_JOINTS[1]
    assert_on_cup(p)
    # The wrist comes to the side the hand is on, at about the hand's height.
    assert np.dot((p - TABLE)[[0, 2]], (NEAR_WRIST - TABLE)[[0, 2]]) > 0
    assert TABLE[1] < p[1] < TABLE[1] + H_CUP + PALM + VOX


def test_a_far_book_does_not_move_the_cup_target():
    """The reported bug: a second object 3 m away moved the objects' centroid, and with it the
    push-out direction near the cup, so the target ended up ~1 cm from the cup's axis."""
    alone = target([(cup(), CUP_POSE)], NEAR_WRIST)[1]
    with_book = target([(cup(), CUP_POSE), (book(), pose(TABLE + [3.0, 0.0, 0.0]))], NEAR_WRIST)[1]
    assert_on_cup(with_book)
    assert np.allclose(with_book, alone, atol=1e-9)


@pytest.mark.parametrize("gap", [0.0, 0.02])
def test_a_book_next_to_the_cup_gets_no_target_inside_either(gap):
    # The book's near face `gap` m beyond the cup's +x side; the hand between them, over the book.
    cup_obj = (cup(), pose(TABLE))
    book_obj = (book(), pose(TABLE + [R_CUP + gap, 0.0, -0.10]))
    for wrist in (TABLE + [R_CUP + gap / 2, 0.05, 0.0], TABLE + [0.12, 0.06, 0.0]):
        _, p = target([cup_obj, book_obj], wrist)
        assert distance_to(cup_obj, p) >= PALM - 0.005
        assert distance_to(book_obj, p) >= PALM - 0.005
        assert axis_distance(p, cup_obj[1]) >= R_CUP + 0.02


def test_a_hand_out_of_reach_gets_no_target():
    assert target([(cup(), CUP_POSE)], TABLE + [0.8, 0.0, 0.0]) is None


def table_scene():
    """A 2 cm scene grid holding a table slab, y in [0.70, 0.75), x in [0.6, 1.4), z in [0.1, 0.9)."""
    occ = np.zeros((100, 50, 60), bool)          # origin (0, 0, 0)
    occ[30:70, 35:38, 5:45] = True
    return OccupancyGrid.from_dense(occ, [0.0, 0.0, 0.0], 0.02)


def test_the_target_is_not_inside_the_table_under_the_cup():
    scene = table_scene()
    assert scene.occupied(TABLE - [0.0, 0.02, 0.0]) and not scene.occupied(TABLE + [0.0, 0.01, 0.0])
    under = TABLE + [0.0, -0.04, 0.0]            # a hand reaching under the cup, in the slab
    # Without the scene the nearest wrist spot is below the cup's base, in the slab...
    _, free = target([(cup(), CUP_POSE)], under)
    assert scene.occupied(free)
    # ...with it, a spot out of the table and out of the cup.
    _, p = target([(cup(), CUP_POSE)], under, scene)
    assert not scene.occupied(p)
    assert_on_cup(p)


def test_no_target_when_every_candidate_is_inside_the_scene():
    everything = OccupancyGrid.from_dense(np.ones((10, 10, 10), bool), TABLE - 0.5, 0.1)
    assert target([(cup(), CUP_POSE)], NEAR_WRIST, everything) is None


def seat_scene():
    """A 2 cm scene grid: a seat x, z in [1.0, 1.5), top at 0.46 m, on a bare floor."""
    occ = np.zeros((100, 50, 100), bool)
    occ[50:75, 0:23, 50:75] = True
    return OccupancyGrid.from_dense(occ, [0.0, 0.0, 0.0], 0.02)


def test_the_object_a_hand_goal_is_done_to_is_the_nearest_within_reach():
    """`object_toward`: the x, z centre of the object nearest the goal, within reach."""
    near, far = (cup(), CUP_POSE), (book(), pose([3.0, 0.0, 3.0]))
    goal = TABLE[[0, 2]] + [0.0, -0.45]                      # standing 0.45 m from the cup's axis
    np.testing.assert_allclose(object_toward(goal, [far, near]), TABLE[[0, 2]], atol=VOX)     # the cup's axis
    np.testing.assert_allclose(object_toward([3.0, 2.6], [far, near]), [3.075, 3.1], atol=VOX)   # the book's middle
    assert object_toward(goal + [0.0, -1.0], [far, near]) is None                            # 1.4 m away: out of reach
    assert object_toward(goal, []) is None


def test_seat_height_is_the_top_of_the_seat_and_nan_over_bare_floor():
    scene = seat_scene()
    assert abs(seat_height(scene, (1.25, 1.25)) - 0.45) <= scene.voxel_size
    assert np.isnan(seat_height(scene, (0.3, 0.3)))


def test_seat_shift_puts_the_pelvis_on_the_target_and_keeps_the_feet():
    j = np.repeat((REST + [0.9, 0.0, 1.0])[None], T, 0).astype(np.float64)       # (T, 22, 3)
    labels = np.zeros(T, int)
    labels[RUN[0]:RUN[1]] = 1
    goal = [1.25, seat_height(seat_scene(), (1.25, 1.25)) + 0.10, 1.25]
    out, reach = seat_shift(j, labels, {1: [0]}, [goal])
    mid = (RUN[0] + RUN[1]) // 2
    assert np.allclose(out[mid, PELVIS], goal)
    assert np.array_equal(out[:, list(FOOT_JOINTS)], j[:, list(FOOT_JOINTS)])
    assert np.array_equal(out[:RUN[0]], j[:RUN[0]]) and np.array_equal(out[RUN[1]:], j[RUN[1]:])
    # Partway into the ramp the pelvis is partway there.
    assert 0 < np.linalg.norm(out[RUN[0], PELVIS] - j[RUN[0], PELVIS]) < np.linalg.norm(goal - j[0, PELVIS])
    frames, joints, points, weights = reach
    assert frames.tolist() == list(range(*RUN)) and set(joints.tolist()) == {PELVIS}
    assert np.allclose(points[mid - RUN[0]], goal) and weights[mid - RUN[0]] == 1.0


# -- the in-loop hand goal: the same targets, given to the network as its wrist goal ------------
def test_hand_goal_is_the_reach_target_of_the_nearer_wrist_and_only_for_hand_actions():
    objects = [(cup(), CUP_POSE), (book(), pose(TABLE + [3.0, 0.0, 0.0]))]
    reach = hand_reach(objects, None, NAMES, ("pick up",), HAND_JOINTS)
    j, _ = body_with_wrist_at(NEAR_WRIST)
    tail = np.repeat(j[:, -3:], 3, 0)                                                     # (3, 3, 22, 3)
    labels = np.array([NAMES.index("pick up"), NAMES.index("walk"), NAMES.index("pick up")])
    far = tail[2] + [0.0, 0.0, 1.5]                                                     # every joint 1.5 m off
    tail[2] = far
    joint, point = hand_goals(reach, tail, labels)
    assert joint.tolist() == [HAND_JOINTS[1], -1, -1]                                   # walk: none; out of reach: none
    assert_on_cup(point[0]) and np.isnan(point[1:]).all()
    # the same point the clean-up's reach picks for that wrist over those frames
    assert np.allclose(point[0], target(objects, NEAR_WRIST)[1], atol=1e-9)
    # the left wrist, held out to the cup's other side, gets the goal instead
    left = np.repeat((REST + (TABLE - [0.10, -0.05, 0.0] - REST[HAND_JOINTS[0]]))[None, None], 3, 1)
    joint, point = hand_goals(reach, left, labels[:1])
    assert joint.tolist() == [HAND_JOINTS[0]] and point[0, 0] < TABLE[0]


def test_hand_reach_needs_objects_and_an_action_the_checkpoint_knows():
    assert hand_reach([], None, NAMES, ("pick up",), HAND_JOINTS) is None
    assert hand_reach([(cup(), CUP_POSE)], None, ["walk"], ("pick up",), HAND_JOINTS) is None
    assert hand_reach([(cup(), CUP_POSE)], None, NAMES, (), HAND_JOINTS) is None
    r = hand_reach([(cup(), CUP_POSE)], None, NAMES, ("pick up",), (HAND_JOINTS[1],))
    assert r.hands == (HAND_JOINTS[1],) and r.actions == (NAMES.index("pick up"),)
