"""The clean-up after the last episode, on known episodes: where the final solve holds a
planted foot (`loop.foot_height`)."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from motiongen.body.solve import MotionBody
from motiongen.sampling.cleanup import clean_up
from motiongen.sampling.episode import EpisodeState
from motiongen.sampling.settings import LoopConfig
from motiongen.skeleton import BODY, FOOT_JOINTS

FPS = 15.0


def _episodes(bm, frames: int = 30) -> tuple[EpisodeState, np.ndarray]:
    """One sample standing still for `frames` model frames, the left foot planted throughout:
    the projected body's joints, and the network's, whose left foot is 1.5 cm lower (the body's
    legs shorter than the network's). Returns (state, the network's joints (Tm, 22, 3))."""
    betas = torch.zeros(1, 10)
    with torch.no_grad():
        X = bm.joints(torch.zeros(1, 3), torch.zeros(1, 63), torch.zeros(1, 3), betas).double().numpy()
    X = np.repeat(X[None], frames, 1)                                       # (1, Tm, 22, 3)
    X[..., 1] += 0.035 - X[..., 1].min()                                    # toes 3.5 cm up
    raw = X.copy()
    raw[:, :, list(FOOT_JOINTS[:2]), 1] -= 0.015
    stance = np.zeros((1, frames, 4), bool)
    stance[:, :, :2] = True
    state = EpisodeState(body=MotionBody(bm, BODY, betas), frames=[X], raws=[raw], stances=[stance],
                         rots=[torch.eye(3, dtype=torch.float64).expand(1, frames, 22, 3, 3).clone()],
                         labels=[np.zeros((1, frames), int)])
    return state, raw[0]


@pytest.mark.parametrize("height", ["network", "body"])
def test_a_planted_foot_is_held_where_foot_height_says(bm, height):
    """`network` (the default): the left foot stays at the network's height, 1.5 cm below the
    projected body's; `body`: at the projected body's. Within 3 mm either way, the foot still."""
    state, raw = _episodes(bm)
    layout = SimpleNamespace(contact_joints=FOOT_JOINTS, num_contacts=4)
    plan = SimpleNamespace(names=["walk"], goals=[])
    out = clean_up(state, layout, FPS, plan, LoopConfig(foot_height=height), None, None).joints[0]   # (T, 22, 3)
    left = list(FOOT_JOINTS[:2])
    want = raw[0, left, 1] if height == "network" else state.frames[0][0, 0, left, 1]
    np.testing.assert_allclose(out[:, left, 1], np.broadcast_to(want, (len(out), 2)), atol=0.003)
    assert np.ptp(out[:, left], axis=0).max() < 0.003


def test_smoothing_goes_by_the_model_rate(bm):
    """`loop.smooth` unset: a 15 fps model's joints are smoothed before the final solve (its
    jittering wrist moves less than with smooth=0), a 10 fps model's are not (smooth=0's joints,
    bit for bit). Without a body, so the output is the joints the solve would start from."""
    state, _ = _episodes(bm)
    state.body = None
    wrist = BODY.index("left_wrist")
    state.frames[0][0, 1::2, wrist, 0] += 0.03                              # 3 cm of frame-to-frame jitter
    layout = SimpleNamespace(contact_joints=FOOT_JOINTS, num_contacts=4)
    plan = SimpleNamespace(names=["walk"], goals=[])

    def out(fps, **kw):
        return clean_up(state, layout, fps, plan, LoopConfig(project=False, **kw), None, None).joints[0]

    jitter = lambda x: np.abs(np.diff(x[:, wrist, 0], 2)).mean()           # noqa: E731
    assert jitter(out(15.0)) < 0.5 * jitter(out(15.0, smooth=0.0))
    np.testing.assert_array_equal(out(10.0), out(10.0, smooth=0.0))


def test_swing_clearance_goes_by_the_model_rate(bm, monkeypatch):
    """The final solve holds a swinging foot at its predicted height with the solve's own weight
    (300) from 15 fps, with 10 below (a 10 fps model's swings keep their height under its weaker
    smoothness), and not at all with `loop.swing_clearance=false`."""
    import motiongen.sampling.cleanup as cleanup
    from motiongen.body.solve import SOLVE_CONFIG

    seen = []
    solve = cleanup.solve_bodies

    def recording(*args, cfg=None, **kw):
        seen.append(cfg.w_clearance)
        return solve(*args, cfg=cfg, **kw)

    monkeypatch.setattr(cleanup, "solve_bodies", recording)
    layout = SimpleNamespace(contact_joints=FOOT_JOINTS, num_contacts=4)
    plan = SimpleNamespace(names=["walk"], goals=[])
    for fps, kw in ((15.0, {}), (10.0, {}), (10.0, {"swing_clearance": False})):
        state, _ = _episodes(bm, frames=12)
        clean_up(state, layout, fps, plan, LoopConfig(solve="joint-space", **kw), None, None)
    assert seen == [SOLVE_CONFIG.w_clearance, 10.0, 0.0] and SOLVE_CONFIG.w_clearance == 300.0
