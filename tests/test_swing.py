"""Swing lift: a foot between two plants rises at least as high as the data's swings of that
length, in the targets (closed form) and in the body the final solve puts on them; the data's
swing table measured, saved with a checkpoint and read back."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from motiongen.body.random_motion import sample_motion
from motiongen.body.solve import MotionBody
from motiongen.data.swing_rise import EMBEDDED, SwingRise, sequence_rows, table
from motiongen.sampling.assemble import solve_bodies
from motiongen.sampling.swing import lift_swings
from motiongen.skeleton import BODY, FOOT_JOINTS, PELVIS
from motiongen.spans import swings
from motiongen.training.setup import swing_meta

L_TOE = FOOT_JOINTS[1]


def test_swings_are_the_unplanted_runs_between_two_plants():
    flags = np.array([0, 1, 1, 0, 0, 0, 1, 1, 0, 1, 0, 0], bool)
    # The leading run has no plant before it and the trailing one none after: no swings.
    assert swings(flags) == [(2, 6), (7, 9)]
    assert swings(np.ones(5, bool)) == [] and swings(np.zeros(5, bool)) == []


def test_the_rise_is_the_table_between_its_lengths_and_its_ends_beyond():
    L, R = EMBEDDED.length["ankle"], EMBEDDED.rise["ankle"]
    assert EMBEDDED.at("ankle", L[2]) == R[2]
    assert EMBEDDED.at("ankle", (L[2] + L[3]) / 2) == pytest.approx((R[2] + R[3]) / 2)
    assert EMBEDDED.at("toe", 0.0) == EMBEDDED.rise["toe"][0] and EMBEDDED.at("toe", 5.0) == EMBEDDED.rise["toe"][-1]
    again = SwingRise.from_state_dict(EMBEDDED.state_dict())
    assert all(np.array_equal(again.rise[k], EMBEDDED.rise[k]) and np.array_equal(again.length[k], EMBEDDED.length[k])
               for k in EMBEDDED.rise) and again.swings == EMBEDDED.swings


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
    arc = 0.02 + EMBEDDED.at("toe", 0.25) * np.sin(np.pi * frac)
    np.testing.assert_allclose(out[0, 10:20, L_TOE, 1], np.maximum(0.025, arc))
    assert out[0, 14:16, L_TOE, 1].min() > 0.02 + 0.95 * EMBEDDED.at("toe", 0.25)    # 5 cm up mid-swing
    # A checkpoint's own table: its rise, whatever the embedded one says.
    own = SwingRise({"ankle": np.array([0.0, 1.0]), "toe": np.array([0.0, 1.0])},
                    {"ankle": np.array([0.1, 0.1]), "toe": np.array([0.1, 0.1])})
    np.testing.assert_allclose(lift_swings(j, planted, FOOT_JOINTS, own)[0, 10:20, L_TOE, 1],
                               np.maximum(0.025, 0.02 + 0.1 * np.sin(np.pi * frac)))
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
    base, rise = X[0, L_TOE, 1], EMBEDDED.at("toe", 0.24)
    assert low[20:25, L_TOE, 1].max() < base + 0.02
    assert high[22, L_TOE, 1] > base + rise - 0.01
    held = planted[:, 1]
    assert np.abs(high[held, L_TOE] - low[held, L_TOE]).max() < 0.01        # the plants stay


def _steps(n_steps=6, rise=0.06, length=0.25):
    """One walk (T, 22, 3) and contact labels (T, 22): the feet take turns, each step a swing of
    11 frames between plants of 13, `length` m forward on an arc `rise` m high (sin, its top on
    the middle frame); toes 2 cm up, ankles 8 cm. Every other joint still, out of contact."""
    plant, swing = 13, 11
    T = n_steps * (plant + swing) + plant
    j = np.zeros((T, 22, 3))
    j[:, :, 1] = 1.0
    contact = np.zeros((T, 22), bool)
    for side, (ankle, toe) in enumerate([FOOT_JOINTS[:2], FOOT_JOINTS[2:]]):
        x = np.zeros(T)
        y = np.zeros(T)
        on = np.ones(T, bool)
        for k in range(side, n_steps, 2):                        # this foot's steps
            a = k * (plant + swing) + plant - 1                  # the plant's last frame
            frac = np.arange(1, swing + 1) / (swing + 1)
            x[a + 1:a + swing + 1] = x[a] + length * frac
            x[a + swing + 1:] = x[a] + length
            y[a + 1:a + swing + 1] = rise * np.sin(np.pi * frac)
            on[a + 1:a + swing + 1] = False
        for jj, h in ((ankle, 0.08), (toe, 0.02)):
            j[:, jj] = np.stack([x + 0.1 * side, y + h, 0.05 * np.ones(T)], -1)
            contact[:, jj] = on
    return j, contact


def test_the_table_of_a_walk_is_its_swings_rise_at_its_step_length():
    j, contact = _steps()
    got = table(sequence_rows(j, contact, 30.0))
    assert got.swings == 12                                                          # 6 steps x ankle and toe
    for kind in ("ankle", "toe"):
        np.testing.assert_allclose(got.length[kind], [0.25])
        np.testing.assert_allclose(got.rise[kind], [0.06])
    assert table(sequence_rows(*_steps(n_steps=2), 30.0)) is None                     # 2 swings a kind: too few


class _Walks:
    """The parts of a MotionDataset `swing_rise.measure` reads: two walks in the train split."""
    fps = 30.0

    def __init__(self):
        a, b = _steps(rise=0.05), _steps(rise=0.07)
        self.joints, self.contact = np.concatenate([a[0], b[0]]), np.concatenate([a[1], b[1]])
        self.seqs = [SimpleNamespace(start=0, end=len(a[0])), SimpleNamespace(start=len(a[0]), end=len(self.joints))]

    def split_sequences(self, split):
        assert split == "train"
        return self.seqs


def test_training_saves_the_data_table_and_a_resumed_run_keeps_its_own():
    meta = swing_meta(_Walks(), None)
    got = SwingRise.from_state_dict(meta["swing_rise"])
    np.testing.assert_allclose(got.rise["toe"], [0.06])                               # median of 0.05 and 0.07
    assert got.swings == 24
    assert swing_meta(_Walks(), {"swing_rise": EMBEDDED.state_dict()}) == {"swing_rise": EMBEDDED.state_dict()}
    assert swing_meta(_Walks(), {}) == {}                                             # a checkpoint from before
    assert swing_meta(_Walks(), None, stance_speed=0.0) == {}                         # no frame slow enough: no plant
