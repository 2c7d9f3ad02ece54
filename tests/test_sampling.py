"""The autoregressive loop, checked with an oracle denoiser so that the loop's mechanics
(frames, pinning, goals, seams, batching) are tested independently of how well a model
trained: the oracle predicts the noise of a clean window that walks the last pinned pose in a
straight line to the pinned goal — what a perfect model would do."""

import numpy as np
import pytest
import torch
from torch import nn

from motiongen.diffusion import MaskConfig
from motiongen.errors import ConfigError
from motiongen.metrics import bone_consistency, bone_lengths
from motiongen.sampling import Goal, LoopConfig, SamplerSettings, generate, plan_scene_route
from motiongen.sampling.assemble import blend_seam
from motiongen.sampling.progress import output_arrival_errors, stall_rule
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.skeleton import BODY_PARENTS, HAND_JOINTS, LEFT_HIP, PELVIS, RIGHT_HIP
from tests.oracle import Oracle, oracle_loaded

J, L = 22, 16


class Still(Oracle):
    """A model that never moves: every free frame holds the last pinned pose, whatever the goal
    (load it with predict_goal=True, or the goal written into the last frame would move it)."""

    def forward(self, x_t, t, cond, known_mask=None):
        x, m, k, last = self.pinned(x_t, known_mask)
        x0 = last[:, None].repeat(1, L, 1, 1)
        x0[:, :k] = x[:, :k]
        x0n = self.stats.normalize(x0.reshape(x_t.shape[0], L, J * 3)).to(x_t.dtype)
        return self.diffusion.eps_from_x0(x_t, x0n, t)



_loaded = oracle_loaded


def _generate(loaded, goals, path="astar", subgoal_spacing=0.6, **kw):
    """generate from (0, 0) through `goals` on an empty floor, the route planned first."""
    route, fmap = plan_scene_route((0.0, 0.0), goals, loaded.action_names, path=path, subgoal_spacing=subgoal_spacing)
    return generate(loaded, route=route, walkable=fmap, **kw)


def _seam_ratio(motion):
    disp = np.linalg.norm(np.diff(motion.joints, axis=1), axis=-1).max(-1)          # (S, T-1)
    seams = motion.episode_starts[1:]
    seams = seams[(seams > 0) & (seams < disp.shape[1])]
    seam_max = disp[:, seams - 1].max()
    rest = np.delete(disp, seams - 1, axis=1)
    return seam_max / np.median(rest)


def test_reaches_goals_in_empty_scene_with_continuous_seams():
    goals = [Goal([1.5, 2.0]), Goal([-1.0, 4.0]), Goal([0.0, 6.0], "sit", 1.0)]
    m = _generate(_loaded(), goals, num_samples=2, generator=torch.Generator().manual_seed(0),
                  sampler=SamplerSettings("ddim", 5), loop=LoopConfig(tolerance=0.2))
    assert m.completed
    assert m.joints.shape[0] == 2 and m.joints.shape[2:] == (J, 3) and m.fps == 30.0
    assert np.all(m.arrival_error < 0.2) and np.all(m.arrival_error_body < 0.2)
    # The pelvis at each arrival frame is at the goal; goals are reached in order.
    assert np.all(np.diff(m.arrival_frame, axis=1) > 0)
    assert _seam_ratio(m) <= 2.0
    # Interactions hold the position with their label for about their duration.
    sit = m.action_names.index("sit")
    assert (m.actions == sit).sum(1).min() >= 0.9 * 30
    # Long routes need several episodes; look-ahead keeps the walk near the model's reach.
    assert len(m.episode_starts) > 5


def test_a_walk_to_a_last_goal_ends_at_rest_on_it():
    """A last goal without an action is reached within the tolerance, still walking; the loop
    then settles (loop.settle=1): one more episode standing on the goal. The episodes up to the
    finish are the same as without it, the finish frame too (evaluation cuts there), and the
    body ends standing on the goal where it would have ended walking (the oracle walks at
    ~0.4 m/s into its goal)."""
    goal = np.array([1.0, 4.0])
    kw = dict(generator=None, sampler=SamplerSettings("ddim", 2), loop=None)
    runs = {}
    for settle in (0, 1):
        kw.update(generator=torch.Generator().manual_seed(0), loop=LoopConfig(tolerance=0.25, settle=settle))
        runs[settle] = _generate(_loaded(predict_goal=True), [Goal(goal)], **kw)
    off, on = runs[0], runs[1]
    assert off.completed and on.completed
    assert [e.kind for e in on.episodes] == [e.kind for e in off.episodes] + ["idle"]
    assert on.finish_frame.tolist() == off.finish_frame.tolist()
    n = len(off.model_joints[0])
    np.testing.assert_array_equal(on.model_joints[:, :n], off.model_joints)          # the same episodes
    assert on.joints.shape[1] > off.joints.shape[1] + 20                               # ~1.2 s more at 30 fps
    end = lambda m: np.linalg.norm(m.joints[0, -1, PELVIS, [0, 2]] - goal)             # noqa: E731
    speed = lambda m: np.linalg.norm(np.diff(m.joints[0, -6:, PELVIS][:, [0, 2]], axis=0), axis=-1).mean() * m.fps   # noqa: E731
    assert end(on) < 0.02 and speed(on) < 0.05 < 0.3 < speed(off)                      # m, m/s: at rest, not mid-stride
    # a last goal with an action ends acting: nothing to settle
    sit = _generate(_loaded(predict_goal=True), [Goal(goal, "sit", 1.0)], **kw)
    assert sit.episodes[-1].kind == "act"


def test_pinned_transition_frames_equal_previous_frames():
    m = _generate(_loaded(), [Goal([0.5, 3.0])], generator=torch.Generator().manual_seed(1),
                  sampler=SamplerSettings("ddpm", 10, eta=1.0))
    eps = m.episodes
    assert len(eps) >= 3
    for prev, cur in zip(eps[:-1], eps[1:]):
        k = cur.transition
        assert k == 2
        np.testing.assert_allclose(cur.window[:, :k], prev.window[:, L - k:], atol=2e-5)
        # The new window starts at its first frame's canonical frame: pelvis at the origin.
        local = np.linalg.inv(cur.to_world[0]) @ np.append(cur.window[0, 0, 0], 1.0)
        np.testing.assert_allclose(local[[0, 2]], 0.0, atol=1e-5)


def test_far_targets_are_clamped_and_lookahead_off_uses_every_subgoal():
    ld = _loaded()
    m = _generate(ld, [Goal([0.0, 4.0])], path="straight", subgoal_spacing=3.0,
                  generator=torch.Generator().manual_seed(0), sampler=SamplerSettings("ddim", 3))
    walk = [e for e in m.episodes if e.kind == "walk"]
    reach = 0.7 * 2.0
    for e in walk:
        frame0 = e.window[0, e.transition - 1, 0, [0, 2]]
        assert np.linalg.norm(e.window[0, -1, 0, [0, 2]] - frame0) <= reach + 0.3
    m2 = _generate(ld, [Goal([0.0, 2.4])], subgoal_spacing=0.6,
                   generator=torch.Generator().manual_seed(0), sampler=SamplerSettings("ddim", 3),
                   loop=LoopConfig(lookahead=False))
    assert sum(e.kind == "walk" for e in m2.episodes) >= 4


def test_max_episodes_warns_and_unknown_action_errors():
    with pytest.warns(UserWarning, match="stopped after max_episodes=2"):
        m = _generate(_loaded(), [Goal([0.0, 8.0])], sampler=SamplerSettings("ddim", 2),
                      loop=LoopConfig(max_episodes=2))
    assert not m.completed and np.isnan(m.arrival_error).all()
    assert m.goal_outcome.tolist() == [["episode limit"]]
    assert [(f["goal"], f["reason"]) for f in m.failed_goals()] == [(1, "episode limit")]
    with pytest.raises(ConfigError, match="knows: walk, sit"):
        _generate(_loaded(), [Goal([0.0, 1.0], "dance")])


class Garbage(nn.Module):
    """A network whose clean-motion estimate is uniform noise over the normalised range (joints
    anywhere within 2 m of the window frame): whatever it says, the motion must stay one body."""

    def __init__(self, diffusion, stats):
        super().__init__()
        self.p = nn.Parameter(torch.zeros(1))
        self.scene_encoder = None
        self.diffusion = diffusion

    def forward(self, x_t, t, cond, known_mask=None):
        x0 = torch.rand(x_t.shape, generator=torch.Generator().manual_seed(int(t[0])), dtype=x_t.dtype) * 2 - 1
        return self.diffusion.eps_from_x0(x_t, x0, t)


@pytest.mark.parametrize("solve", ["lbfgs", "joint-space", "refined"])
def test_one_body_across_seams_whatever_the_network_predicts(solve):
    with pytest.warns(UserWarning, match="max_episodes"):
        m = _generate(_loaded(Garbage), [Goal([0.0, 3.0])], num_samples=2,
                      generator=torch.Generator().manual_seed(0), sampler=SamplerSettings("ddim", 3),
                      loop=LoopConfig(max_episodes=4, solve=solve))
    for s in range(2):
        raw = bone_consistency(m.joints_raw[s], BODY_PARENTS)
        assert raw.cv_median > 0.2                                        # the network's bones are garbage ...
        out = bone_consistency(m.joints[s], BODY_PARENTS)
        assert out.max_deviation < 1e-4                                   # ... the output's are one body's
        proj = bone_lengths(m.model_joints[s], BODY_PARENTS)              # model-rate frames, every seam
        np.testing.assert_allclose(proj, np.broadcast_to(proj[0], proj.shape), atol=1e-4)
        # the SMPL-X parameters pose exactly the output joints
        b = m.bodies[s]
        assert b.joints.shape == m.joints[s].shape and np.allclose(b.joints, m.joints[s])


def test_blend_seam_continues_the_pinned_velocity():
    # pinned frames 0..3 move at v per frame; the network's frames 4.. also move at v but start
    # d off the continuation: a velocity jump δ = d at the seam.
    k, n, L = 4, 6, 16
    v, d = np.array([0.03, 0.0, -0.01]), np.array([0.05, 0.02, 0.0])
    t = np.arange(L, dtype=np.float64)[:, None]
    x = (t * v + (t >= k) * d)[None, :, None, :].repeat(2, axis=2)                    # (1, L, 2, 3)
    out = blend_seam(x, k, n)
    np.testing.assert_array_equal(out[:, :k], x[:, :k])                              # pinned untouched
    np.testing.assert_allclose(out[0, k, 0], x[0, k - 1, 0] + v, atol=1e-12)         # C1 at the seam
    np.testing.assert_array_equal(out[:, k + n:], x[:, k + n:])                      # faded out
    # the correction's own acceleration: raised cosine, at most |δ| (1 - cos(π/n)) per frame²
    acc = np.abs(np.diff(out[0, :, 0], n=2, axis=0)).max(0)
    assert np.all(acc <= np.abs(d) * (1 - np.cos(np.pi / n)) + 1e-12)
    assert np.abs(np.diff(x[0, :, 0], n=2, axis=0)).max() == pytest.approx(np.abs(d).max())
    # nothing to carry without two pinned frames, or with no frames to fade over
    np.testing.assert_array_equal(blend_seam(x, 1, n), x)
    np.testing.assert_array_equal(blend_seam(x, k, 0), x)


def test_a_body_that_stands_still_stalls_and_the_loop_ends_early():
    goals = [Goal([0.0, 3.0]), Goal([2.0, 4.0])]
    with pytest.warns(UserWarning, match="stopped early, no progress for loop.stall_s=3 s: sample 0 reached 0/2"):
        m = _generate(_loaded(Still, predict_goal=True), goals, generator=torch.Generator().manual_seed(0),
                      sampler=SamplerSettings("ddim", 2), loop=LoopConfig(stall_s=3.0, max_episodes=200))
    assert not m.completed
    # one episode to measure from, 3 s (30 model frames at 10 fps, 14 a window) without progress
    walks = [e for e in m.episodes if e.kind == "walk"]
    assert len(walks) == 4 and len(m.episodes) == 2 + 4                 # the 2 warm-up episodes
    assert m.goal_outcome.tolist() == [["stalled", "not attempted"]]
    failed = m.failed_goals()
    assert [(f["sample"], f["goal"], f["reason"]) for f in failed] == [(0, 1, "stalled"), (0, 2, "not attempted")]
    assert failed[0]["distance_m"] == pytest.approx(3.0, abs=0.05)


def test_stalled_sample_idles_while_the_others_walk_on():
    """Sample 1 stands still, sample 0 walks: the first stalls and idles where it stopped, the
    loop goes on until the second has reached its goal; stall_s=0 turns the rule off."""

    class Half(Oracle):
        def forward(self, x_t, t, cond, known_mask=None):
            eps = super().forward(x_t, t, cond, known_mask)
            eps[1] = Still.forward(self, x_t, t, cond, known_mask)[1]
            return eps

    kw = dict(num_samples=2, generator=torch.Generator().manual_seed(0), sampler=SamplerSettings("ddim", 2))
    with pytest.warns(UserWarning, match="sample 1 reached 0/1"):
        m = _generate(_loaded(Half, predict_goal=True), [Goal([0.0, 6.0])], loop=LoopConfig(stall_s=2.0), **kw)
    assert m.goal_outcome.tolist() == [["reached"], ["stalled"]] and not m.completed
    assert m.finish_frame[0] > 0 and m.finish_frame[1] == -1
    assert len([e for e in m.episodes if e.kind == "walk"]) >= 4                         # went on after the stall
    pelvis = m.joints[1, :, 0, [0, 2]]                                                     # (T, 2) the still one
    assert np.abs(pelvis - pelvis[0]).max() < 0.05
    with pytest.warns(UserWarning, match="stopped after max_episodes=4"):
        off = _generate(_loaded(Half, predict_goal=True), [Goal([0.0, 6.0])],
                        loop=LoopConfig(stall_s=0, max_episodes=4), **kw)
    assert off.goal_outcome.tolist() == [["episode limit"], ["episode limit"]]


def test_an_oracle_run_completes_and_reports_every_goal_reached():
    m = _generate(_loaded(), [Goal([1.0, 2.0]), Goal([0.0, 3.5], "sit", 0.5)], generator=torch.Generator().manual_seed(0),
                  sampler=SamplerSettings("ddim", 2), loop=LoopConfig(stall_s=3.0))
    assert m.completed and m.failed_goals() == []
    assert m.goal_outcome.tolist() == [["reached", "reached"]]
    # The goal errors printed and saved are the output's (after smoothing and the final solve):
    # the output pelvis comes that close to each goal within 0.5 s of its arrival frame.
    pel = m.joints[0, :, PELVIS][:, [0, 2]]
    for g, goal in enumerate(m.route.goals):
        a, w = int(m.arrival_frame[0, g]), int(0.5 * m.fps)
        near = np.linalg.norm(pel[max(a - w, 0):a + w + 1] - goal.xz, axis=-1).min()
        assert abs(near - m.arrival_error[0, g]) < 1e-5, (g, near, m.arrival_error[0, g])


def test_output_arrival_errors_closed_form():
    """A pelvis walking along x past a goal 0.3 m to its side: the closest approach is 0.3 m, at
    the frame it passes; outside the 0.5 s window around the arrival frame nothing counts."""
    T, fps = 90, 30.0
    joints = np.zeros((1, T, 22, 3))
    x = np.linspace(-1.5, 1.5, T)                                               # 1 m/s
    joints[0, :, :, 0] = x[:, None]
    joints[0, :, LEFT_HIP, 2], joints[0, :, RIGHT_HIP, 2] = 0.1, -0.1           # hips straddle the pelvis
    goals = np.array([[0.0, 0.3], [1.5, 0.0]])
    arrival = np.array([[45, -1]])
    pel, hips = output_arrival_errors(joints, arrival, goals, fps)
    assert abs(pel[0, 0] - np.hypot(x[np.abs(x).argmin()], 0.3)) < 1e-12 and abs(hips[0, 0] - pel[0, 0]) < 1e-12
    assert np.isnan(pel[0, 1]) and np.isnan(hips[0, 1])
    far, _ = output_arrival_errors(joints, np.array([[0, -1]]), goals, fps)      # arrival 1.5 s before passing
    assert abs(far[0, 0] - np.hypot(x[15], 0.3)) < 1e-12                         # the window's nearest frame


@pytest.mark.parametrize("stall_s", [-1.0, float("inf"), float("nan")])
def test_stall_s_must_be_seconds(stall_s):
    with pytest.raises(ConfigError, match="loop.stall_s"):
        LoopConfig(stall_s=stall_s)


def test_stall_rule():
    """Progress: a subgoal passed (or an action), or 0.1 m closer than the best since the last
    progress; small steps count once they add up; the clock runs from the last progress."""
    best, moved = np.array([np.inf, 2.0, 2.0, 2.0]), np.array([-1, 10, 10, 10])
    passed = np.array([False, True, False, False])
    best, moved, stalled = stall_rule(best, moved, passed, np.array([5.0, 3.0, 1.95, 2.5]), 40, limit=30)
    assert best.tolist() == [5.0, 3.0, 2.0, 2.0] and moved.tolist() == [40, 40, 10, 10]
    assert stalled.tolist() == [False, False, True, True]
    one = lambda b, m, d, now: stall_rule(np.array([b]), np.array([m]), np.array([False]), np.array([d]), now, 30)  # noqa: E731
    assert not one(2.0, 10, 1.95, 39)[2][0]                            # 29 frames: not yet
    best, moved, _ = one(2.0, 10, 1.95, 20)                            # 5 cm closer: not progress ...
    assert (best[0], moved[0]) == (2.0, 10)
    best, moved, _ = one(best[0], moved[0], 1.89, 30)                  # ... 11 cm closer in two steps: progress
    assert (best[0], moved[0]) == (1.89, 30)


@pytest.mark.parametrize("solve", ["lbfgs", "joint-space", "refined"])
def test_the_clean_up_in_the_loop_seats_the_body_among_placed_objects(solve):
    """The whole loop with the clean-up on, in a scene with a seat, and a cup placed on a table:
    while sitting the pelvis is `seat_offset` above the seat top; no wrist ever enters the cup.
    (The oracle's arms are held out in a T: its wrists stay beyond the hand reach's range, so
    the reach itself is tested on known geometry in tests/test_interactions.py.)"""
    occ = np.zeros((150, 60, 150), bool)                       # 4 cm voxels, origin (-3, 0, -3): 6 x 2.4 x 6 m
    occ[95:107, 0:11, 45:57] = True                            # a seat: x, z in [0.8, 1.28) x [-1.2, -0.72), top 0.44 m
    occ[45:55, 0:18, 95:105] = True                            # a table: x, z in [-1.2, -0.8) x [0.8, 1.2), top 0.72 m
    scene = OccupancyGrid.from_dense(occ, [-3.0, 0.0, -3.0], 0.04)
    ii, kk = np.meshgrid(np.arange(8), np.arange(8), indexing="ij")
    cup_occ = np.repeat((((ii - 3.5) ** 2 + (kk - 3.5) ** 2) <= 3.5 ** 2)[:, None, :], 10, 1)   # r 4 cm, 10 cm tall
    cup = OccupancyGrid.from_dense(cup_occ, [-0.04, 0.0, -0.04], 0.01)
    cup_pose = np.eye(4)
    cup_pose[:3, 3] = [-1.0, 0.72, 1.0]                                                  # on the table
    loaded = _loaded(predict_goal=True)
    loaded.action_names = ["walk", "sit", "pick up"]
    route, fmap = plan_scene_route((0.0, 0.0), [Goal([1.04, -0.96], "sit", 1.0)], loaded.action_names, scene)
    m = generate(loaded, scene, route=route, walkable=fmap, objects=[(cup, cup_pose)],
                 generator=torch.Generator().manual_seed(0), sampler=SamplerSettings("ddim", 2),
                 loop=LoopConfig(stall_s=None, solve=solve))
    assert m.completed, m.goal_outcome
    sit = np.flatnonzero(m.actions[0] == 1)
    mid = sit[len(sit) // 3: 2 * len(sit) // 3]                                          # past the ramps
    assert len(mid) > 5 and np.allclose(m.joints[0, mid, PELVIS, 1], 0.44 + 0.10, atol=0.02), \
        m.joints[0, mid, PELVIS, 1]
    cup_pts = (np.argwhere(cup_occ) + 0.5) * 0.01 + cup.origin + cup_pose[:3, 3]         # (N, 3) voxel centres
    wrists = m.joints[0][:, list(HAND_JOINTS)].reshape(-1, 3)                            # (2T, 3)
    assert np.linalg.norm(wrists[:, None] - cup_pts[None], axis=-1).min() > 0.01


def test_clean_up_variants_equal_runs_with_that_clean_up():
    """generate(cleanups=): the same episodes cleaned up another way equal a whole run with that
    loop configuration, bit for bit (the ablation rows of `evaluate` rest on this); a variant
    that would change the episodes themselves is refused."""
    import dataclasses

    loaded = _loaded()
    goals = [Goal([1.5, 2.0]), Goal([0.0, 3.5], "sit", 1.0)]
    loop = LoopConfig(stall_s=None, smooth=2.0)                  # on whatever the model rate
    off = {"smoothing": dataclasses.replace(loop, smooth=0.0), "seat_height": dataclasses.replace(loop, seat_shift=False)}
    kw = dict(sampler=SamplerSettings("ddim", 2))
    both = _generate(loaded, goals, loop=loop, cleanups=off, generator=torch.Generator().manual_seed(0), **kw)
    assert set(both.variants) == set(off)
    for name, lc in off.items():
        alone = _generate(loaded, goals, loop=lc, generator=torch.Generator().manual_seed(0), **kw)
        assert np.array_equal(both.variants[name].joints, alone.joints), name
        assert np.array_equal(both.variants[name].joints_raw, both.joints_raw)          # the same episodes
    assert not np.array_equal(both.variants["smoothing"].joints, both.joints)            # the stage does something
    with pytest.raises(ConfigError, match="seam_blend"):
        _generate(loaded, goals, loop=loop, cleanups={"x": dataclasses.replace(loop, seam_blend=0.0)}, **kw)


def _pick_up_a_cup(p_hand, **loop_kw):
    """The oracle walks from (0, 0) to pick up a cup (r 4 cm, 10 cm tall) beside its goal (0, 2),
    under the left wrist of a T-pose facing +z, with no body (loop.project=false: the network's
    own joints are what is checked, and a solve would only cost time). Returns (the motion, the
    cup's voxel centres (N, 3))."""
    n = 8                                                                                # 1 cm voxels
    ii, kk = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    cup_occ = np.repeat((((ii - 3.5) ** 2 + (kk - 3.5) ** 2) <= 3.5 ** 2)[:, None, :], 10, 1)
    cup = OccupancyGrid.from_dense(cup_occ, [-0.04, 0.0, -0.04], 0.01)
    cup_pose = np.eye(4)
    cup_pose[:3, 3] = [0.7, 0.9, 2.0]
    cup_pts = (np.argwhere(cup_occ) + 0.5) * 0.01 + cup.origin + cup_pose[:3, 3]         # (N, 3)
    loaded = _loaded(predict_goal=True)
    loaded.action_names = ["walk", "sit", "pick up"]
    loaded.mask = MaskConfig(max_transition=2, p_hand=p_hand, hand_joints=HAND_JOINTS)
    m = _generate(loaded, [Goal([0.0, 2.0], "pick up", 3.0)], objects=[(cup, cup_pose)],
                  generator=torch.Generator().manual_seed(0), sampler=SamplerSettings("ddim", 2),
                  loop=LoopConfig(stall_s=None, project=False, **loop_kw))
    assert m.completed, m.goal_outcome
    return m, cup_pts


def _wrist_to_cup(m, cup_pts, kind) -> np.ndarray:
    """(A,) the left wrist's distance to the cup at the last frame of each episode of `kind`."""
    ends = np.stack([e.raw[0, -1] for e in m.episodes if e.kind == kind])                # (A, J, 3)
    return np.linalg.norm(ends[:, HAND_JOINTS[0], None] - cup_pts[None], axis=-1).min(-1)


def test_pick_up_episodes_give_the_network_the_hand_goal_it_was_trained_on():
    """A checkpoint trained with hand goals (mask.p_hand > 0, either wrist) is told, in each
    pick-up episode, where the nearer wrist goes: a point `palm` out from the cup's surface, at
    the window's last frame. The oracle predicts what it is given there, so the network's own
    wrist ends each pick-up episode 3 cm off the cup; without the goal (loop.hand_goal=() or a
    checkpoint trained without hand goals) it stays where the T-pose holds it."""
    given = _wrist_to_cup(*_pick_up_a_cup(0.5), "act")
    assert len(given) >= 2 and np.all((given > 0.03) & (given < 0.03 + 0.01)), given   # 3 cm off the skin (voxel centres +0.5 cm)
    for m, cup_pts in (_pick_up_a_cup(0.5, hand_goal=()), _pick_up_a_cup(0.0)):
        off = _wrist_to_cup(m, cup_pts, "act")
        assert np.all(off > 0.3), off


def test_the_episode_that_arrives_at_a_pick_up_is_given_its_hand_goal():
    """`loop.hand_goal_on_arrival`: the walk episode that ends on the pick-up's spot gets the
    pick-up's hand goal, so the body arrives with its wrist at the cup (the oracle's wrist 3 cm
    off it at that episode's last frame); switched off, the wrist arrives where the T-pose holds
    it, 0.39 m from the cup. Earlier walk episodes, whose target is short of the spot, get none."""
    m, cup_pts = _pick_up_a_cup(0.5)
    walks = _wrist_to_cup(m, cup_pts, "walk")
    assert len(walks) >= 2, walks
    assert 0.03 < walks[-1] < 0.04 and np.all(walks[:-1] > 0.3), walks
    m, cup_pts = _pick_up_a_cup(0.5, hand_goal_on_arrival=False)
    assert np.all(_wrist_to_cup(m, cup_pts, "walk") > 0.3)


def _facings_asked(**loop_kw) -> tuple:
    """(the motion, the facing goal given in each denoising call) of the cup's pick-up
    (`_pick_up_a_cup`) by a checkpoint trained with one (mask.p_facing > 0): (S, 2) (sin, cos),
    NaN where not given, or None when the call has no facing at all."""
    class Recording(Oracle):
        def forward(self, x_t, t, cond, known_mask=None):
            self.conditions.append(None if cond.facing is None else
                                   torch.where(cond.facing_given[:, None], cond.facing, torch.nan).numpy())
            return super().forward(x_t, t, cond, known_mask)

    loaded = _loaded(Recording, predict_goal=True)
    loaded.action_names = ["walk", "sit", "pick up"]
    loaded.mask = MaskConfig(max_transition=2, p_hand=0.5, hand_joints=HAND_JOINTS, p_facing=0.5)
    cup = OccupancyGrid.from_dense(np.ones((8, 10, 8), bool), [-0.04, 0.0, -0.04], 0.01)
    pose = np.eye(4)
    pose[:3, 3] = [0.7, 0.9, 2.0]
    m = _generate(loaded, [Goal([0.0, 2.0], "pick up", 3.0)], objects=[(cup, pose)],
                  generator=torch.Generator().manual_seed(0), sampler=SamplerSettings("ddim", 2),
                  loop=LoopConfig(stall_s=None, project=False, **loop_kw))
    return m, loaded.model.conditions


def test_episodes_with_a_hand_goal_ask_a_facing_checkpoint_to_face_the_object():
    """The cup stands 0.7 m to the +x side of the pick-up's spot (0, 2), which the body walks to
    along +z: the pick-up's episodes ask the body to end facing +x, yaw 90 degrees in the window
    frame, (sin, cos) = (1, 0), within 6 degrees (from the episode's pelvis goal, a few cm from
    the spot); the walking episodes ask nothing, the one that walks onto the spot with the hand
    goal included. loop.facing_goal=false asks nothing anywhere."""
    m, asked = _facings_asked()
    kinds = [e.kind for e in m.episodes for _ in range(2)]                             # DDIM-2: two calls each
    given = [f[0] for f in asked if f is not None and np.isfinite(f[0, 0])]
    assert all(f is not None for f in asked) and len(asked) == len(kinds)
    assert [np.isfinite(f[0, 0]) for f in asked] == [k == "act" for k in kinds] and "act" in kinds
    np.testing.assert_allclose(given, [[1.0, 0.0]] * len(given), atol=0.1)
    assert all(f is None for f in _facings_asked(facing_goal=False)[1])


def test_facing_on_arrival_also_asks_the_episode_that_walks_onto_the_spot():
    """`loop.facing_on_arrival`: the walking episode given the pick-up's hand goal (the last
    one, which walks onto the spot) is asked to face the cup too, towards +x from its own pelvis
    goal; the walking episodes before it, which get no hand goal, are not."""
    m, asked = _facings_asked(facing_on_arrival=True)
    kinds = [e.kind for e in m.episodes for _ in range(2)]                             # DDIM-2: two calls each
    walk_given = [np.isfinite(f[0, 0]) for f, k in zip(asked, kinds) if k == "walk"]
    assert len(walk_given) >= 4 and walk_given[-2:] == [True, True] and not any(walk_given[:-2]), walk_given
    arrival = [f[0] for f, k in zip(asked, kinds) if k == "walk" and np.isfinite(f[0, 0])]
    assert all(f[0] > 0.5 for f in arrival), arrival                                  # sin(yaw) > 0.5: towards +x
    assert all(np.isfinite(f[0, 0]) for f, k in zip(asked, kinds) if k == "act")
