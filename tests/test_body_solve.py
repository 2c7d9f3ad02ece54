"""One body per motion: projection keeps bone lengths whatever the input, foot locking plants feet."""

import os

import numpy as np
import pytest
import torch

from motiongen.body.random_motion import sample_motion
from motiongen.body.solve import MotionBody
from motiongen.metrics import bone_consistency, grounded_slide
from motiongen.sampling.assemble import PARALLEL_MIN_SAMPLES, parallel_solves, solve_bodies
from motiongen.skeleton import BODY, BODY_PARENTS, FOOT_JOINTS, JOINT_SETS


def _posed(bm, T, seed, gait=False):
    p = sample_motion(T, rng=np.random.default_rng(seed), gait=gait)
    t = {k: torch.as_tensor(v) for k, v in p.items()}
    with torch.no_grad():
        X = bm.joints(t["global_orient"], t["body_pose"], t["transl"], t["betas"])      # (T, 22, 3)
    return X.double().numpy(), t["betas"]


def test_projection_recovers_a_body_and_is_rigid_on_noise(bm):
    X, betas = _posed(bm, 16, seed=0)
    body = MotionBody(bm, BODY, betas[None])
    J, R, transl = body.project(X[None])
    assert np.abs(J[0] - X).max() < 1e-4                                  # a body's joints come back as they were
    noisy = X + np.random.default_rng(1).normal(0, 0.05, X.shape)        # 5 cm of noise on every joint
    Jn, _, _ = body.project(noisy[None])
    assert bone_consistency(noisy, BODY_PARENTS).cv_median > 0.05
    b = bone_consistency(Jn[0], BODY_PARENTS)
    assert b.max_deviation < 1e-5                                         # rigid again
    np.testing.assert_allclose(Jn[0, :, 0], noisy[:, 0])                  # the root stays where it was predicted


def test_estimate_finds_the_shape(bm):
    X, betas = _posed(bm, 16, seed=2)
    body = MotionBody.estimate(bm, BODY, X[None])
    true = bm.rest_joints(betas)
    est = body.rest[0]
    assert (true - est).norm(dim=-1).max() < 0.005                      # bone lengths within 5 mm


def test_index_fingers_ride_on_the_wrists(bm):
    X, betas = _posed(bm, 8, seed=3)
    js = JOINT_SETS["body+index1"]
    body = MotionBody(bm, js, betas[None])
    J, _, _ = body.project(X[None])
    assert J.shape == (1, 8, 24, 3)
    for k in (22, 23):
        wrist = js.index(js.names[k].replace("index1", "wrist"))
        d = np.linalg.norm(J[0, :, k] - J[0, :, wrist], axis=-1)
        assert np.ptp(d) < 1e-5 and 0.05 < d[0] < 0.15                  # a rigid hand, 5-15 cm long


def _solve(body, method, X, R, planted, cfg=None):
    """The final solve of sample 0 by each method (`assemble.SOLVE_METHODS`); `refined` as the
    sampler runs it, at one frame rate (no resampling)."""
    if method == "lbfgs":
        return body.solve(0, X, R, planted, FOOT_JOINTS, cfg=cfg)
    if method == "refined":
        return solve_bodies(body, X[None], R[None], None if planted is None else planted[None], FOOT_JOINTS,
                            30.0, 30.0, cfg=cfg, method="refined")[0]
    return body.solve_joint_space(0, X, R, planted, FOOT_JOINTS, cfg=cfg)


METHODS = pytest.mark.parametrize("method", ["joint-space", "lbfgs", "refined"])


@METHODS
def test_foot_locking_plants_a_sliding_foot(bm, method):
    """A standing body whose predicted left foot slides 8 cm along the floor and jitters by 1 cm
    while flagged planted: after the solve it stays within 1 cm of one spot over the span, and
    the rest of the body still follows the prediction."""
    T = 40
    X, betas = _posed(bm, 1, seed=4)
    X = np.repeat(X, T, 0)                                                  # (T, 22, 3) standing still
    X[..., 1] += 0.02 - X[..., 1].min()                                     # toes 2 cm up, as in the data
    rng = np.random.default_rng(5)
    slide = np.linspace(0, 0.08, T)
    target = X.copy()
    for j in FOOT_JOINTS[:2]:                                               # left ankle, left toe
        target[:, j, 0] += slide + rng.normal(0, 0.01, T)
        target[:, j, 2] += rng.normal(0, 0.01, T)
    planted = np.zeros((T, 4), bool)
    planted[5:35, :2] = True                                                # the left foot's span
    body = MotionBody(bm, BODY, betas[None])
    _, R, _ = body.project(target[None])
    free = _solve(body, method, target, R[0], None)                         # no locking: follows the slide
    locked = _solve(body, method, target, R[0], planted)
    for j in FOOT_JOINTS[:2]:
        span_free = free.joints[5:35, j]
        span = locked.joints[5:35, j]
        assert np.linalg.norm(span_free - span_free.mean(0), axis=-1).max() > 0.02       # ±3 cm of slide
        assert np.linalg.norm(span - span.mean(0), axis=-1).max() < 0.01
    others = [j for j in range(22) if j not in FOOT_JOINTS[:2] + (4,)]     # not the left foot or knee
    assert np.linalg.norm(locked.joints[:, others] - target[:, others], axis=-1).mean() < 0.01
    assert bone_consistency(locked.joints, BODY_PARENTS).max_deviation < 1e-5
    # the SMPL-X parameters pose exactly these joints
    with torch.no_grad():
        again = bm.joints(torch.as_tensor(locked.global_orient), torch.as_tensor(locked.body_pose),
                          torch.as_tensor(locked.transl), torch.as_tensor(locked.betas))
    np.testing.assert_allclose(again.numpy(), locked.joints, atol=1e-4)


@METHODS
def test_grounded_slide_drops_with_locking_on_a_walk(bm, method):
    """Gait from the procedural parameters slides its feet (the root moves at constant speed);
    flag each foot planted where it is low and slow, and locking stops it."""
    X, betas = _posed(bm, 90, seed=6, gait=True)
    X = X - [0, X[..., 1].min(), 0]                                        # feet on the floor
    toe_v = np.linalg.norm(np.gradient(X[:, FOOT_JOINTS, :][..., [0, 2]], axis=0), axis=-1) * 30   # (T, 4)
    low = X[:, FOOT_JOINTS, 1] < np.percentile(X[:, FOOT_JOINTS, 1], 40, axis=0)
    planted = low & (toe_v < np.percentile(toe_v, 50))
    body = MotionBody(bm, BODY, betas[None])
    _, R, _ = body.project(X[None])
    locked = _solve(body, method, X, R[0], planted)
    before = np.median(toe_v[planted])
    after_v = np.linalg.norm(np.gradient(locked.joints[:, FOOT_JOINTS][..., [0, 2]], axis=0), axis=-1) * 30
    assert np.median(after_v[planted]) < 0.25 * before
    assert np.isfinite(grounded_slide(locked.joints, 30.0, foot_joints=FOOT_JOINTS, floor_y=X[..., 1].min()))


@METHODS
def test_swing_clearance_keeps_swinging_feet_at_the_predicted_height(bm, method):
    """A strong joint-acceleration weight (the final solve's at 15 fps) flattens each swing and
    pulls the swinging foot below its predicted height (4 cm on this gait), which the skating
    metric reads as a low, fast foot; the clearance term keeps every unplanted foot joint at or
    above the prediction, within a few millimetres."""
    from dataclasses import replace

    from motiongen.body.solve import SOLVE_CONFIG

    X, betas = _posed(bm, 90, seed=6, gait=True)
    X = X - [0, X[..., 1].min(), 0]
    toe_v = np.linalg.norm(np.gradient(X[:, FOOT_JOINTS, :][..., [0, 2]], axis=0), axis=-1) * 30
    low = X[:, FOOT_JOINTS, 1] < np.percentile(X[:, FOOT_JOINTS, 1], 40, axis=0)
    planted = low & (toe_v < np.percentile(toe_v, 50))
    body = MotionBody(bm, BODY, betas[None])
    _, R, _ = body.project(X[None])

    def shortfall(w_clearance):
        cfg = replace(SOLVE_CONFIG, w_smooth_joints=200.0, w_clearance=w_clearance)
        out = _solve(body, method, X, R[0], planted, cfg)
        return ((X[:, FOOT_JOINTS, 1] - out.joints[:, FOOT_JOINTS, 1]) * ~planted).max()

    assert shortfall(0.0) > 0.02
    assert shortfall(300.0) < 0.005


def test_a_planted_foot_is_held_at_its_height_when_the_body_travels_on(bm):
    """A standing body whose prediction moves on 30 cm while its left foot is flagged planted
    throughout: holding the foot still, the solve must angle the leg. Left free to choose the
    foot's height (`lock_height=False`) it lifts the foot (a diagonal leg reaches further from
    a higher foot); held, the foot stays at the predicted height, or at the heights it is given
    (`planted_heights`, the network's own in the sampler), within 2 mm, and still."""
    from dataclasses import replace

    from motiongen.body.solve import SOLVE_CONFIG

    T = 40
    _, betas = _posed(bm, 1, seed=4)
    with torch.no_grad():
        X = bm.joints(torch.zeros(1, 3), torch.zeros(1, 63), torch.zeros(1, 3), betas).double().numpy()
    X = np.repeat(X, T, 0)                                                  # (T, 22, 3) rest pose
    X[..., 1] += 0.02 - X[..., 1].min()                                     # toes 2 cm up, as in the data
    X[..., 0] += np.linspace(-0.15, 0.15, T)[:, None]                       # walks on 30 cm
    planted = np.zeros((T, 4), bool)
    planted[:, :2] = True                                                   # left ankle and toe
    body = MotionBody(bm, BODY, betas[None])
    _, R, _ = body.project(X[None])
    left = list(FOOT_JOINTS[:2])
    free = _solve(body, "lbfgs", X, R[0], planted, replace(SOLVE_CONFIG, lock_height=False))
    held = _solve(body, "lbfgs", X, R[0], planted)
    lower = X[:, left, 1] - 0.01
    given = body.solve(0, X, R[0], planted, FOOT_JOINTS, planted_heights=np.concatenate([lower, X[:, list(FOOT_JOINTS[2:]), 1]], 1))
    assert (free.joints[:, left, 1] - X[:, left, 1]).mean() > 0.005          # lifted
    np.testing.assert_allclose(held.joints[:, left, 1], X[:, left, 1], atol=0.002)
    np.testing.assert_allclose(given.joints[:, left, 1], lower, atol=0.002)
    for m in (free, held, given):
        assert np.ptp(m.joints[:, left, 0], axis=0).max() < 0.005          # still, all three


def test_projection_keeps_ankles_and_wrists_where_predicted(bm):
    """A prediction whose knees and elbows are 3 cm off (so its thighs, shins and arms have the
    wrong lengths): following bone directions down the chain would carry those errors to the
    feet and hands; the projection puts ankles and wrists where predicted, bones rigid."""
    X, betas = _posed(bm, 12, seed=7)
    bad = X.copy()
    for j in (4, 5, 18, 19):                                              # knees, elbows
        bad[:, j] += [0.03, 0.0, 0.02]
    body = MotionBody(bm, BODY, betas[None])
    J, _, _ = body.project(bad[None])
    for j in (7, 8, 20, 21):                                              # ankles, wrists
        assert np.linalg.norm(J[0, :, j] - X[:, j], axis=-1).max() < 1e-3
    assert bone_consistency(J[0], BODY_PARENTS).max_deviation < 1e-5


def test_a_batch_solved_in_forked_workers_is_the_batch_solved_here(bm):
    """Eight samples (different bodies and motions, feet planted in turn) through the refined
    final solve in two forked processes and here, one after another: every result bitwise the
    same; below assemble.PARALLEL_MIN_SAMPLES every job runs in this process, from it in
    the children."""
    S, T = PARALLEL_MIN_SAMPLES, 24
    X, betas = zip(*[_posed(bm, T, seed=10 + s, gait=True) for s in range(S)])
    X, betas = np.stack(X), torch.stack(list(betas))                       # (S, T, 22, 3), (S, nβ)
    body = MotionBody(bm, BODY, betas)
    _, R, _ = body.project(X)
    planted = np.zeros((S, T, 4), bool)
    planted[:, :12, :2] = planted[:, 12:, 2:] = True
    here, forked = (solve_bodies(body, X, R, planted, FOOT_JOINTS, 30.0, 30.0, method="refined", workers=w)
                    for w in (1, 2))
    for a, b in zip(here, forked):
        assert np.array_equal(a.joints, b.joints) and np.array_equal(a.rotmats, b.rotmats)
    assert not np.array_equal(here[0].joints, here[1].joints)              # eight different motions
    pid = os.getpid()
    assert parallel_solves(lambda s: os.getpid(), list(range(PARALLEL_MIN_SAMPLES - 1)), 2) == [pid] * (S - 1)
    assert set(parallel_solves(lambda s: os.getpid(), list(range(S)), 2)) - {pid}


def test_default_solve_workers_follow_torch_threads():
    """loop.solve_workers=0 forks as many workers as torch has threads: none under one thread
    (an `evaluate jobs=N` worker on its share of the cores), two under two."""
    pid, items, old = os.getpid(), list(range(PARALLEL_MIN_SAMPLES)), torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert parallel_solves(lambda s: os.getpid(), items, 0) == [pid] * len(items)
        torch.set_num_threads(2)
        assert set(parallel_solves(lambda s: os.getpid(), items, 0)) - {pid}
    finally:
        torch.set_num_threads(old)
