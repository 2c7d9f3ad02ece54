"""Metrics on hand-made motions with known answers."""

import numpy as np
import pytest

from motiongen.scene.distance_field import surface_distance
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.metrics import (apd, body_metrics, contact_rate, floor_penetration, foot_skating_ratio,
                                    goal_distances, goal_success, heading_off_travel, knee_angles, leg_knee_angles,
                                    lower_toe_height, mean_jerk, pskl, walking_knee_angle,
                                    scene_penetration, seam_jump, trajectory_fail_rate)
from motiongen.geometry import yaw_matrix
from motiongen.skeleton import BODY_PARENTS, FOOT_JOINTS, LEFT_HIP, PELVIS, RIGHT_HIP

FPS = 30.0
TOES = (10, 11)


def still(T=31, J=22, y=1.0):
    """(T, J, 3): every joint at height y, not moving."""
    j = np.zeros((T, J, 3))
    j[..., 1] = y
    return j


def with_feet(j, y, vx, frames=None):
    """Put both toe joints at height y, sliding along x at vx m/s over `frames` transitions."""
    T = len(j)
    steps = np.zeros(T - 1)
    steps[slice(None) if frames is None else frames] = vx / FPS
    x = np.concatenate([[0.0], np.cumsum(steps)])
    for k in TOES:
        j[:, k, 1], j[:, k, 0] = y, x
    return j


def walking(direction_deg: float, facing_deg: float, speed: float = 1.0, T: int = 31) -> np.ndarray:
    """(T, 22, 3): a pelvis moving at `speed` m/s along the ground direction `direction_deg`
    (0 = +z, 90 = +x), its hips turned to face `facing_deg` (SMPL-X: facing +z, left is +x)."""
    j = still(T)
    go = np.radians(direction_deg)
    t = np.arange(T)[:, None] / FPS
    j[:, :, [0, 2]] += speed * t[:, None] * np.array([np.sin(go), np.cos(go)])
    across = yaw_matrix(np.radians(facing_deg)) @ np.array([0.1, 0.0, 0.0])               # left hip from the pelvis
    j[:, LEFT_HIP] = j[:, PELVIS] + across
    j[:, RIGHT_HIP] = j[:, PELVIS] - across
    return j


def legs_bent(j: np.ndarray, knee_deg: float) -> np.ndarray:
    """joints (T, 22, 3) with both legs hanging from their hips, thigh and shin 0.4 m, the knees
    bent forward to an angle of knee_deg between thigh and shin (180: straight)."""
    j = j.copy()
    half = np.radians(knee_deg) / 2
    for hip, knee, ankle in ((1, 4, 7), (2, 5, 8)):
        j[:, knee] = j[:, hip] + 0.4 * np.array([0.0, -np.sin(half), np.cos(half)])
        j[:, ankle] = j[:, knee] + 0.4 * np.array([0.0, -np.sin(half), -np.cos(half)])
    return j


def test_walking_knee_angle_is_the_angle_between_thigh_and_shin_while_walking():
    """Knees bent to 150° (and 110°, a crouch) on a body walking at 1 m/s read 150° (110°);
    straight legs 180°; a body that walks slower than 0.5 m/s, or stands, has no walking frame."""
    for deg in (150.0, 110.0, 180.0):
        assert walking_knee_angle(legs_bent(walking(30, 30), deg), FPS) == pytest.approx(deg, abs=1e-6)
    # Only the walking frames count: a crouch while standing still does not.
    j = legs_bent(walking(0, 0, T=61), 150.0)
    j[31:, :, [0, 2]] = j[30][:, [0, 2]]
    j[32:] = legs_bent(j[32:], 90.0)
    assert walking_knee_angle(j, FPS) == pytest.approx(150.0, abs=1e-6)
    assert np.isnan(walking_knee_angle(legs_bent(walking(0, 0, speed=0.3), 150.0), FPS))
    assert np.isnan(walking_knee_angle(still(), FPS))
    # each knee on its own: the right leg at 110° beside a left one at 150° (their mean, 130°)
    j = legs_bent(walking(30, 30), 150.0)
    j[:, [2, 5, 8]] = legs_bent(walking(30, 30), 110.0)[:, [2, 5, 8]]
    np.testing.assert_allclose(leg_knee_angles(j), np.tile([150.0, 110.0], (len(j), 1)), atol=1e-6)
    np.testing.assert_allclose(knee_angles(j), 130.0, atol=1e-6)


def test_lower_toe_height_is_the_median_of_the_lower_toe():
    """Toes at 2 cm and 30 cm (one swinging): the lower one, 0.02 m, every frame; the whole body
    lifted by 5 cm reads 0.07 m, and it no longer skates by the skating figure (its toes are
    over the 5 cm line) although its feet slide at 1 m/s; a floor at y = 0.05 gives 0.02 again."""
    j = still(40)
    j[:, TOES[0], 1], j[:, TOES[1], 1] = 0.02, 0.30
    j[:, :, 0] += np.arange(40)[:, None] / FPS                                         # the whole body slides at 1 m/s
    assert lower_toe_height(j) == pytest.approx(0.02)
    assert foot_skating_ratio(j, FPS) > 0.9
    up = j + np.array([0.0, 0.05, 0.0])
    assert lower_toe_height(up) == pytest.approx(0.07) and foot_skating_ratio(up, FPS) == 0
    assert lower_toe_height(up, floor_y=0.05) == pytest.approx(0.02)
    assert np.isnan(lower_toe_height(np.zeros((0, 22, 3))))
    assert body_metrics(j, FPS, BODY_PARENTS)["toe_height_m"] == pytest.approx(0.02)


def test_lower_toe_height_leaves_out_a_body_lying_down():
    """30 of 40 frames lying on a 0.5 m bed (pelvis and toes at the bed's height): the figure is
    the 10 standing frames' 0.02 m, not the bed's; seated (pelvis 0.45 m over feet on the floor)
    counts as on its feet; lying throughout gives NaN."""
    j = still(40)
    j[:, TOES[0], 1], j[:, TOES[1], 1] = 0.02, 0.30
    j[10:, :, 1] = 0.5 + np.linspace(0.0, 0.2, 22)[None]                             # lying: every joint within 0.2 m of the bed
    assert lower_toe_height(j) == pytest.approx(0.02)
    seated = still(20, y=0.47)
    seated[:, TOES, 1] = 0.02
    assert lower_toe_height(seated) == pytest.approx(0.02)
    assert np.isnan(lower_toe_height(j[10:]))


def test_heading_off_travel_is_the_angle_between_facing_and_going():
    # Walking facing where it goes: 0; sideways (crab): 90; at 30 degrees: 30, whichever way
    # the path runs; backwards: 180; standing or too slow: NaN.
    assert heading_off_travel(walking(0, 0), FPS) == pytest.approx(0.0, abs=1e-6)
    assert heading_off_travel(walking(120, 120), FPS) == pytest.approx(0.0, abs=1e-6)
    assert heading_off_travel(walking(90, 0), FPS) == pytest.approx(90.0, abs=1e-6)
    assert heading_off_travel(walking(-45, -15), FPS) == pytest.approx(30.0, abs=1e-6)
    assert heading_off_travel(walking(200, 20), FPS) == pytest.approx(180.0, abs=1e-6)
    assert np.isnan(heading_off_travel(walking(0, 0, speed=0.3), FPS))
    assert np.isnan(heading_off_travel(still(), FPS))


# --- foot skating ------------------------------------------------------------------------

def test_skating_planted_feet_is_zero():
    assert foot_skating_ratio(with_feet(still(), 0.02, 0.0), FPS) == 0.0


def test_skating_sliding_on_floor_is_one():
    assert foot_skating_ratio(with_feet(still(), 0.02, 1.0), FPS) == 1.0


def test_skating_needs_both_height_and_speed():
    assert foot_skating_ratio(with_feet(still(), 0.10, 1.0), FPS) == 0.0   # swinging foot, above 5 cm
    assert foot_skating_ratio(with_feet(still(), 0.02, 0.4), FPS) == 0.0   # slow creep under 0.5 m/s


def test_skating_half_clip():
    # 15 of 30 transitions slide at 1 m/s; the last sliding transition's 5-frame average is
    # 3/5 = 0.6 m/s > 0.5, so all 15 count.
    j = with_feet(still(T=31), 0.02, 1.0, frames=slice(0, 15))
    assert foot_skating_ratio(j, FPS) == pytest.approx(0.5)


def test_skating_single_spike_is_averaged_away():
    # one transition at 2 m/s: its window average is 2/5 = 0.4 m/s < 0.5
    j = with_feet(still(T=31), 0.02, 2.0, frames=slice(10, 11))
    assert foot_skating_ratio(j, FPS) == 0.0
    assert foot_skating_ratio(j, FPS, window=1) == pytest.approx(1 / 30)


def test_skating_foot_joint_choice():
    j = still()
    j[:, 7, 1] = 0.02                                  # left ankle low and sliding, toes high
    j[:, 7, 0] = np.arange(len(j)) / FPS
    assert foot_skating_ratio(j, FPS) == 0.0           # default: toes only (GMD)
    assert foot_skating_ratio(j, FPS, foot_joints=FOOT_JOINTS) == 1.0


# --- goals -------------------------------------------------------------------------------

def line_walk(T=31):
    j = still(T)
    j[:, PELVIS, 0] = np.linspace(0, 3, T)             # pelvis along x from 0 to 3 m
    return j


def test_goal_distances_in_order():
    d = goal_distances(line_walk(), [[1, 0.1], [2, -0.3], [3, 0.0]])
    np.testing.assert_allclose(d, [0.1, 0.3, 0.0], atol=1e-12)


def test_goal_distances_order_matters_and_3d_goals():
    # after reaching (3, 0) at the last frame, the goal at x=1 is 2 m behind
    d = goal_distances(line_walk(), np.array([[3, 5.0, 0], [1, 5.0, 0]]))
    np.testing.assert_allclose(d, [0.0, 2.0], atol=1e-12)


def test_goal_distances_arrival_frames():
    np.testing.assert_allclose(goal_distances(line_walk(), [[1, 0], [3, 0]], arrival_frames=[0, 30]), [1.0, 0.0])


def test_goal_success_and_fail_rate():
    assert goal_success(np.array([0.1, 0.3, 0.6])) == pytest.approx({0.2: 1 / 3, 0.5: 2 / 3})
    assert goal_success([np.array([0.1]), np.array([0.3, 0.6])], thresholds=(0.5,)) == pytest.approx({0.5: 2 / 3})
    assert trajectory_fail_rate([np.array([0.1, 0.2]), np.array([0.1, 0.6])], threshold=0.5) == 0.5


# --- penetration and contact ---------------------------------------------------------------

def box_grid(top=0.5):
    """2 cm grid over [0, 2]^3 m; a solid box x, z in [0.5, 1.5], y in [0, top]."""
    vs = 0.02
    occ = np.zeros((100, 100, 100), bool)
    occ[25:75, :int(round(top / vs)), 25:75] = True
    return OccupancyGrid.from_dense(occ, origin=[0, 0, 0], voxel_size=vs)


def test_surface_distance_box():
    grid = box_grid()
    sdf = surface_distance(grid)
    assert surface_distance(grid) is sdf                  # built once, kept with the grid
    d = sdf(np.array([[1.0, 0.7, 1.0], [1.0, 0.4, 1.0], [1.0, 0.3, 0.6], [0.2, 0.3, 1.0], [1.0, 0.3, 0.5]]))
    np.testing.assert_allclose(d, [0.2, -0.1, -0.1, 0.3, 0.0], atol=0.011)
    # Off the grid: free, the true distance to the box (above it, and beside it at y = 0.25).
    off = sdf(np.array([[1.0, 2.5, 1.0], [-1.5, 0.25, 1.0], [1.0, 0.25, 3.5]]))
    np.testing.assert_allclose(off, [2.0, 2.0, 2.0], atol=0.02)
    # The floor half-space: a point 5 cm up, far from the box, is 5 cm from a surface.
    with_floor = surface_distance(grid, floor_y=0.0)
    assert with_floor(np.array([[0.2, 0.05, 0.2]]))[0] == pytest.approx(0.05)
    assert with_floor(np.array([[1.0, 0.7, 1.0]]))[0] == pytest.approx(0.2, abs=0.011)   # the box is nearer
    assert sdf(np.array([[0.2, 0.05, 0.2]]))[0] > 0.2     # the kept field has no floor
    empty = surface_distance(OccupancyGrid.from_dense(np.zeros((4, 4, 4), bool), [0, 0, 0], 0.1))
    assert empty(np.zeros((1, 3)))[0] >= 100.0             # no surface at all: far


def test_scene_penetration_depth_and_ratio():
    j = still(T=4, J=22, y=1.8)
    j[0, 3] = [1.0, 0.4, 1.0]                          # 10 cm deep in frame 0
    j[1, 5] = [1.0, 0.45, 1.0]                         # 5 cm deep in frame 1
    r = scene_penetration(j, box_grid())
    assert r["frame_ratio"] == 0.5
    assert r["mean_depth"] == pytest.approx(0.075, abs=0.011)
    assert r["max_depth"] == pytest.approx(0.10, abs=0.011)
    v = np.full((4, 5, 3), 1.8)
    v[3, 2] = [1.0, 0.3, 1.0]                          # a vertex 20 cm deep in frame 3
    assert scene_penetration(j, box_grid(), vertices=v)["frame_ratio"] == 0.75
    assert scene_penetration(still(4), box_grid())["frame_ratio"] == 0.0


def test_floor_penetration():
    j = still(T=4, y=0.5)
    j[1, 0, 1] = -0.03
    j[2, 4, 1] = -0.01
    r = floor_penetration(j)
    assert r["frame_ratio"] == 0.5
    assert r["mean_depth"] == pytest.approx(0.02) and r["max_depth"] == pytest.approx(0.03)
    assert floor_penetration(j, tol=0.02)["frame_ratio"] == 0.25


def test_contact_rate_sit():
    grid = box_grid(top=0.44)                          # a seat top at y = 0.44
    j = still(T=4, y=1.5)
    j[:, PELVIS] = [[1.0, 0.55, 1.0], [1.0, 0.55, 1.0], [1.0, 0.9, 1.0], [1.0, 0.55, 1.0]]
    actions = np.array([[1, 0], [1, 0], [1, 0], [0, 1]], bool)      # frame 3 labelled "walk"
    r = contact_rate(j, actions, ["sit", "walk"], grid)
    # pelvis 11 cm above the seat, less its 10 cm skin offset: touching; 46 cm: not
    assert r == pytest.approx({"sit": 2 / 3, "all": 2 / 3})
    assert contact_rate(j, actions, ["sit", "walk"], grid, skin_offset={})["sit"] == 0.0


# --- diversity and smoothness ------------------------------------------------------------

def test_apd():
    base = np.random.default_rng(0).normal(size=(10, 22, 3))
    s = np.stack([base, base + 0.1, base + 0.3])        # pairwise norms 0.1, 0.3, 0.2 times sqrt(660)
    assert apd(s) == pytest.approx(0.2 * np.sqrt(10 * 22 * 3))
    with pytest.raises(ValueError):
        apd(s[:1])


def test_mean_jerk_of_cubic_is_exact():
    t = np.arange(20) / FPS
    j = np.zeros((20, 22, 3))
    j[..., 0] = (2.0 * t ** 3)[:, None]                 # jerk = 6 * 2 = 12 m/s^3
    assert mean_jerk(j, FPS) == pytest.approx(12.0)
    j[..., 0] = (0.5 * t ** 2)[:, None]
    assert mean_jerk(j, FPS) == pytest.approx(0.0, abs=1e-9)


def test_seam_jump():
    j = still(T=30)
    x = np.arange(30) * 0.01
    x[20:] += 0.09                                      # episode 2 starts at frame 20, 9 cm off
    j[..., 0] = x[:, None]
    s = seam_jump(j, [20])
    assert s.seam == pytest.approx(0.10) and s.elsewhere == pytest.approx(0.01)
    assert s.ratio == pytest.approx(10.0)


# --- PSKL ----------------------------------------------------------------------------------

def pskl_reference(A, B):
    """Eqs. 10-11 spelled out with loops over features and frequencies."""
    def spectra(S):
        F = S[0][2:].size // (len(S[0]) - 2)
        out = []
        for f in range(F):
            ps = np.mean([np.abs(np.fft.fft(np.diff(m.reshape(len(m), -1)[:, f], n=2))) ** 2 for m in S], axis=0)
            out.append(ps / ps.sum())
        return out
    pa, pb = spectra(A), spectra(B)
    return np.mean([sum(p[e] * np.log(p[e] / q[e]) for e in range(len(p))) for p, q in zip(pa, pb)])


def test_pskl_matches_the_formula_and_is_asymmetric():
    rng = np.random.default_rng(1)
    t = np.arange(40)[:, None, None]
    A = [np.sin(0.3 * t + rng.normal(size=(1, 2, 3))) + 0.1 * rng.normal(size=(40, 2, 3)) for _ in range(3)]
    B = [np.cumsum(rng.normal(size=(40, 2, 3)), axis=0) for _ in range(4)]
    ab, ba = pskl(A, B, FPS, eps=0)
    assert ab == pytest.approx(pskl_reference(A, B), rel=1e-9)
    assert ba == pytest.approx(pskl_reference(B, A), rel=1e-9)
    assert ab > 0 and ba > 0 and abs(ab - ba) > 1e-3


def test_pskl_zero_for_same_spectrum_and_scale_free():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(3, 32, 22, 3))
    assert pskl(A, A, FPS) == pytest.approx((0.0, 0.0), abs=1e-12)
    assert pskl(A, 3.0 * A, FPS) == pytest.approx((0.0, 0.0), abs=1e-9)   # normalised spectra
    # different lengths: cut to the shortest
    assert pskl(list(A), [A[0][:20]], FPS)[0] >= 0


# --- one body: bone lengths and grounded feet ----------------------------------------------

def _rigid_walk(T=40):
    from tests.helpers import walking_sequence
    return walking_sequence(T, [0.0, 0.0], 0.2, 0.4, 1.2).astype(np.float64)          # rotating, translating


def test_rigid_motion_has_zero_bone_variation():
    from motiongen.metrics import bone_consistency
    from motiongen.skeleton import BODY_PARENTS
    b = bone_consistency(_rigid_walk(), BODY_PARENTS)
    assert b.cv_median < 1e-6 and b.cv_max < 1e-6 and b.max_deviation < 1e-6


def test_stretched_bone_shows_its_deviation():
    from motiongen.metrics import bone_consistency, bone_lengths
    from motiongen.skeleton import BODY_PARENTS, LEFT_HIP
    j = _rigid_walk()
    # frame 10: the pelvis joint moves 0.5 m up, away from its body (a pinned joint left behind)
    j[10, PELVIS, 1] += 0.5
    b = bone_consistency(j, BODY_PARENTS)
    L = bone_lengths(_rigid_walk(), BODY_PARENTS)[0]
    kids = [c for c, p in enumerate(BODY_PARENTS) if p >= 0]
    hip = L[kids.index(LEFT_HIP)]                                                      # 0.122 m pelvis -> hip
    stretched = np.hypot(0.09, 0.07 + 0.5)                                              # |(0.09, -0.07 - 0.5)|
    assert b.max_deviation == pytest.approx((stretched - hip) / hip, rel=1e-6)
    assert b.worst_bone in (1, 2, 3)                                                    # a bone of the pelvis


def test_grounded_slide_is_the_drag_speed():
    from motiongen.metrics import grounded_slide
    assert grounded_slide(with_feet(still(), 0.02, 0.0), FPS) == 0.0                    # planted
    assert grounded_slide(with_feet(still(), 0.02, 0.3), FPS) == pytest.approx(0.3)     # dragged at 0.3 m/s
    assert np.isnan(grounded_slide(with_feet(still(), 0.2, 0.3), FPS))                  # never on the floor
    # half the 32 transitions dragged at 1 m/s, half planted: the median of equally many 1s and 0s
    j = with_feet(still(T=33), 0.02, 1.0, frames=slice(0, 16))
    assert grounded_slide(j, FPS) == pytest.approx(0.5)
