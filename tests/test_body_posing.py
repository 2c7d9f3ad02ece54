"""The final solve's hand-written posing pass is the autograd map it replaces: same joints, same
rotations, same gradients, on a body, on raw (unnormalised) 6D parameters and at a zero gradient."""

import pytest
import torch

from motiongen.body.model import BodyModel
from motiongen.body.posing import FixedBodyPose
from motiongen.body.rotations import rot6d_to_matrix


@pytest.fixture(scope="module")
def bm64(model_path):
    return BodyModel(model_path, dtype=torch.float64)


def _autograd_pose(bm, betas, rot6d, transl):
    R = rot6d_to_matrix(rot6d)
    return bm.joints_from_rotmats(R, transl, betas), R


def _inputs(T, seed, dtype):
    g = torch.Generator().manual_seed(seed)
    rot6d = torch.randn(T, 22, 6, generator=g, dtype=dtype) * 1.5            # far from orthonormal: Gram-Schmidt's work
    transl = torch.randn(T, 3, generator=g, dtype=dtype)
    betas = torch.randn(10, generator=g, dtype=dtype) * 0.5
    wJ, wR = torch.randn(T, 22, 3, generator=g, dtype=dtype), torch.randn(T, 22, 3, 3, generator=g, dtype=dtype)
    return rot6d, transl, betas, wJ, wR


def test_posing_matches_autograd_in_value_and_gradient(bm64):
    bm = bm64
    rot6d, transl, betas, wJ, wR = _inputs(7, seed=0, dtype=torch.float64)
    pose = FixedBodyPose(bm.rest_joints(betas), bm.parents)
    results = []
    for fn in (lambda r, t: pose(r, t), lambda r, t: _autograd_pose(bm, betas, r, t)):
        r, t = rot6d.clone().requires_grad_(True), transl.clone().requires_grad_(True)
        J, R = fn(r, t)
        ((J * wJ).sum() + (R * wR).sum()).backward()                          # a loss on both outputs
        results.append((J.detach(), R.detach(), r.grad, t.grad))
    for mine, ref in zip(*results):
        torch.testing.assert_close(mine, ref, rtol=1e-10, atol=1e-10)
    assert results[1][2].abs().max() > 0.1                                    # the comparison is not of zeros


def test_posing_gradient_of_one_output_alone(bm64):
    """A loss on the joints only (no gradient reaches the rotations output) and the finite-difference check."""
    bm = bm64
    rot6d, transl, betas, wJ, _ = _inputs(3, seed=1, dtype=torch.float64)
    pose = FixedBodyPose(bm.rest_joints(betas), bm.parents)
    r, t = rot6d.clone().requires_grad_(True), transl.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda a, b: pose(a, b)[0], (r, t))
    J, _ = pose(r, t)
    (J * wJ).sum().backward()
    torch.testing.assert_close(t.grad, wJ.sum(1))                              # every joint moves with the root
