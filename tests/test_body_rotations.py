"""Rotation conversions: round trips and agreement with scipy."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from motiongen.body import rotations as rot


def _random_aa(n, rng, max_angle=np.pi - 1e-3):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return axis * rng.uniform(0, max_angle, size=(n, 1))


@pytest.fixture
def aa():
    rng = np.random.default_rng(0)
    a = _random_aa(500, rng)
    a[:5] *= 1e-5                                  # near-identity: the Taylor branches
    a[5] = 0.0
    a[6:10] = _random_aa(4, rng, 1.0) / np.linalg.norm(_random_aa(4, rng, 1.0), axis=1, keepdims=True) * (np.pi - 1e-4)
    return a


def test_axis_angle_to_matrix_matches_scipy(aa):
    R = rot.axis_angle_to_matrix(torch.as_tensor(aa)).numpy()
    np.testing.assert_allclose(R, Rotation.from_rotvec(aa).as_matrix(), atol=1e-10)


def test_matrix_to_axis_angle_and_quaternion_match_scipy(aa):
    R = Rotation.from_rotvec(aa).as_matrix()
    np.testing.assert_allclose(rot.matrix_to_axis_angle(torch.as_tensor(R)).numpy(), Rotation.from_matrix(R).as_rotvec(),
                               atol=1e-6)
    q = rot.matrix_to_quaternion(torch.as_tensor(R)).numpy()                 # (w, x, y, z), w >= 0
    q_sp = Rotation.from_matrix(R).as_quat()[:, [3, 0, 1, 2]]
    q_sp *= np.where(q_sp[:, :1] < 0, -1, 1)
    np.testing.assert_allclose(np.abs((q * q_sp).sum(1)), 1.0, atol=1e-9)     # same rotation
    np.testing.assert_allclose(rot.quaternion_to_matrix(torch.as_tensor(q)).numpy(), R, atol=1e-9)
    np.testing.assert_allclose(rot.axis_angle_to_quaternion(torch.as_tensor(aa)).numpy(), q_sp, atol=1e-6)


def test_rot6d_round_trip_and_batching(aa):
    R = rot.axis_angle_to_matrix(torch.as_tensor(aa).reshape(5, 100, 3))   # batched leading dims
    d6 = rot.matrix_to_rot6d(R)
    assert d6.shape == (5, 100, 6)
    np.testing.assert_allclose(d6[..., :3].numpy(), R[..., :, 0].numpy())   # first column
    np.testing.assert_allclose(rot.rot6d_to_matrix(d6).numpy(), R.numpy(), atol=1e-10)
    # Gram-Schmidt maps any (non-degenerate) 6-vector to a rotation.
    M = rot.rot6d_to_matrix(torch.randn(50, 6, dtype=torch.float64))
    np.testing.assert_allclose((M @ M.transpose(-1, -2)).numpy(), np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-10)
    np.testing.assert_allclose(torch.det(M).numpy(), 1.0, atol=1e-10)
    np.testing.assert_allclose(rot.rot6d_to_axis_angle(rot.axis_angle_to_rot6d(torch.as_tensor(aa))).numpy(),
                               Rotation.from_rotvec(aa).as_rotvec(), atol=1e-6)


def test_gradients_are_finite_at_identity():
    a = torch.zeros(4, 3, requires_grad=True)
    rot.axis_angle_to_matrix(a).sum().backward()
    assert torch.isfinite(a.grad).all()
    R = torch.eye(3).expand(4, 3, 3).clone().requires_grad_(True)
    rot.matrix_to_axis_angle(R).sum().backward()
    assert torch.isfinite(R.grad).all()
    ok = torch.autograd.gradcheck(rot.axis_angle_to_matrix, torch.randn(3, 3, dtype=torch.float64, requires_grad=True))
    assert ok


def test_geodesic_angle():
    aa = torch.tensor([[0.0, 0.3, 0.0]], dtype=torch.float64)
    R = rot.axis_angle_to_matrix(aa)
    assert rot.geodesic_angle(R, torch.eye(3, dtype=torch.float64)[None]).item() == pytest.approx(0.3, abs=1e-6)
