"""Swing lift: a foot between two plants rises at least as high as the data's swings of that
length, in the targets (closed form) and in the body the final solve puts on them."""

import numpy as np
import pytest
import torch

from motiongen.body.random_motion import sample_motion
from motiongen.body.solve import MotionBody
from motiongen.sampling.assemble import solve_bodies
from motiongen.sampling.swing import SWING_LENGTH, SWING_RISE, lift_swings, swing_rise, swings
from motiongen.skeleton import BODY, FOOT_JOINTS, PELVIS

L_TOE = FOOT_JOINTS[1]


def test_swings_are_the_unplanted_runs_between_two_plants():
    flags = np.array([0, 1, 1, 0, 0, 0, 1, 1, 0, 1, 0, 0], bool)
    # The leading run has no plant before it and the trailing one none after: no swings.
    assert swings(flags) == [(2, 6), (7, 9)]
    assert swings(np.ones(5, bool)) == [] and swings(np.zeros(5, bool)) == []


def test_the_rise_is_the_table_between_its_lengths_and_its_ends_beyond():
    assert swing_rise("toe", SWING_LENGTH[2]) == SWING_RISE["toe"][2]
    mid = (SWING_LENGTH[2] + SWING_LENGTH[3]) / 2
    assert swing_rise("ankle", mid) == pytest.approx((SWING_RISE["ankle"][2] + SWING_RISE["ankle"][3]) / 2)
    assert swing_rise("toe", 0.0) == SWING_RISE["toe"][0] and swing_rise("toe", 5.0) == SWING_RISE["toe"][-1]


def _shuffle(T=30):
    """(1, T, 22, 3): a left toe planted at x = 0 (frames 0-9), sliding 0.25 m at 2.5 cm (10-19:
    a shuffle), planted at x = 0.25 (20-29), 2 cm up; every other joint still. Flags (1, T, 4)."""
    j = np.zeros((1, T, 22, 3))
    j[0, :, :, 1] = np.linspace(0.0, 1.0, 22)[None]                         # distinct heights
    j[0, :, L_TOE, 1] = 0.02
    j[0, 10:20, L_TOE, 1] = 0.025
    j[0, :, L_TOE, 0] = np.clip((np.arange(T) - 9) / 11, 0, 1) * 0.25
    planted = np.ones((1, T, 4), bool)
    planted[0, 10:20, 1] = False
    return j, planted


def test_a_shuffling_toe_rises_on_the_datas_arc_and_nothing_else_moves():
    j, planted = _shuffle()
    out = lift_swings(j, planted, FOOT_JOINTS)
    frac = np.arange(1, 11) / 11                                            # frames 10..19 between plants at 9 and 20
    arc = 0.02 + swing_rise("toe", 0.25) * np.sin(np.pi * frac)
    np.testing.assert_allclose(out[0, 10:20, L_TOE, 1], np.maximum(0.025, arc))
    assert out[0, 14:16, L_TOE, 1].min() > 0.02 + 0.95 * swing_rise("toe", 0.25)   # 5 cm up mid-swing
    changed = out != j
    changed[0, 10:20, L_TOE, 1] = False
    assert not changed.any()                                                # x, z, plants and other joints as they were


def test_a_swing_the_network_lifts_higher_and_one_without_a_landing_are_kept():
    j, planted = _shuffle()
    j[0, 10:20, L_TOE, 1] = 0.20                                            # already 20 cm up
    planted[0, 25:, 3] = False                                              # the right toe lifts and never lands
    j[0, 25:, FOOT_JOINTS[3], 1] = 0.0
    np.testing.assert_array_equal(lift_swings(j, planted, FOOT_JOINTS), j)


def test_contact_joints_that_are_no_ankle_or_toe_are_left_alone():
    j, planted = _shuffle()
    flags = np.ones((1, 30, 1), bool)
    flags[0, 10:20, 0] = False
    np.testing.assert_array_equal(lift_swings(j, flags, [PELVIS]), j)


def test_the_final_solve_puts_the_bodys_toe_on_the_raised_swing(bm):
    """A standing body whose left foot shuffles 24 cm forward 1 cm above the floor between two
    plants (the network's shuffle): solved as it is, the body's toe stays low; with the swing
    lifted, it rises to within 1 cm of the data's arc at mid-swing, and the plants stay put."""
    T = 45
    p = sample_motion(1, rng=np.random.default_rng(4))
    t = {k: torch.as_tensor(v) if k in ("betas", "transl") else torch.zeros_like(torch.as_tensor(v))
         for k, v in p.items()}                                             # the rest pose: feet flat
    with torch.no_grad():
        X = bm.joints(t["global_orient"], t["body_pose"], t["transl"], t["betas"]).double().numpy()
    X = np.repeat(X, T, 0)                                                  # (T, 22, 3) standing still
    X[..., 1] += 0.02 - X[..., 1].min()                                     # toes 2 cm up, as in the data
    step = np.clip((np.arange(T) - 14) / 16, 0, 1) * 0.24 - 0.12            # -12 cm, then +12 cm
    forward = np.cross([0.0, 1.0, 0.0], X[0, 2] - X[0, 1])                  # from the hips, towards the face
    forward /= np.linalg.norm(forward)
    for j in FOOT_JOINTS[:2]:
        X[:, j] += step[:, None] * forward
    X[15:30, FOOT_JOINTS[:2], 1] += 0.01                                    # the shuffle
    planted = np.ones((T, 4), bool)
    planted[15:30, :2] = False
    body = MotionBody(bm, BODY, t["betas"][None])
    _, R, _ = body.project(X[None])

    def solved(target):
        return solve_bodies(body, target[None], R, planted[None], FOOT_JOINTS, 30.0, 30.0, method="refined")[0].joints

    low = solved(X)
    high = solved(lift_swings(X[None], planted[None], FOOT_JOINTS)[0])
    base, rise = X[0, L_TOE, 1], swing_rise("toe", 0.24)
    assert low[20:25, L_TOE, 1].max() < base + 0.02
    assert high[22, L_TOE, 1] > base + rise - 0.01
    held = planted[:, 1]
    assert np.abs(high[held, L_TOE] - low[held, L_TOE]).max() < 0.01        # the plants stay
