"""Body model: procedural SMPL-X file, fast joint kinematics vs smplx / our LBS mesh."""

import numpy as np
import pytest
import torch

from motiongen.body.model import BodyModel, load_body_model
from motiongen.body.procedural import NUM_VERTICES, SMPLX_PARENTS, build_procedural_model
from motiongen.errors import DataError


def _params(T, seed=0, scale=0.5):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(T, 3, generator=g), torch.randn(T, 63, generator=g) * scale,
            torch.randn(T, 3, generator=g), torch.randn(T, 10, generator=g))


def test_procedural_file_layout_and_determinism(model_path):
    a = build_procedural_model()
    with np.load(model_path) as z:
        for k in ("v_template", "shapedirs", "J_regressor", "weights", "posedirs", "f"):
            np.testing.assert_array_equal(z[k], a[k])
    assert a["v_template"].shape == (NUM_VERTICES, 3)
    assert a["shapedirs"].shape == (NUM_VERTICES, 3, 20)
    assert a["posedirs"].shape == (NUM_VERTICES, 3, 486)
    assert a["J_regressor"].shape == (55, NUM_VERTICES)
    np.testing.assert_allclose(a["weights"].sum(1), 1.0, atol=1e-9)
    np.testing.assert_allclose(a["J_regressor"].sum(1), 1.0, atol=1e-9)
    assert tuple(a["kintree_table"][0, 1:]) == SMPLX_PARENTS[1:]
    assert a["f"].max() < NUM_VERTICES


def test_shape_directions_change_height_and_bones(bm):
    def height(b):
        return (bm.rest_joints(b)[15, 1] - bm.rest_joints(b)[10, 1]).item()   # head above left toe
    b = torch.zeros(10)
    tall = b.clone()
    tall[0] = 2.0
    assert height(tall) > 1.08 * height(b)
    legs = b.clone()
    legs[1] = 2.0
    J0, J1 = bm.rest_joints(b), bm.rest_joints(legs)
    assert (J1[7] - J1[4]).norm() > 1.1 * (J0[7] - J0[4]).norm()             # shin longer
    assert 1.45 < height(b) < 1.6    # head joint over toe joint: a stature of about 1.7 m


def test_joints_match_our_lbs_mesh(bm):
    # The procedural regressor averages a ring centred on each joint, and skinning is linear,
    # so joints regressed from the posed mesh equal the kinematic joints exactly.
    go, bp, tr, be = _params(8, seed=1)
    J = bm.joints(go, bp, tr, be)
    np.testing.assert_allclose(J.numpy(), bm.regress_joints(bm.vertices(go, bp, tr, be)).numpy(), atol=1e-5)


def test_joints_match_smplx_package(bm, model_path):
    smplx = pytest.importorskip("smplx")
    T = 16
    go, bp, tr, be = _params(T, seed=2)
    m = smplx.SMPLX(str(model_path), num_betas=10, use_pca=False, flat_hand_mean=True, batch_size=T)
    with torch.no_grad():
        out = m(global_orient=go, body_pose=bp, transl=tr, betas=be, return_verts=True)
    J = bm.joints(go, bp, tr, be)
    np.testing.assert_allclose(J.numpy(), out.joints[:, :22].numpy(), atol=1e-5)
    np.testing.assert_allclose(bm.vertices(go, bp, tr, be).numpy(), out.vertices.numpy(), atol=1e-5)


def test_batching_broadcasting_and_gradients(bm):
    go, bp, tr, be = _params(6, seed=3)
    J = bm.joints(go.reshape(2, 3, 3), bp.reshape(2, 3, 63), tr.reshape(2, 3, 3), be[0])   # shared betas
    assert J.shape == (2, 3, 22, 3)
    np.testing.assert_allclose(J.reshape(6, 22, 3).numpy(), bm.joints(go, bp, tr, be[0].expand(6, 10)).numpy(), atol=1e-6)
    bp = bp.clone().requires_grad_(True)
    be = be.clone().requires_grad_(True)
    bm.joints(go, bp, tr, be).square().sum().backward()
    assert torch.isfinite(bp.grad).all() and bp.grad.abs().sum() > 0 and be.grad.abs().sum() > 0


def test_missing_or_bad_model_file(tmp_path, monkeypatch):
    with pytest.raises(DataError, match="not found"):
        BodyModel(tmp_path / "nope.npz")
    np.savez(tmp_path / "bad.npz", v_template=np.zeros((3, 3)))
    with pytest.raises(DataError, match="shapedirs"):
        BodyModel(tmp_path / "bad.npz")
    monkeypatch.setenv("MOTIONGEN_SMPLX_MODEL", str(tmp_path / "missing.npz"))
    with pytest.raises(DataError, match="MOTIONGEN_SMPLX_MODEL"):
        load_body_model()
