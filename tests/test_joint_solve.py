"""The final solve in joint space: the objective's exact minimum, the limbs' soft reach and
bending plane, and the twist hints interpolated between model frames."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from motiongen.body.joint_solve import LIMB_JOINTS, TRUNK, follow_locks, held_limbs, into_reach, solve_joints
from motiongen.body.limbs import LIMBS, limb_lengths, place_limbs, two_bone
from motiongen.body.rotations import axis_angle_to_matrix
from motiongen.body.solve import SOLVE_CONFIG
from motiongen.errors import ConfigError
from motiongen.sampling.assemble import interpolate_rotations, solve_bodies
from motiongen.skeleton import FOOT_JOINTS, HAND_JOINTS


def _objective(Y, X, cfg, planted, reach):
    """`fit.refine`'s joint terms written out on joints Y (T, 22, 3) (torch), term by term; a
    lock span's centre is its own mean, upwards (cfg.lock_height) the mean of X's heights."""
    T = Y.shape[0]
    loss = cfg.w_joints * (Y - X).square().sum(-1).mean()
    acc = (Y[2:] - 2 * Y[1:-1] + Y[:-2]).square().sum(-1)                          # (T-2, 22)
    w = torch.full((22,), cfg.w_smooth_joints, dtype=Y.dtype)
    if cfg.w_smooth_contact is not None:
        w[list(FOOT_JOINTS)] = cfg.w_smooth_contact
    loss = loss + (w * acc).mean()
    on, sq = 0, 0.0
    for c, j in enumerate(FOOT_JOINTS):
        col = planted[:, c]
        t = 0
        while t < T:                                            # each run of planted frames
            if not col[t]:
                t += 1
                continue
            e = t
            while e < T and col[e]:
                e += 1
            span = Y[t:e, j]
            centre = span.mean(0)
            if cfg.lock_height:
                centre = torch.stack([centre[0], X[t:e, j, 1].mean(), centre[2]])
            sq = sq + (span - centre).square().sum()
            on += e - t
            t = e
    loss = loss + cfg.w_contact * sq / on
    loss = loss + cfg.w_floor * (cfg.floor_y - Y[..., 1]).clamp(min=0).square().sum(-1).mean()
    swing = torch.as_tensor(~planted, dtype=Y.dtype)
    short = (X[:, list(FOOT_JOINTS), 1] - Y[:, list(FOOT_JOINTS), 1]).clamp(min=0) * swing
    loss = loss + cfg.w_clearance * short.square().sum() / swing.sum()
    f, j, p, w = reach
    loss = loss + cfg.w_reach * (w * (Y[f, j] - p).square().sum(-1)).sum() / w.sum()
    return loss


@pytest.mark.parametrize("feet,held", [(None, True), (400.0, True), (None, False)])
def test_solve_joints_is_the_objectives_minimum(feet, held):
    """Every term of the final solve at once (locks, reach, floor and clearance active on some
    entries; the feet's own acceleration weight or not; lock spans held at a height or not):
    the objective is convex, so a zero gradient is its global minimum."""
    rng = np.random.default_rng(0)
    T = 40
    X = rng.normal(0, 0.05, (T, 22, 3)) + np.linspace(0, 1, T)[:, None, None] * [1, 0, 0]
    X[..., 1] += 0.5
    X[:, list(FOOT_JOINTS), 1] = rng.uniform(-0.02, 0.1, (T, 4))            # feet around the floor
    planted = np.zeros((T, 4), bool)
    planted[3:12, 0] = planted[20:31, 1] = planted[5:9, 2] = True
    reach = (np.array([10, 11, 12, 30]), np.array([HAND_JOINTS[0]] * 3 + [0]),
             rng.normal(0, 0.3, (4, 3)), np.array([0.5, 1.0, 0.5, 2.0]))
    cfg = replace(SOLVE_CONFIG, w_smooth_joints=50.0, w_smooth_contact=feet, floor_y=0.003, lock_height=held)
    Y = solve_joints(X, cfg, planted, FOOT_JOINTS, reach)
    Yt = torch.tensor(Y, requires_grad=True)
    Xt = torch.as_tensor(X)
    rt = tuple(torch.as_tensor(a) for a in reach)
    loss = _objective(Yt, Xt, cfg, planted, rt)
    loss.backward()
    assert (Yt[..., 1] < cfg.floor_y).any()                                  # the floor term is on somewhere
    # a zero gradient, against the gradient's size at the prediction itself
    X0 = torch.tensor(X, requires_grad=True)
    _objective(X0, Xt, cfg, planted, rt).backward()
    assert Yt.grad.abs().max() < 1e-9 * max(1.0, float(X0.grad.abs().max())) + 1e-10
    # and lower than the prediction and than a small step away from Y in any direction
    with torch.no_grad():
        for _ in range(5):
            step = torch.as_tensor(rng.normal(0, 1e-3, Y.shape))
            assert _objective(Yt + step, Xt, cfg, planted, rt) > loss


def test_a_planted_span_holds_one_spot_and_the_rest_is_smoothed():
    """A foot sliding 10 cm while flagged planted stays within a millimetre of one spot; a joint
    with 2 cm of frame-to-frame noise comes out smoother, its mean unchanged."""
    rng = np.random.default_rng(1)
    T = 60
    X = np.zeros((T, 22, 3))
    X[:, :, 1] = 0.5
    X[:, FOOT_JOINTS[0], 0] = np.linspace(0, 0.1, T)
    X[:, 15] += rng.normal(0, 0.02, (T, 3))
    planted = np.zeros((T, 4), bool)
    planted[10:50, 0] = True
    Y = solve_joints(X, replace(SOLVE_CONFIG, w_smooth_joints=50.0, w_floor=0.0), planted, FOOT_JOINTS)
    span = Y[10:50, FOOT_JOINTS[0]]
    assert np.linalg.norm(span - span.mean(0), axis=-1).max() < 1e-3
    d2 = lambda a: np.linalg.norm(a[2:] - 2 * a[1:-1] + a[:-2], axis=-1).mean()
    assert d2(Y[:, 15]) < 0.2 * d2(X[:, 15])
    np.testing.assert_allclose(Y[:, 15].mean(0), X[:, 15].mean(0), atol=2e-3)


def test_a_planted_span_is_held_at_the_heights_given():
    """A foot predicted 5 cm up while flagged planted, its heights given as 2 cm (the network's
    own, where the prediction is the projected body's): the span is held at 2 cm, within a
    millimetre, and still; across the floor the solve is the same as without held heights."""
    T = 60
    X = np.zeros((T, 22, 3))
    X[:, :, 1] = 0.5
    j = FOOT_JOINTS[1]
    X[:, j, 1] = 0.05
    X[:, j, 0] = np.linspace(0, 0.1, T)
    planted = np.zeros((T, 4), bool)
    planted[10:50, 1] = True
    heights = X[:, list(FOOT_JOINTS), 1].copy()
    heights[:, 1] = 0.02
    cfg = replace(SOLVE_CONFIG, w_smooth_joints=50.0, w_floor=0.0, w_clearance=0.0)
    Y = solve_joints(X, cfg, planted, FOOT_JOINTS, planted_heights=heights)
    np.testing.assert_allclose(Y[15:45, j, 1], 0.02, atol=1e-3)
    free = solve_joints(X, replace(cfg, lock_height=False), planted, FOOT_JOINTS, planted_heights=heights)
    np.testing.assert_allclose(free[10:50, j, 1], 0.05, atol=1e-3)       # the lock leaves the height alone
    np.testing.assert_allclose(Y[..., [0, 2]], free[..., [0, 2]])         # across the floor: the same solve


def test_soft_reach_never_snaps_the_knee():
    """A target walking out through the chain's full reach and back: hard IK moves the knee by
    far more than the target's step near full extension (the bend grows as the square root of
    the slack); soft IK keeps the knee's step within a few target steps and the end within reach."""
    upper, lower = torch.tensor(0.41, dtype=torch.float64), torch.tensor(0.44, dtype=torch.float64)
    root = torch.zeros(3, dtype=torch.float64)
    pole = torch.tensor([0.0, -0.4, 0.2], dtype=torch.float64)
    step = 0.002
    d = torch.cat([torch.arange(0.80, 0.90, step), torch.arange(0.90, 0.80, -step)]).double()
    target = torch.stack([torch.zeros_like(d), -d, torch.zeros_like(d)], -1)        # (N, 3) straight down
    out = {}
    for soft in (0.0, 0.03):
        mid, end = two_bone(root.expand_as(target), target, pole.expand_as(target), upper, lower, soft)
        out[soft] = (mid[1:] - mid[:-1]).norm(dim=-1).max().item()
        assert end.norm(dim=-1).max() < upper + lower
        assert ((mid - root).norm(dim=-1) - upper).abs().max() < 1e-9             # bones keep their lengths
    assert out[0.0] > 10 * step
    assert out[0.03] < 4 * step


def test_the_bend_comes_from_the_bend_pose_and_never_backwards(bm):
    """A standing leg whose ankle was moved 10 cm up with its knee left where it was: the knee
    sits on the new hip-ankle line, so alone it gives no bending plane; with the pose before the
    move (`bend`) the knee bends forward (+z, the body faces +z), as it does when that pose is
    itself bent a little backwards."""
    rest = bm.rest_joints(torch.zeros(bm.num_betas)).double()                          # (22, 3) facing +z
    knee, ankle = 4, 7
    for back in (0.0, -0.01):
        bend = rest.clone()
        bend[knee, 2] += back                                                          # straight, or over-straight
        X = rest.clone()
        X[ankle, 1] += 0.10
        X[knee] = X[1] + (X[ankle] - X[1]) * 0.5                                       # on the new line
        P = place_limbs(rest[None], X[None], rest[None], bend[None])[0]
        assert P[knee, 2] - rest[knee, 2] > 0.05                                       # bent forward
        np.testing.assert_allclose(P[ankle].numpy(), X[ankle].numpy(), atol=1e-9)


def test_twist_hints_are_interpolated_between_model_frames():
    """Rotations about y of 0°, 170°, 190° at 10 fps read at 30 fps: model frames come back, and
    between them the angle moves linearly in the middle and the short way round past 180°."""
    angles = np.radians([0.0, 170.0, 190.0])
    aa = torch.zeros(3, 2, 3, dtype=torch.float64)
    aa[:, 0, 1] = torch.as_tensor(angles)
    R = axis_angle_to_matrix(aa)                                                       # (3, 2, 3, 3)
    t = np.array([0.0, 0.05, 0.1, 0.15, 0.2])
    out = interpolate_rotations(R, 10.0, t)
    assert (out[[0, 2, 4]] - R).abs().max() < 1e-9
    half = axis_angle_to_matrix(torch.tensor([[0.0, math.radians(85.0), 0.0]], dtype=torch.float64))
    assert (out[1, 0] - half[0]).abs().max() < 1e-9                                    # the midpoint is exact
    past = axis_angle_to_matrix(torch.tensor([[0.0, math.pi, 0.0]], dtype=torch.float64))
    assert (out[3, 0] - past[0]).abs().max() < 1e-9                                    # 180°, not back through 0°


def test_an_unknown_solve_method_is_a_config_error(bm):
    with pytest.raises(ConfigError, match="loop.solve"):
        solve_bodies(None, np.zeros((1, 4, 22, 3)), torch.zeros(1, 2, 22, 3, 3), None, FOOT_JOINTS, 10.0, 30.0,
                     method="newton")



def test_into_reach_brings_the_hips_to_a_far_planted_foot(bm):
    """A standing body whose left ankle the joint-space solve left 12 cm beyond the leg's length
    for 10 frames (a step, the hardest case for a smoothed shift): the trunk moves towards it,
    smoothly and by about what it needs, the ankle is then within reach but for a centimetre at
    the step's edges (the legs' soft IK takes that), and the limbs' ends stay where they were."""
    rest_t = bm.rest_joints(torch.zeros(bm.num_betas)).double()
    rest, lengths = rest_t.numpy(), limb_lengths(rest_t).numpy()                       # (22, 3), (4,)
    T = 40
    Y = np.repeat(rest[None], T, 0)
    hip, ankle = LIMBS[0][0], LIMBS[0][2]
    leg = rest[ankle] - rest[hip]
    Y[15:25, ankle] = rest[hip] + leg / np.linalg.norm(leg) * (lengths[0] + 0.12)
    out = into_reach(Y, lengths, held_limbs(T, None), sigma=3.0)
    before = np.linalg.norm(Y[:, ankle] - Y[:, hip], axis=-1) - lengths[0]
    after = np.linalg.norm(out[:, ankle] - out[:, hip], axis=-1) - lengths[0]
    assert before.max() > 0.119 and after.max() < 0.015
    right = LIMBS[1]
    assert (np.linalg.norm(out[:, right[2]] - out[:, right[0]], axis=-1) <= lengths[1] + 1e-6).all()
    moved = np.linalg.norm(out - Y, axis=-1)                                           # (T, 22)
    ends = [j for limb in LIMB_JOINTS for j in limb]
    assert moved[:, ends].max() == 0
    np.testing.assert_allclose(moved[:, list(TRUNK)], moved[:, :1].repeat(len(TRUNK), 1))   # the trunk as one
    assert 0.11 <= moved[20, 0] < 0.16                                                 # about what it needs
    assert moved[0, 0] < 3e-3 and moved[-1, 0] < 3e-3                                  # and only around the span
    step = np.linalg.norm(np.diff(out[:, 0], axis=0), axis=-1)
    assert step.max() < 0.06                                                           # eased in, not a 12 cm jump


def test_follow_locks_moves_the_trunk_by_the_held_feet_moves():
    """Known answer: where both feet of a standing body are held 10 cm from their targets the
    trunk moves by that mean across the floor; where only one foot joint pair is held, by
    half; where none is, not at all; limbs' middles and ends stay where the solve put them."""
    T = 9
    X = np.zeros((T, 22, 3))
    Y = X.copy()
    Y[:, list(FOOT_JOINTS), 0] += 0.1                                  # the lock moved every foot joint 10 cm in x
    planted = np.zeros((T, 4), bool)
    planted[:3] = True                                                 # both feet held
    planted[3:6, :2] = True                                            # the left foot only
    out = follow_locks(Y, X, planted, FOOT_JOINTS, 0.0)
    trunk = list(TRUNK)
    np.testing.assert_allclose(out[:3][:, trunk, 0], 0.1)
    np.testing.assert_allclose(out[3:6][:, trunk, 0], 0.05)
    np.testing.assert_allclose(out[6:][:, trunk], 0.0)
    np.testing.assert_allclose(out[:, trunk, 1:], 0.0)                 # nothing up or sideways
    others = [j for j in range(22) if j not in TRUNK]
    np.testing.assert_array_equal(out[:, others], Y[:, others])
    assert follow_locks(Y, X, None, FOOT_JOINTS, 3.0) is Y
