"""A window put on the motion's body: a network skeleton smaller than the body is scaled up to
it before the projection, so the body stands as the network's pose does instead of crouching."""

import numpy as np
import torch

from motiongen.body.random_motion import sample_motion
from motiongen.body.solve import MotionBody
from motiongen.metrics import knee_angles
from motiongen.sampling.projection import body_size_ratio, project_window
from motiongen.skeleton import BODY, PELVIS


def _walk(bm, T=16, seed=4):
    """(T, 22, 3) a body's walk with its lowest joint on the floor (y = 0), and its betas."""
    p = sample_motion(T, rng=np.random.default_rng(seed), gait=True)
    t = {k: torch.as_tensor(v) for k, v in p.items()}
    with torch.no_grad():
        X = bm.joints(t["global_orient"], t["body_pose"], t["transl"], t["betas"]).double().numpy()
    X[..., 1] -= X[..., 1].min()
    return X, t["betas"]


def _shrunk(X, s):
    """Every frame scaled by s about the floor point under its pelvis."""
    c = X[:, PELVIS:PELVIS + 1].copy()
    c[..., 1] = 0.0
    return c + s * (X - c)


def test_a_smaller_skeleton_is_scaled_back_to_the_body(bm):
    X, betas = _walk(bm)
    body = MotionBody(bm, BODY, betas[None])
    small = _shrunk(X, 0.85)[None]                                     # (1, T, 22, 3) the network at 85 %
    np.testing.assert_allclose(body_size_ratio(small, body), 1 / 0.85, rtol=1e-6)
    stance = np.zeros((1, len(X), 4), bool)
    J, _, _ = project_window(small, stance, None, 0, 0, body, scale=True)
    assert np.abs(J[0] - X).max() < 1e-4                               # the body's own walk comes back
    np.testing.assert_allclose(J[0, :, PELVIS, [0, 2]], small[0, :, PELVIS, [0, 2]], atol=1e-9)


def test_without_the_scale_the_body_crouches_under_a_smaller_skeleton(bm):
    X, betas = _walk(bm)
    body = MotionBody(bm, BODY, betas[None])
    small = _shrunk(X, 0.85)[None]
    stance = np.zeros((1, len(X), 4), bool)
    J, _, _ = project_window(small, stance, None, 0, 0, body, scale=False)
    np.testing.assert_allclose(J[0, :, PELVIS], small[0, :, PELVIS], atol=1e-9)   # the pelvis where the network put it
    assert np.median(knee_angles(X) - knee_angles(J[0])) > 15.0       # degrees more bent than the walk's knees
