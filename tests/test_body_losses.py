"""Training-time geometry on the network's prediction (motiongen/training/body_losses.py):
closed forms on a hand-made window, and the terms reaching the loss and its gradient."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from motiongen.data.representation import Layout
from motiongen.data.windows import NormStats
from motiongen.diffusion import DiffusionConfig, GaussianDiffusion
from motiongen.errors import ConfigError
from motiongen.geometry import facing_yaw, yaw_matrix
from motiongen.skeleton import BODY, BODY_PARENTS, FOOT_JOINTS, LEFT_HIP, PELVIS, RIGHT_HIP
from motiongen.training.body_losses import BodyLosses, across_vectors
from motiongen.training.train_config import TrainConfig
from motiongen.training.trainer import body_losses
from tests.helpers import REST

L, FPS = 8, 10.0
LAYOUT = Layout(22, "absolute", tuple(FOOT_JOINTS))
STATS = NormStats(np.full(LAYOUT.channels, 0.1, np.float32), np.full(LAYOUT.channels, 2.0, np.float32))
CHILD = [j for j, p in enumerate(BODY_PARENTS) if p >= 0]


def window(joints, planted):
    """joints (L, 22, 3), planted (L, 4) bool -> the normalised window (1, L, D)."""
    x = LAYOUT.encode(torch.as_tensor(joints, dtype=torch.float64), torch.as_tensor(planted))
    return STATS.normalize(x)[None]


def losses(w_bone=1.0, w_foot=1.0, noise_weights=None):
    return BodyLosses(LAYOUT, STATS, BODY.parents, FPS, w_bone, w_foot, noise_weights)


T0 = torch.tensor([0])                                                                  # one window, step 0


def trainer_run(tc: TrainConfig) -> SimpleNamespace:
    """What `trainer.body_losses` reads of a run: its train config, data layout and joint set."""
    data = SimpleNamespace(layout=LAYOUT, stats=STATS, cfg=SimpleNamespace(stride=1))
    return SimpleNamespace(tc=tc, train_set=data, ds=SimpleNamespace(joint_set=BODY, fps=FPS))


def test_closed_forms():
    rest = np.repeat(REST[None].astype(np.float64), L, 0)                             # (L, 22, 3)
    planted = np.ones((L, 4), bool)
    x0 = window(rest, planted)
    free = torch.ones_like(x0)
    t = losses()(x0, x0, free, T0)
    assert t["bone_length"][1].item() == pytest.approx(0, abs=1e-9) and t["planted_feet"][1].item() == pytest.approx(0, abs=1e-9)
    # every bone 10 % longer: the mean error is 10 % of the mean bone length
    big = rest[:, PELVIS:PELVIS + 1] + 1.1 * (rest - rest[:, PELVIS:PELVIS + 1])
    bones = np.linalg.norm(REST[CHILD] - REST[[BODY_PARENTS[j] for j in CHILD]], axis=-1)
    assert losses()(window(big, planted), x0, free, T0)["bone_length"][1].item() == pytest.approx(0.1 * bones.mean(), rel=1e-6)
    # the whole body sliding at 0.5 m/s: the planted feet's speed is 0.5 m/s, and 0 where not planted
    slide = rest + (0.5 / FPS) * np.arange(L)[:, None, None] * np.array([1.0, 0, 0])
    moved = window(slide, planted)
    assert losses()(moved, x0, free, T0)["planted_feet"][1].item() == pytest.approx(0.5, rel=1e-6)
    assert losses()(moved, window(rest, ~planted), free, T0)["planted_feet"][1].item() == pytest.approx(0, abs=1e-9)
    # only frames with a free entry count: all pinned, nothing to learn
    assert losses()(window(big, planted), x0, torch.zeros_like(x0), T0)["bone_length"][1].item() == 0


def turn(joints: np.ndarray, angle: float) -> np.ndarray:
    """joints (..., 22, 3) turned by angle (radians) about the vertical through the origin."""
    return joints @ yaw_matrix(np.float64(angle)).T


def test_facing_is_how_far_the_across_vectors_are():
    """A body turned by θ from the data's, every frame: each across vector (hips, shoulders) moves
    by its chord 2 sin(θ/2)·|a|, whatever the body turns about, and the term is the norm of both:
    2 sin(θ/2)·√(|hips|² + |shoulders|²). The whole body moved: 0. Hips each 5 cm further out:
    0.10 m. The facing the vectors give for the rest pose is +z, as geometry.facing_yaw's."""
    rest = np.repeat(REST[None].astype(np.float64), L, 0)                             # (L, 22, 3)
    planted = np.ones((L, 4), bool)
    x0, free = window(rest, planted), torch.ones_like(window(rest, planted))
    face = BodyLosses(LAYOUT, STATS, BODY.parents, FPS, 0.0, 0.0, w_facing=1.0)
    a = across_vectors(torch.as_tensor(REST))                                          # (6,)
    assert facing_yaw(REST) == pytest.approx(0, abs=1e-9) and a[0] > 0 and a[3] > 0       # left is +x
    for theta in (0.1, 0.5, np.pi / 2, np.pi):
        got = face(window(turn(rest, theta) + np.array([0.4, 0, -0.3]), planted), x0, free, T0)["facing"][1].item()
        assert got == pytest.approx(2 * np.sin(theta / 2) * a.norm().item(), rel=1e-6)
    moved = window(rest + np.array([1.0, 0, 2.0]), planted)
    assert face(moved, x0, free, T0)["facing"][1].item() == pytest.approx(0, abs=1e-9)
    wide = rest.copy()
    wide[:, [LEFT_HIP, RIGHT_HIP]] += np.array([[0.05, 0, 0], [-0.05, 0, 0]])
    assert face(window(wide, planted), x0, free, T0)["facing"][1].item() == pytest.approx(0.10, rel=1e-6)
    # the weight is the ramp's share of w_facing, and only frames with a free entry count
    assert face(window(turn(rest, 0.5), planted), x0, free, T0)["facing"][0] == 1.0
    assert face(window(turn(rest, 0.5), planted), x0, torch.zeros_like(x0), T0)["facing"][1].item() == 0


def test_the_trainer_builds_the_facing_term_alone():
    """train.w_facing alone is enough for the trainer to build the geometry terms, and only the
    facing term is computed; every weight 0 builds none; a negative weight is refused."""
    x0 = window(np.repeat(REST[None].astype(np.float64), L, 0), np.ones((L, 4), bool))
    terms = body_losses(trainer_run(TrainConfig(w_facing=0.5)))(x0, x0, torch.ones_like(x0), T0)
    assert list(terms) == ["facing"] and terms["facing"][0] == 0.5
    assert body_losses(trainer_run(TrainConfig())) is None
    with pytest.raises(ConfigError, match="train.w_facing"):
        TrainConfig(w_facing=-1.0)


def test_terms_reach_the_loss_and_its_gradient():
    diffusion = GaussianDiffusion(DiffusionConfig(prediction="x0"))
    net = torch.nn.Linear(LAYOUT.channels, LAYOUT.channels).double()
    model = lambda x_t, t, cond, known_mask=None: net(x_t)                            # noqa: E731
    x0 = window(np.repeat(REST[None].astype(np.float64), L, 0), np.ones((L, 4), bool)).repeat(2, 1, 1)
    t, noise = torch.tensor([3, 50]), torch.randn(x0.shape, generator=torch.Generator().manual_seed(0), dtype=x0.dtype)
    plain = diffusion.training_losses(model, x0, t, None, noise=noise)
    body = diffusion.training_losses(model, x0, t, None, noise=noise, window_terms=losses(2.0, 0.5))
    extra = 2.0 * body["bone_length"] + 0.5 * body["planted_feet"]
    assert body["bone_length"] > 0 and body["loss"].item() == pytest.approx((plain["loss"] + extra).item())
    body["loss"].backward()
    assert net.weight.grad.abs().sum() > 0


def test_signal_weighting_counts_each_window_by_its_share_of_signal():
    """Two windows, one with every bone 10 % long, one exact: uniform weighting gives the mean
    error over both; by signal, the noisier window counts ᾱ_t as much."""
    rest = np.repeat(REST[None].astype(np.float64), L, 0)
    planted = np.ones((L, 4), bool)
    big = rest[:, PELVIS:PELVIS + 1] + 1.1 * (rest - rest[:, PELVIS:PELVIS + 1])
    pred = torch.cat([window(big, planted), window(rest, planted)])                    # (2, L, D)
    x0 = torch.cat([window(rest, planted)] * 2)
    free, t = torch.ones_like(x0), torch.tensor([1, 0])
    err = 0.1 * np.linalg.norm(REST[CHILD] - REST[[BODY_PARENTS[j] for j in CHILD]], axis=-1).mean()
    assert losses()(pred, x0, free, t)["bone_length"][1].item() == pytest.approx(err / 2, rel=1e-6)
    w = torch.tensor([1.0, 0.25], dtype=torch.float64)                                 # ᾱ of steps 0, 1
    assert losses(noise_weights=w)(pred, x0, free, t)["bone_length"][1].item() == pytest.approx(
        0.25 * err / 1.25, rel=1e-6)


def test_planted_feet_needs_stance_channels():
    with pytest.raises(ConfigError, match="window.contact_joints"):
        BodyLosses(Layout(22), NormStats(np.zeros(66, np.float32), np.ones(66, np.float32)), BODY.parents, FPS, 1.0, 1.0)


def test_ramp_scales_both_weights_by_the_training_step():
    """train.geometry_start=10, geometry_ramp=4: weight 0 before step 10, then 1/4, 2/4, 3/4 of
    full, and full from step 13 on; the terms themselves do not change."""
    rest = np.repeat(REST[None].astype(np.float64), L, 0)
    x0 = window(rest, np.ones((L, 4), bool))
    body = BodyLosses(LAYOUT, STATS, BODY.parents, FPS, 2.0, 0.5, None, start=10, ramp=4)
    seen = []
    for step in (0, 9, 10, 11, 12, 13, 500):
        body.step = step
        terms = body(x0, x0, torch.ones_like(x0), T0)
        seen.append((terms["bone_length"][0], terms["planted_feet"][0]))
    assert seen == [(0.0, 0.0), (0.0, 0.0), (0.5, 0.125), (1.0, 0.25), (1.5, 0.375), (2.0, 0.5), (2.0, 0.5)]
    body = BodyLosses(LAYOUT, STATS, BODY.parents, FPS, 2.0, 0.5, None, start=0, ramp=0)
    assert body.scale() == 1.0


def test_foot_height_is_how_far_the_feet_are_in_height():
    """Every foot joint 4 cm lower than the data's: 0.04 m, whether planted or swinging; one
    ankle 8 cm higher: 0.02 m (a mean over the four foot joints); the feet moved sideways or the
    whole body turned: 0, the term sees heights only. Built by the trainer from its key alone."""
    rest = np.repeat(REST[None].astype(np.float64), L, 0)                             # (L, 22, 3)
    planted = np.ones((L, 4), bool)
    x0, free = window(rest, planted), torch.ones_like(window(rest, planted))
    feet = BodyLosses(LAYOUT, STATS, BODY.parents, FPS, 0.0, 0.0, w_foot_height=2.0)
    low = rest.copy()
    low[:, list(FOOT_JOINTS), 1] -= 0.04
    assert feet(window(low, ~planted), x0, free, T0)["foot_height"][1].item() == pytest.approx(0.04, rel=1e-6)
    one = rest.copy()
    one[:, FOOT_JOINTS[0], 1] += 0.08
    assert feet(window(one, planted), x0, free, T0)["foot_height"][1].item() == pytest.approx(0.02, rel=1e-6)
    aside = rest.copy()
    aside[:, list(FOOT_JOINTS), 0] += 0.3
    assert feet(window(aside, planted), x0, free, T0)["foot_height"][1].item() == pytest.approx(0, abs=1e-9)
    assert feet(window(turn(rest, 1.0), planted), x0, free, T0)["foot_height"][1].item() == pytest.approx(0, abs=1e-9)
    assert feet(window(low, planted), x0, free, T0)["foot_height"][0] == 2.0
    assert list(body_losses(trainer_run(TrainConfig(w_foot_height=0.3)))(x0, x0, free, T0)) == ["foot_height"]
    with pytest.raises(ConfigError, match="train.w_foot_height"):
        TrainConfig(w_foot_height=-0.1)


def test_foot_offset_is_how_far_the_feet_are_from_the_pelvis_along_the_floor():
    """The feet 0.3 m behind the pelvis where the data's are under it: 0.3 m, planted or not;
    one toe 0.2 m out: 0.05 m (a mean over the four foot joints); the whole body moved along the
    floor, lifted, or the feet lifted: 0 (the offset is horizontal and from the body's own
    pelvis). Built by the trainer from its key alone."""
    rest = np.repeat(REST[None].astype(np.float64), L, 0)                             # (L, 22, 3)
    planted = np.ones((L, 4), bool)
    x0, free = window(rest, planted), torch.ones_like(window(rest, planted))
    feet = BodyLosses(LAYOUT, STATS, BODY.parents, FPS, 0.0, 0.0, w_foot_offset=0.5)
    behind = rest.copy()
    behind[:, list(FOOT_JOINTS), 2] -= 0.3
    assert feet(window(behind, ~planted), x0, free, T0)["foot_offset"][1].item() == pytest.approx(0.3, rel=1e-6)
    one = rest.copy()
    one[:, FOOT_JOINTS[1], 0] += 0.2
    assert feet(window(one, planted), x0, free, T0)["foot_offset"][1].item() == pytest.approx(0.05, rel=1e-6)
    for same in (rest + np.array([1.5, 0.2, -0.7]), rest + (0.1 * np.arange(L))[:, None, None] * np.array([0, 0, 1.0])):
        assert feet(window(same, planted), x0, free, T0)["foot_offset"][1].item() == pytest.approx(0, abs=1e-9)
    up = rest.copy()
    up[:, list(FOOT_JOINTS), 1] += 0.1
    assert feet(window(up, planted), x0, free, T0)["foot_offset"][1].item() == pytest.approx(0, abs=1e-9)
    assert feet(window(behind, planted), x0, free, T0)["foot_offset"][0] == 0.5
    assert list(body_losses(trainer_run(TrainConfig(w_foot_offset=0.1)))(x0, x0, free, T0)) == ["foot_offset"]
    with pytest.raises(ConfigError, match="train.w_foot_offset"):
        TrainConfig(w_foot_offset=-0.1)


def test_pace_is_how_far_the_pelvis_steps_are_from_the_datas():
    """The data's body walks 0.1 m per frame; a prediction that stops after its third frame
    misses its last L - 3 steps by 0.1 m each (fps m/s); the whole body shifted or lifted, or
    its feet moved, costs nothing (steps of the pelvis along the floor). Built by the trainer
    from its key alone."""
    planted = np.zeros((L, 4), bool)
    walk = np.repeat(REST[None].astype(np.float64), L, 0) + (0.1 * np.arange(L))[:, None, None] * np.array([0, 0, 1.0])
    x0, free = window(walk, planted), torch.ones_like(window(walk, planted))
    pace = BodyLosses(LAYOUT, STATS, BODY.parents, FPS, 0.0, 0.0, w_pace=0.2)
    stop = walk.copy()
    stop[3:] = walk[2]
    assert pace(window(stop, planted), x0, free, T0)["pace"][1].item() == pytest.approx(0.1 * FPS * (L - 3) / (L - 1), rel=1e-5)
    feet = walk.copy()
    feet[:, list(FOOT_JOINTS), 0] += 0.3
    for same in (walk + np.array([1.5, 0.2, -0.7]), feet):
        assert pace(window(same, planted), x0, free, T0)["pace"][1].item() == pytest.approx(0, abs=1e-6)
    assert pace(window(stop, planted), x0, free, T0)["pace"][0] == 0.2
    assert list(body_losses(trainer_run(TrainConfig(w_pace=0.1)))(x0, x0, free, T0)) == ["pace"]
    with pytest.raises(ConfigError, match="train.w_pace"):
        TrainConfig(w_pace=-0.1)


def test_the_facing_goal_term_counts_the_last_quarter_of_windows_given_a_facing():
    """Two windows, the second given a facing goal: a body turned by θ over the last quarter (2
    of 8 frames) of both reads the facing term's chord on the second only, and 0 where its turn
    is in the first frames; nothing given (the loop sets no flags), no term."""
    rest = np.repeat(REST[None].astype(np.float64), L, 0)                             # (L, 22, 3)
    planted = np.ones((L, 4), bool)
    x0 = torch.cat([window(rest, planted)] * 2)
    late, early = rest.copy(), rest.copy()
    late[-2:], early[:2] = turn(rest[-2:], 0.5), turn(rest[:2], 0.5)
    goal = BodyLosses(LAYOUT, STATS, BODY.parents, FPS, 0.0, 0.0, w_facing_goal=0.3)
    goal.facing_given = torch.tensor([False, True])
    chord = 2 * np.sin(0.25) * across_vectors(torch.as_tensor(REST)).norm().item()
    free = torch.ones_like(x0)
    for turned, want in ((late, chord), (early, 0.0)):
        weight, term = goal(torch.cat([window(turned, planted)] * 2), x0, free, torch.tensor([0, 0]))["facing_goal"]
        assert weight == 0.3 and term.item() == pytest.approx(want, abs=1e-9, rel=1e-6)
    goal.facing_given = None
    assert goal(x0, x0, free, torch.tensor([0, 0])) == {}


def test_the_squared_facing_goal_term_is_the_chord_squared():
    """`facing_goal_norm=squared`: a body turned by θ over the last quarter reads the square
    (m²) of the across vectors' chord 2 sin(θ/2)·|a|, at two angles."""
    rest = np.repeat(REST[None].astype(np.float64), L, 0)                             # (L, 22, 3)
    planted = np.ones((L, 4), bool)
    x0 = window(rest, planted)
    goal = BodyLosses(LAYOUT, STATS, BODY.parents, FPS, 0.0, 0.0, w_facing_goal=5.0, facing_goal_norm="squared")
    goal.facing_given = torch.tensor([True])
    width = across_vectors(torch.as_tensor(REST)).norm().item()
    free = torch.ones_like(x0)
    for angle in (0.2, 0.5):
        late = rest.copy()
        late[-2:] = turn(rest[-2:], angle)
        weight, term = goal(window(late, planted), x0, free, torch.tensor([0]))["facing_goal"]
        assert weight == 5.0 and term.item() == pytest.approx((2 * np.sin(angle / 2) * width) ** 2, rel=1e-6)


def test_a_bad_facing_goal_norm_is_one_line():
    with pytest.raises(ConfigError, match="train.facing_goal_norm: expected one of l1, squared, got 'l2'"):
        TrainConfig(facing_goal_norm="l2")


def test_a_facing_goal_term_without_facing_goals_is_one_line():
    run = trainer_run(TrainConfig(w_facing_goal=0.2))
    run.cfg = OmegaConf.create({"mask": {"p_facing": 0.0}})
    with pytest.raises(ConfigError, match=r"train.w_facing_goal=0.2 needs facing goals \(mask.p_facing > 0\)"):
        body_losses(run)
    run.cfg = OmegaConf.create({"mask": {"p_facing": 0.5}})
    assert body_losses(run).w_facing_goal == 0.2
