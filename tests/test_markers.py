"""Body-surface markers (LEMO / SSM2 style) on the procedural SMPL-X body, and the rotation-matrix
mesh path they are posed with."""

import numpy as np
import pytest
import torch
import trimesh

from motiongen.body.model import BodyModel, BodyParams
from motiongen.body.procedural import build_procedural_model
from motiongen.body.rotations import axis_angle_to_matrix
from motiongen.capture import markers as mk
from motiongen.skeleton import BODY

HEAD = ("LFHD", "RFHD", "LCHEEK", "RCHEEK", "LBHD", "RBHD", "LBROW", "RBROW", "NOSE", "CHIN")
FEET = ("LHEE", "RHEE", "LTOE", "RTOE", "LMT1", "RMT1", "LMT5", "RMT5")
LEGS = tuple(s + n for s in "LR"
             for n in ("THI", "FTHI", "FTHIIN", "KNE", "KNI", "TIB", "ANK", "HEE", "MT5", "MT1", "TOE"))
ARMS = tuple(s + n for s in "LR" for n in ("SHO", "BCEP", "ELB", "ELBIN", "FRM", "OWR", "IWR", "FIN", "THMB",
                                          "THUMBT", "INDEXT", "MIDDLET", "RINGT", "PINKYT"))


def _idx(names):
    return np.array([mk.MARKER_NAMES.index(n) for n in names])


@pytest.fixture(scope="module")
def rest(bm):
    """(81, 3) rest-pose marker positions."""
    return bm.template_vertices[mk.marker_vertices(bm)]


def _pose(shape, seed, scale=0.5):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(shape + (3,), generator=g), torch.randn(shape + (63,), generator=g) * scale,
            torch.randn(shape + (3,), generator=g), torch.randn(10, generator=g))


def _rotmats(go, bp):
    return axis_angle_to_matrix(torch.cat([go[..., None, :], bp.reshape(bp.shape[:-1] + (21, 3))], -2))


def test_names_and_ids(bm):
    assert (mk.NUM_BODY_MARKERS, mk.NUM_MARKERS) == (67, 81)
    assert len(mk.BODY_MARKER_NAMES) == 67 and len(mk.EXTRA_MARKER_NAMES) == 14
    assert mk.MARKER_NAMES == mk.BODY_MARKER_NAMES + mk.EXTRA_MARKER_NAMES
    assert len(set(mk.MARKER_NAMES)) == 81
    ids = mk.marker_vertices(bm)
    assert ids.shape == (81,) and ids.dtype == np.int64
    assert len(set(ids.tolist())) == 81 and ids.min() >= 0 and ids.max() < bm.num_vertices
    ids[0] = -1                                                            # a copy: the cache is safe
    assert mk.marker_vertices(bm)[0] >= 0


def test_markers_lie_on_the_surface_off_the_bones(bm, rest):
    mesh = trimesh.Trimesh(bm.template_vertices, bm.faces, process=False)
    _, dist, _ = trimesh.proximity.closest_point(mesh, rest)
    assert dist.max() < 1e-6
    # distance of each marker to every bone segment of the full skeleton: none is an interior point
    J = bm.rest_joints(None, body_only=False).numpy().astype(np.float64)
    a, b = J[list(bm.full_parents[1:])], J[1:]                              # (54, 3) bone ends
    ab = b - a
    t = np.clip(np.einsum("mbc,bc->mb", rest[:, None] - a, ab) / (ab * ab).sum(1), 0, 1)
    d = np.linalg.norm(rest[:, None] - (a + t[..., None] * ab), axis=-1).min(1)   # (81,)
    assert d.min() > 0.005, mk.MARKER_NAMES[int(d.argmin())]


def test_markers_are_left_right_symmetric(bm, rest):
    M = mk.MIRROR
    assert M.shape == (81,) and np.array_equal(M[M], np.arange(81))
    for m, n in enumerate(mk.MARKER_NAMES):
        twin = mk.MARKER_NAMES[M[m]]
        assert twin == n or {n[0], twin[0]} == {"L", "R"} and n[1:] == twin[1:]
    mirrored = rest * np.array([-1.0, 1.0, 1.0])
    assert np.linalg.norm(mirrored - rest[M], axis=1).max() < 0.015
    mid = M == np.arange(81)
    assert set(np.array(mk.MARKER_NAMES)[mid]) == {"C7", "T8", "MBLLY", "STRN", "CLAV", "NOSE", "CHIN"}
    assert np.abs(rest[mid, 0]).max() < 0.01
    left = np.array([n[0] == "L" for n in mk.MARKER_NAMES]) & ~mid
    assert left.sum() == 37 and (rest[left, 0] > 0).all()
    # the joint each marker moves with mirrors too
    assert np.array_equal(mk.marker_joints(bm)[M], np.array(BODY.mirror)[mk.marker_joints(bm)])


def test_placement_is_anatomical(bm, rest):
    J = bm.rest_joints().numpy()
    shoulders = J[[16, 17], 1].max()
    assert (rest[_idx(HEAD), 1] > shoulders).all()
    assert (rest[_idx(FEET), 1] < bm.template_vertices[:, 1].min() + 0.15).all()
    y = dict(zip(mk.MARKER_NAMES, rest[:, 1]))
    assert y["LFHD"] > y["LBROW"] > y["NOSE"] > y["CHIN"] > y["C7"] > y["STRN"] > y["MBLLY"] > y["LKNE"] > y["LANK"]
    z = dict(zip(mk.MARKER_NAMES, rest[:, 2]))
    assert z["STRN"] > z["T8"] and z["LFHD"] > z["LBHD"] and z["LFWT"] > z["LBWT"] and z["LTOE"] > z["LHEE"]
    tips = rest[_idx(["LTHUMBT", "LINDEXT", "LMIDDLET", "LRINGT", "LPINKYT"])]
    assert (tips[:, 0] > J[20, 0] + 0.05).all()                             # past the left wrist
    # neighbours in the list are neighbours on the body (the priors convolve over this axis)
    gaps = np.linalg.norm(np.diff(rest[_idx(LEGS[:11])], axis=0), axis=1)
    assert gaps.max() < 0.3


def test_marker_joints_and_lower_body(bm):
    j = mk.marker_joints(bm)
    assert j.shape == (81,) and j.dtype == np.int64 and j.min() >= 0 and j.max() < 22
    assert (j[_idx(["LTHUMBT", "LPINKYT"])] == 20).all() and (j[_idx(["RTHUMBT", "RPINKYT"])] == 21).all()
    low = mk.markers_of_joints(bm, mk.LOWER_BODY_JOINTS)
    assert low.shape == (81,) and low.dtype == bool
    assert low[_idx(LEGS)].all()
    assert not low[_idx(HEAD + ARMS)].any()


def test_posed_markers_equal_mesh_vertices_and_have_gradients(bm):
    go, bp, tr, be = _pose((4,), seed=1)
    ids = mk.marker_vertices(bm)
    ref = bm.vertices(go, bp, tr, be)[:, ids]
    R = _rotmats(go, bp).requires_grad_()
    tr = tr.clone().requires_grad_()
    be = be.clone().requires_grad_()
    P = mk.posed_markers(bm, R, tr, be)
    assert P.shape == (4, 81, 3)
    np.testing.assert_allclose(P.detach().numpy(), ref.detach().numpy(), atol=1e-5)
    P.square().sum().backward()
    for g in (R.grad, tr.grad, be.grad):
        assert torch.isfinite(g).all() and g.abs().sum() > 0
    sub = [3, 50, 80]
    np.testing.assert_allclose(mk.posed_markers(bm, R, tr, be, ids=sub).detach().numpy(),
                               ref[:, sub].detach().numpy(), atol=1e-5)


def test_vertices_from_rotmats_equals_vertices(bm):
    go, bp, tr, be = _pose((2, 3), seed=2, scale=0.8)
    R = _rotmats(go, bp)
    np.testing.assert_allclose(bm.vertices_from_rotmats(R, tr, be).numpy(), bm.vertices(go, bp, tr, be).numpy(),
                               atol=1e-5)
    np.testing.assert_allclose(bm.vertices_from_rotmats(R[0, 0]).numpy(), bm.vertices(go[0, 0], bp[0, 0]).numpy(),
                               atol=1e-5)


def test_markers_follow_shape(bm):
    go, bp, tr, _ = _pose((2,), seed=3)
    be = torch.zeros(10)
    be[0], be[3] = 2.0, 1.5                                                # taller, wider
    R, ids = _rotmats(go, bp), mk.marker_vertices(bm)
    shaped, mean = mk.posed_markers(bm, R, tr, be), mk.posed_markers(bm, R, tr)
    np.testing.assert_allclose(shaped.numpy(), bm.vertices(go, bp, tr, be)[:, ids].numpy(), atol=1e-5)
    assert (shaped - mean).norm(dim=-1).mean() > 0.02


def test_params_markers_in_chunks(bm):
    go, bp, tr, be = _pose((70,), seed=4)
    params = BodyParams(go.numpy(), bp.numpy(), tr.numpy(), be.numpy())
    out = mk.params_markers(bm, params, chunk=32)
    assert out.shape == (70, 81, 3) and isinstance(out, np.ndarray)
    np.testing.assert_allclose(out, mk.posed_markers(bm, _rotmats(go, bp), tr, be).numpy(), atol=1e-5)
    np.testing.assert_allclose(mk.params_markers(bm, params, ids=[0, 5]), out[:, [0, 5]], atol=1e-6)


def test_ids_are_per_model_and_geometric(bm, tmp_path):
    """Another model file with the vertices stored in another order: the same markers, at the
    renumbered ids (placement reads each model's mesh, never cached ids of another)."""
    a = build_procedural_model()
    n = len(a["v_template"])
    perm = np.random.default_rng(0).permutation(n)                         # new vertex i = old perm[i]
    inv = np.argsort(perm)
    for k in ("v_template", "shapedirs", "weights", "posedirs"):
        a[k] = a[k][perm]
    a["J_regressor"] = a["J_regressor"][:, perm]
    a["f"] = inv[a["f"]].astype(np.int32)
    np.savez(tmp_path / "SMPLX_NEUTRAL.npz", **a)
    other = BodyModel(tmp_path / "SMPLX_NEUTRAL.npz")
    ids = mk.marker_vertices(other)
    np.testing.assert_allclose(other.template_vertices[ids], bm.template_vertices[mk.marker_vertices(bm)], atol=1e-9)
    assert np.array_equal(ids, inv[mk.marker_vertices(bm)])
