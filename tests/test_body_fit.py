"""Joints -> SMPL-X: the 3-frame MLP, initialisation, refinement, AMASS output."""

import subprocess
import sys

import numpy as np
import pytest
import torch

from motiongen.body.analytic import analytic_init, posed_joints, swing
from motiongen.body.fit import FitResult, RefineConfig, fit_joints, refine, save_amass_npz
from motiongen.body.mlp import JointsToBodyMLP, MLPConfig, canonicalise, triplets
from motiongen.body.model import forward_kinematics
from motiongen.body.random_motion import joint_limits, sample_motion
from motiongen.body.rotations import axis_angle_to_matrix, geodesic_angle, matrix_to_axis_angle
from motiongen.errors import ConfigError
from motiongen.geometry import yaw_matrix


def _motion(bm, T, seed, gait=None):
    m = sample_motion(T, 30.0, np.random.default_rng(seed), gait=gait)
    p = {k: torch.as_tensor(v) for k, v in m.items()}
    with torch.no_grad():
        X = bm.joints(p["global_orient"], p["body_pose"], p["transl"], p["betas"])
    return X, p


def _local_rotmats(p):
    return axis_angle_to_matrix(torch.cat([p["global_orient"][:, None], p["body_pose"].reshape(-1, 21, 3)], 1))


def _max_angular_accel_deg(R):
    """R (T, J, 3, 3) -> max over frames/joints of |ω_{t+1} − ω_t| in degrees per frame²."""
    w = matrix_to_axis_angle(R[1:] @ R[:-1].transpose(-1, -2))
    return torch.rad2deg((w[1:] - w[:-1]).norm(dim=-1)).max().item()


def test_triplets_duplicate_the_middle_frame_at_edges():
    x = torch.arange(2 * 22 * 3, dtype=torch.float32).reshape(2, 22, 3)
    tr = triplets(x)                                             # (T, 3, 22, 3)
    assert tr.shape == (2, 3, 22, 3)
    for t, (a, b, c) in enumerate([(0, 0, 1), (0, 1, 1)]):
        assert torch.equal(tr[t, 0], x[a]) and torch.equal(tr[t, 1], x[b]) and torch.equal(tr[t, 2], x[c])
    assert torch.equal(triplets(x[:1])[0], x[:1].expand(3, 22, 3))


@pytest.mark.parametrize("T", [1, 2, 3, 7])
def test_mlp_predicts_any_length(bm, T):
    X, _ = _motion(bm, max(T, 3), seed=1)
    mlp = JointsToBodyMLP(MLPConfig(width=32, num_betas=10))
    out = mlp.predict(X[:T])
    assert out["rotmats"].shape == (T, 22, 3, 3) and out["betas"].shape == (10,)
    R = out["rotmats"]
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3).expand(T, 22, 3, 3), atol=1e-5, rtol=0)


def test_canonical_features_ignore_heading_and_position(bm):
    X, _ = _motion(bm, 5, seed=2)
    f0, yaw0 = canonicalise(triplets(X))
    Ry = yaw_matrix(torch.tensor(1.1))
    X2 = X @ Ry.T + torch.tensor([3.0, 0.0, -2.0])
    f1, yaw1 = canonicalise(triplets(X2))
    torch.testing.assert_close(f0, f1, atol=1e-5, rtol=0)
    torch.testing.assert_close(torch.remainder(yaw1 - yaw0, 2 * np.pi), torch.full_like(yaw0, 1.1), atol=1e-5, rtol=0)


def test_sampled_motion_respects_joint_limits():
    m = sample_motion(300, 30.0, np.random.default_rng(3))
    lim = joint_limits()
    pose = m["body_pose"].reshape(-1, 21, 3)
    assert (pose >= lim[..., 0] - 0.85 * np.abs(lim[..., 0]) - 1e-6).all()   # gait overlay mixes in
    assert np.isfinite(pose).all() and m["transl"].shape == (300, 3)


def test_refinement_recovers_known_parameters(bm):
    X, p = _motion(bm, 90, seed=4, gait=True)
    R_gt = _local_rotmats(p)
    g = torch.Generator().manual_seed(0)
    # An MLP's errors are smooth in time: a fixed 0.15 rad per-joint offset plus a little jitter.
    noise = 0.15 * torch.randn(1, 22, 3, generator=g) + 0.02 * torch.randn(R_gt.shape[:-1], generator=g)
    R_mlp = R_gt @ axis_angle_to_matrix(noise)
    R_init = analytic_init(X, bm.rest_joints(torch.zeros(10)), R_mlp)                     # as fit_joints does
    R, transl, betas, steps, _ = refine(bm, X, R_init, torch.zeros(10), RefineConfig(max_steps=40))
    J = bm.joints_from_rotmats(R, transl, betas)
    assert (J - X).norm(dim=-1).mean() < 0.005
    assert (transl - p["transl"]).norm(dim=-1).max() < 0.02
    assert torch.rad2deg(geodesic_angle(R[:, 0], R_gt[:, 0])).max() < 3.0
    # Joints with a child in the body set have observable swing (twist is only weakly
    # observable): their rotations get closer to the truth than the noisy prediction.
    inner = [1, 2, 3, 4, 5, 6, 7, 8, 9, 12, 16, 17, 18, 19]
    err = geodesic_angle(R[:, inner], R_gt[:, inner]).median()
    assert err < 0.8 * geodesic_angle(R_mlp[:, inner], R_gt[:, inner]).median()


def test_fit_joints_analytic_init_is_accurate_and_smooth(bm):
    X, p = _motion(bm, 120, seed=5)
    fit = fit_joints(X, bm, None)
    assert isinstance(fit, FitResult) and fit.init == "analytic" and fit.mpjpe_mlp is None
    assert fit.mpjpe < 0.01 and fit.per_frame_error.max() < 0.02
    assert fit.mpjpe < fit.mpjpe_init
    R = axis_angle_to_matrix(torch.as_tensor(np.concatenate([fit.global_orient[:, None],
                                                             fit.body_pose.reshape(-1, 21, 3)], 1)))
    steps = torch.rad2deg(geodesic_angle(R[1:], R[:-1]))
    assert steps.max() < 30.0                                     # no 180° flips
    gt = _max_angular_accel_deg(_local_rotmats(p))
    assert _max_angular_accel_deg(R) < max(2 * gt, gt + 3.0)      # no jitter


def test_analytic_init_points_bones_at_targets(bm):
    X, p = _motion(bm, 10, seed=6)
    R = analytic_init(X, bm.rest_joints(p["betas"]))
    J = bm.joints_from_rotmats(R, X[:, 0] - bm.rest_joints(p["betas"])[0], p["betas"])
    assert (J - X).norm(dim=-1).max() < 1e-4                       # exact with the true shape


def test_swing_and_its_numpy_kinematics_agree_with_forward_kinematics(bm):
    # The sampler's projection stays in numpy between its two swings: its posed joints must be
    # forward kinematics' joints of the same rotations (float64 both ways), and on a body's own
    # motion they are the targets themselves.
    X, p = _motion(bm, 12, seed=8)
    rest = bm.rest_joints(p["betas"]).double()
    X64 = X.double().numpy() - X[:, :1].double().numpy() + rest[0].numpy()                 # root at rest[0]
    R, G = swing(X64, np.broadcast_to(rest.numpy(), X64.shape))
    P = posed_joints(G, np.broadcast_to(rest.numpy(), X64.shape))
    P_fk, G_fk = forward_kinematics(torch.from_numpy(R), rest, bm.parents, bm._levels)
    np.testing.assert_allclose(P, P_fk.numpy(), atol=1e-12)
    np.testing.assert_allclose(G, G_fk.numpy(), atol=1e-12)
    assert np.abs(P - X64).max() < 1e-4                                                   # exact with the true shape


def test_known_betas_contact_and_adam(bm):
    X, p = _motion(bm, 40, seed=7, gait=True)
    contact = np.zeros((40, 4), bool)
    contact[:4] = True                                             # a short planted span: the lock term runs
    fit = fit_joints(X, bm, None, betas=p["betas"], contact=contact,
                     config=RefineConfig(w_contact=1.0, max_steps=10))
    np.testing.assert_allclose(fit.betas, p["betas"].numpy())
    assert fit.mpjpe < 0.02
    fit2 = fit_joints(X, bm, None, config=RefineConfig(optimizer="adam", max_steps=20))
    assert fit2.steps <= 20 and np.isfinite(fit2.mpjpe)
    with pytest.raises(ConfigError):
        fit_joints(X, bm, None, config=RefineConfig(optimizer="sgd"))


def test_fit_joints_rejects_bad_input(bm):
    with pytest.raises(ConfigError, match="shape"):
        fit_joints(np.zeros((10, 21, 3)), bm)
    bad = np.zeros((10, 22, 3))
    bad[3, 4, 1] = np.nan
    with pytest.raises(ConfigError, match="NaN"):
        fit_joints(bad, bm)


def test_amass_npz(bm, tmp_path):
    X, _ = _motion(bm, 12, seed=8)
    fit = fit_joints(X, bm, None, refine_steps=5)
    path = save_amass_npz(tmp_path / "out" / "params.npz", fit, fps=30.0)
    with np.load(path) as z:
        assert z["poses"].shape == (12, 165) and z["trans"].shape == (12, 3) and z["betas"].shape == (10,)
        np.testing.assert_allclose(z["poses"][:, :3], z["root_orient"])
        np.testing.assert_allclose(z["poses"][:, 3:66], z["pose_body"])
        assert (z["poses"][:, 66:] == 0).all() and float(z["mocap_framerate"]) == 30.0
        assert str(z["gender"]) == "neutral" and z["joint_error"].shape == (12,)
        # the saved parameters reproduce the fitted joints
        J = bm.joints(torch.as_tensor(z["root_orient"]), torch.as_tensor(z["pose_body"]), torch.as_tensor(z["trans"]),
                      torch.as_tensor(z["betas"]))
        np.testing.assert_allclose(J.numpy(), fit.joints, atol=1e-5)
    assert sorted(p.name for p in path.parent.iterdir()) == ["params.npz"]


def test_train_mlp_checkpoint_round_trip_and_fit(bm, tmp_path):
    from motiongen.body.train_mlp import DataConfig, TrainMLPConfig, load_mlp, save_checkpoint, train

    cfg = TrainMLPConfig(steps=40, batch_size=64, log_every=20, threads=1, mlp=MLPConfig(width=64),
                         data=DataConfig(num_sequences=8, seq_frames=60))
    model = train(cfg, bm=bm, log_dir=str(tmp_path / "tb"), verbose=False)
    assert any((tmp_path / "tb").iterdir())
    path = save_checkpoint(model, cfg, tmp_path / "mlp.pt")
    again = load_mlp(path)
    X, _ = _motion(bm, 20, seed=9)
    torch.testing.assert_close(again.predict(X)["rotmats"], model.predict(X)["rotmats"])
    fit = fit_joints(X, bm, str(path))
    assert fit.init == "mlp" and fit.mpjpe_mlp is not None and fit.mpjpe < 0.015


def test_refine_imports_no_compiler_and_still_converges():
    """refine's L-BFGS is built without importing torch's compiler (a 1.4 s import on the
    first optimizer of a process, nothing compiled): in a fresh process a refine leaves
    torch._dynamo unloaded and still fits its target, and the optimizer's wrapper is as it was."""
    code = """
import sys, torch
from motiongen.body.fit import RefineConfig, refine
from motiongen.body.model import load_body_model
bm = load_body_model(None)
R0 = torch.eye(3).expand(8, 22, 3, 3).clone()
X = bm.joints_from_rotmats(R0, torch.zeros(8, 3), torch.zeros(10)) + torch.tensor([0.1, 0.0, 0.0])
R, transl, _, steps, _ = refine(bm, X, R0, torch.zeros(10), RefineConfig(max_steps=20), fixed_betas=True)
assert steps >= 1 and (transl - torch.tensor([0.1, 0.0, 0.0])).norm(dim=-1).max() < 1e-3, transl
print("torch._dynamo" in sys.modules, hasattr(torch.optim.Optimizer.add_param_group.__wrapped__, "__dynamo_disable"))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["False", "False"]          # no compiler loaded, the wrapper's cache left empty
