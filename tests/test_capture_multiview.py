"""Multi-view SMPL-X fitting (the multi-view capture paper, A1): cameras, keypoint layouts,
triangulation, the pose prior, the objective, and the three-stage fit on a rig with a known
answer (capture_rig.py)."""

import json

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from capture_rig import look_at_cameras, make_rig  # tests/ is on sys.path under pytest

from motiongen.capture.cameras import load_cameras, save_cameras
from motiongen.capture.fit_multiview import main as fit_main
from motiongen.capture.keypoints import layout_to_joints, load_keypoints2d, load_keypoints3d, to_body_joints
from motiongen.capture.multiview import MultiviewConfig, fit_multiview, root_init
from motiongen.capture.objective import SEED_STAGES, Targets, geman_mcclure, terms
from motiongen.capture.pose_prior import default_prior, fit_prior, load_prior
from motiongen.capture.triangulate import temporal_outliers, triangulate
from motiongen.errors import ConfigError, DataError
from motiongen.skeleton import BODY_JOINT_NAMES
from tests.helpers import user_error


@pytest.fixture(scope="module")
def cams():
    return look_at_cameras(np.array([0.0, 1.0, 0.0]), 4, rng=np.random.default_rng(3))


def mpjpe(a, b) -> float:
    return float(np.linalg.norm(a - b, axis=-1).mean())


# ---- cameras ---------------------------------------------------------------------------------

def test_projection_is_the_opencv_pinhole_with_distortion(cams):
    c = cams.subset([0])
    X = np.array([[0.1, 1.3, 0.2], [-0.4, 0.5, 0.3]])
    xc = X @ c.R[0].T + c.t[0]
    x, y = xc[:, 0] / xc[:, 2], xc[:, 1] / xc[:, 2]
    k1, k2, p1, p2, k3 = c.dist[0]
    r2 = x * x + y * y
    rad = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    xd, yd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    K = c.K[0]
    uv, depth = c.project_np(X)
    assert np.allclose(uv[:, 0], np.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], -1), atol=1e-9)
    assert np.allclose(depth[:, 0], xc[:, 2])
    # the camera centre's optical axis lands on the principal point
    ahead = c.centers[0] + 2.0 * c.R[0][2]
    assert np.allclose(c.project_np(ahead[None])[0][0, 0], K[:2, 2], atol=1e-9)
    # undistort inverts the distortion
    assert np.allclose(c.undistort(uv.transpose(1, 0, 2))[0], np.stack([x, y], -1), atol=1e-9)


def test_camera_files_round_trip_and_world_conventions(tmp_path, cams):
    back = load_cameras(save_cameras(tmp_path / "c.json", cams))
    for k in ("K", "R", "t", "dist", "image_size"):
        assert np.allclose(getattr(back, k), getattr(cams, k))
    X = np.random.default_rng(0).normal(size=(5, 3)) * 0.3 + [0, 1, 0]
    # the same rig calibrated in a z-up world measured in millimetres
    y_to_z = Rotation.from_euler("x", 90, degrees=True).as_matrix()          # y-up point -> z-up point
    doc = json.loads((tmp_path / "c.json").read_text())
    doc["up"], doc["units"] = "+z", "mm"
    for e in doc["cameras"]:
        e["R"] = (np.array(e["R"]) @ y_to_z.T).tolist()
        e["t"] = (np.array(e["t"]) * 1000).tolist()
    (tmp_path / "z.json").write_text(json.dumps(doc))
    zc = load_cameras(tmp_path / "z.json")
    assert np.allclose(zc.project_np(X)[0], cams.project_np(X)[0], atol=1e-6)
    assert np.allclose(zc.file_points_to_world(X @ y_to_z.T * 1000), X)
    # npz layout with Rodrigues vectors
    np.savez(tmp_path / "c.npz", K=cams.K, rvec=Rotation.from_matrix(cams.R).as_rotvec(), t=cams.t,
             dist=cams.dist[:, :4], names=np.array(cams.names))
    n = load_cameras(tmp_path / "c.npz")
    assert n.names == cams.names and np.allclose(n.project_np(X)[0], cams.project_np(X)[0], atol=1e-6)


def test_camera_file_errors_name_the_field(tmp_path, cams):
    save_cameras(tmp_path / "c.json", cams)
    doc = json.loads((tmp_path / "c.json").read_text())

    def bad(edit, field):
        d = json.loads(json.dumps(doc))
        edit(d)
        (tmp_path / "b.json").write_text(json.dumps(d))
        with pytest.raises(DataError, match=field):
            load_cameras(tmp_path / "b.json")

    bad(lambda d: d["cameras"][1].pop("K"), r"cameras\[1\] \(cam1\)\.K")
    bad(lambda d: d["cameras"][0].__setitem__("R", [[1, 0, 0], [0, 1, 0], [0, 0, 2]]), "not a rotation")
    bad(lambda d: d["cameras"][2].__setitem__("dist", [0.1, 0.2, 0.3]), "dist")
    bad(lambda d: d.__setitem__("up", "+w"), "up")
    with pytest.raises(DataError, match="does not exist"):
        load_cameras(tmp_path / "missing.json")


# ---- keypoints ---------------------------------------------------------------------------------

def test_layouts_map_onto_our_joints():
    coco = layout_to_joints("coco17")
    assert coco[:5].tolist() == [-1] * 5                                      # face: no SMPL-X body joint
    assert BODY_JOINT_NAMES[coco[11]] == "left_hip" and BODY_JOINT_NAMES[coco[16]] == "right_ankle"
    b25 = layout_to_joints("body25")
    assert BODY_JOINT_NAMES[b25[8]] == "pelvis" and BODY_JOINT_NAMES[b25[19]] == "left_foot"
    assert BODY_JOINT_NAMES[b25[2]] == "right_shoulder" and (b25 >= 0).sum() == 16
    assert layout_to_joints("smplx22").tolist() == list(range(22))
    v = np.arange(17 * 2, dtype=float).reshape(1, 17, 2)
    out, c = to_body_joints(v, np.ones((1, 17)), "coco17", axis=1)
    assert np.allclose(out[0, BODY_JOINT_NAMES.index("left_knee")], v[0, 13]) and c.sum() == 12


def test_keypoint_files(tmp_path):
    rng = np.random.default_rng(0)
    kp = np.concatenate([rng.uniform(0, 500, (3, 5, 17, 2)), rng.uniform(0, 1, (3, 5, 17, 1))], -1)
    kp[1, 2, 13, 0] = np.nan                                                  # a missed detection
    np.savez(tmp_path / "k.npz", keypoints=kp, layout="coco17", camera_names=np.array(["b", "c", "a"]), fps=25.0)
    obs = load_keypoints2d(tmp_path / "k.npz", ["a", "b", "c"])
    knee = BODY_JOINT_NAMES.index("left_knee")
    assert obs.fps == 25 and obs.uv.shape == (3, 5, 22, 2) and obs.observed.sum() == 12
    assert np.allclose(obs.uv[0, :, knee], kp[2, :, 13, :2])                   # camera "a" was third in the file
    assert obs.conf[2, 2, knee] == 0 and obs.conf[:, :, BODY_JOINT_NAMES.index("spine1")].max() == 0
    np.savez(tmp_path / "nolayout.npz", keypoints=kp)
    with pytest.raises(DataError, match="layout"):
        load_keypoints2d(tmp_path / "nolayout.npz", ["a", "b", "c"])
    kp2 = kp.copy()
    kp2[0, 0, 0, 2] = 3.0
    np.savez(tmp_path / "conf.npz", keypoints=kp2, layout="coco17")
    with pytest.raises(DataError, match=r"\[0, 1\]"):
        load_keypoints2d(tmp_path / "conf.npz", ["a", "b", "c"])
    np.savez(tmp_path / "three.npz", keypoints=kp, layout="coco17")
    with pytest.raises(DataError, match="3 cameras of keypoints but 2"):
        load_keypoints2d(tmp_path / "three.npz", ["a", "b"])
    x3 = np.concatenate([rng.normal(size=(5, 22, 3)), np.ones((5, 22, 1))], -1)
    np.savez(tmp_path / "k3.npz", keypoints3d=x3)
    X, c = load_keypoints3d(tmp_path / "k3.npz", 5, lambda p: p * 2)
    assert np.allclose(X, x3[..., :3] * 2) and c.min() == 1
    with pytest.raises(DataError, match="5 frames, the 2D keypoints have 6"):
        load_keypoints3d(tmp_path / "k3.npz", 6, lambda p: p)


# ---- triangulation -----------------------------------------------------------------------------

def test_triangulation_exact_weighted_and_robust(cams):
    rng = np.random.default_rng(1)
    X = rng.normal(size=(30, 22, 3)) * 0.3 + [0, 1, 0]                          # (T, J, 3)
    uv = cams.project_np(X)[0].transpose(2, 0, 1, 3)                           # (C, T, J, 2)
    conf = np.ones(uv.shape[:3])
    assert np.abs(triangulate(cams, uv, conf).points - X).max() < 1e-6        # noise-free: exact
    # a bad view: at full confidence it moves the plain DLT; at low confidence it barely does
    bad = uv.copy()
    bad[0] += 40.0
    plain = triangulate(cams, bad, conf, reject_px=None, max_jump=None).points
    low = conf.copy()
    low[0] = 0.05
    weighted = triangulate(cams, bad, low, reject_px=None, max_jump=None).points
    assert mpjpe(weighted, X) < 0.3 * mpjpe(plain, X)
    # consensus finds the bad view and drops it
    robust = triangulate(cams, bad, conf, reject_px=20.0, max_jump=None)
    assert mpjpe(robust.points, X) < 1e-6 and not robust.views[0].any() and robust.views[1:].all()
    # two views that disagree: no point (except where the shift runs along an epipolar line,
    # which two views cannot see)
    two = np.zeros_like(conf)
    two[:2] = 1
    t2 = triangulate(cams, bad, two, reject_px=20.0, max_jump=None)
    assert (t2.conf == 0).mean() > 0.9 and (triangulate(cams, uv, two, max_jump=None).conf == 1).all()


def test_temporal_outliers_flag_jumps_only():
    t = np.arange(40) / 30
    P = np.stack([np.sin(3 * t), 1 + 0.2 * np.cos(5 * t), 2 * t], -1)[:, None]   # fast, smooth (40, 1, 3)
    conf = np.ones((40, 1))
    P[17, 0] += [0.0, 0.3, 0.0]
    P[25:27, 0] += [0.5, 0.0, 0.0]                                               # two outliers in a row
    conf[[24, 27, 28]] = 0                                                       # ... with gaps around them
    conf[33:36] = 0                                                              # a gap in smooth motion
    flags = set(np.flatnonzero(temporal_outliers(P, conf, 0.1)[:, 0]).tolist())
    # the outliers go; next to a run of them a good point may go too (harmless: the fit fills in)
    assert {17, 25, 26} <= flags <= {17, 23, 25, 26, 29}


# ---- pose prior --------------------------------------------------------------------------------

def test_pose_prior_fit_round_trip_and_files(tmp_path):
    rng = np.random.default_rng(0)
    std = np.linspace(0.6, 0.01, 63)
    Q = np.linalg.qr(rng.normal(size=(63, 63)))[0]
    poses = 0.1 + (rng.normal(size=(20000, 63)) * std) @ Q.T
    p = fit_prior(poses, min_std=0.05)
    assert np.allclose(p.std[:40], std[:40], rtol=0.05) and p.std.min() == 0.05
    assert np.allclose(p.mean, 0.1, atol=0.02)
    assert np.allclose(p.decode(p.encode(poses[:5])), poses[:5], atol=1e-9)
    z = p.decoder(torch.float64)(torch.as_tensor(p.encode(poses[:3])))
    assert np.allclose(z.numpy(), poses[:3], atol=1e-9)
    back = load_prior(p.save(tmp_path / "prior.npz"))
    assert np.allclose(back.components, p.components) and back.num_poses == 20000
    assert fit_prior(poses, dims=8).dims == 8
    d = default_prior()
    assert d.dims == 63 and "builtin" in d.source and load_prior("builtin") is d
    with pytest.raises(DataError, match="format"):
        np.savez(tmp_path / "x.npz", mean=np.zeros(63))
        load_prior(tmp_path / "x.npz")


def test_pose_prior_cli(tmp_path, bm, capsys):
    from motiongen.body.fit import FitResult, save_amass_npz
    from motiongen.capture.pose_prior import main

    rng = np.random.default_rng(0)
    pose = rng.normal(0, 0.2, (50, 63))
    fit = FitResult(np.zeros((50, 3)), pose, np.zeros((50, 3)), np.zeros(10), np.zeros((50, 22, 3)), np.zeros(50),
                    None, 0.0, 0.0, 0, 0.0, "x")
    save_amass_npz(tmp_path / "a.npz", fit, 30)
    main([f"out={tmp_path / 'p.npz'}", f"amass=[{tmp_path / 'a.npz'}]", "dims=10"])
    p = load_prior(tmp_path / "p.npz")
    assert p.dims == 10 and np.allclose(p.mean, pose.mean(0), atol=1e-6)
    a = tmp_path / "a.npz"
    amass_bytes = a.read_bytes()
    (tmp_path / "file").write_text("")
    for argv, words in [([f"out={tmp_path / 'q.npz'}"], "exactly one of"),
                        ([f"out={tmp_path / 'q.npz'}", "builtin=true", "dims=0"], "dims=0: expected 1..63"),
                        ([f"out={tmp_path / 'q.npz'}", "builtin=true", "min_std=-1"], "min_std=-1.0: expected a positive"),
                        ([f"out={tmp_path / 'q.npz'}", f"data.root={tmp_path / 'none'}"], "dataset directory does not exist"),
                        ([f"out={tmp_path / 'q.npz'}", f"amass=[{tmp_path / 'none.npz'}]"], "AMASS file is missing"),
                        (["out=/proc/q.npz", "builtin=true"], "out: cannot write under /proc"),
                        ([f"out={tmp_path}", "builtin=true"], "exists and is not a file"),
                        ([f"out={tmp_path / 'file' / 'q.npz'}", "builtin=true"], "is a file, not a directory"),
                        ([f"out={a}", f"amass=[{a}]"], "the output is the input")]:   # never over an input
        assert words in user_error(capsys, main, argv), argv
    assert not (tmp_path / "q.npz").exists() and a.read_bytes() == amass_bytes


# ---- objective ---------------------------------------------------------------------------------

def test_objective_terms_closed_forms(cams):
    assert float(geman_mcclure(torch.tensor(4.0), 2.0)) == 0.5
    T = 5
    t = torch.arange(T, dtype=torch.float64)
    J = torch.zeros(T, 22, 3, dtype=torch.float64) + torch.linspace(0, 1, 22, dtype=torch.float64)[:, None]
    J = J + 0.1 * t[:, None, None]                                             # constant velocity
    J = J + torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    theta = 0.01 * t[:, None, None].expand(T, 21, 3)                           # linear in time
    R = torch.eye(3, dtype=torch.float64).expand(T, 3, 3)
    x3d = J.clone()
    x3d[:, 3, 0] += 0.02                                                        # 2 cm off at one joint
    c = cams.tensors(torch.float64)
    uv, depth = cams.project(J, c)                                              # (T, 22, C, 2)
    uv_obs = uv.clone()
    uv_obs[0, 5, 1] += 1e4                                                      # a gross outlier
    tg = Targets(x3d, torch.ones(T, 22, dtype=torch.float64), uv_obs, torch.ones(T, 22, 4, dtype=torch.float64),
                 torch.arange(22), torch.sqrt(c["K"][:, 0, 0] * c["K"][:, 1, 1]))
    z, b = torch.ones(T, 63, dtype=torch.float64), torch.full((10,), 2.0, dtype=torch.float64)
    out = terms(J, theta, R, z, b, tg, lambda X: cams.project(X, c), length_unit=0.01, rho=0.01)
    assert abs(float(out["L3D"]) - 2.0 / 22) < 1e-3                             # 2 cm / (T K) x T
    assert abs(float(out["L2D"]) - 1.0 / (T * 22 * 4)) < 1e-6                   # the outlier: φ -> 1
    assert float(out["Lz"]) == 63 and float(out["Lbeta"]) == 40
    assert float(out["Lsmooth"]) < 1e-12                                        # linear motion
    # ρ is a length at the subject: 1 cm across camera 0's image plane gives φ(1 cm; 1 cm) = 1/2
    c0 = cams.subset([0])
    t0 = c0.tensors(torch.float64)
    uv2, _ = c0.project(J + 0.01 * torch.as_tensor(c0.R[0][0]), t0)
    tg2 = Targets(J, torch.zeros(T, 22, dtype=torch.float64), uv2, torch.ones(T, 22, 1, dtype=torch.float64),
                  torch.arange(22), torch.sqrt(t0["K"][:, 0, 0] * t0["K"][:, 1, 1]))
    l2d = float(terms(J, theta, R, z, b, tg2, lambda X: c0.project(X, t0), length_unit=0.01, rho=0.01)["L2D"])
    assert abs(l2d - 0.5) < 0.02                                                # (distortion: ~1 %)
    assert SEED_STAGES[3].w2d == 0.5 and SEED_STAGES[1].w3d == 5.0 and SEED_STAGES[2].smooth == 2.5


def test_root_init_aligns_a_rigid_template(bm):
    rest = bm.rest_joints().double().numpy()
    R = Rotation.from_euler("yx", [[0.3 * i, 0.1] for i in range(6)]).as_matrix()
    transl = np.array([[0.5, 0.9, -1.0]]) + 0.1 * np.arange(6)[:, None]
    X = np.einsum("tij,kj->tki", R, rest - rest[0]) + (rest[0] + transl)[:, None]
    w = np.ones((6, 22))
    w[2] = 0                                                                     # a frame without targets
    Ri, ti = root_init(bm, X, w)
    assert np.abs(Ri - R).max() < 0.02 and np.abs(ti - transl).max() < 0.01    # frame 2 interpolated
    keep = [0, 1, 3, 4, 5]
    assert np.abs(Ri[keep] - R[keep]).max() < 1e-5 and np.abs(ti[keep] - transl[keep]).max() < 1e-5


# ---- the fit -----------------------------------------------------------------------------------

@pytest.mark.slow
def test_fit_recovers_the_rig_within_2cm_across_chunks(bm):
    rig = make_rig(bm, T=40, cameras=4, noise_px=1.5, drop=0.1, outliers=0.0, seed=2)
    cfg = MultiviewConfig(steps=(60, 40, 60), chunk=20, stage1_frames=25)
    res = fit_multiview(bm, rig.cams, rig.uv, rig.conf, default_prior(), cfg)
    err = np.linalg.norm(res.joints - rig.joints, axis=-1)                      # (T, 22)
    assert err.mean() < 0.02 and err.mean(1).max() < 0.03
    assert np.nanmedian(res.err2d) < 4.0                                          # pixels (noise 1.5 px)
    # continuity at the chunk border (frames 19 | 20): its acceleration is like the others'
    # (the true motion's is even there). Measured 2.1x the median; without the previous chunk's
    # frames in the smoothness term 4.4x.
    acc = np.linalg.norm(res.joints[2:] - 2 * res.joints[1:-1] + res.joints[:-2], axis=-1).mean(1)   # (T-2,)
    assert acc[18:20].max() < 3 * np.median(acc)
    assert set(res.stage_losses) == {1, 2, 3} and res.stage_losses[1]["L2D"] == 0 < res.stage_losses[3]["L2D"]


@pytest.mark.slow
def test_geman_mcclure_beats_plain_l2_with_10_percent_outliers(bm):
    rig = make_rig(bm, T=40, cameras=4, noise_px=1.5, drop=0.05, outliers=0.1, seed=1)
    assert 0.08 < rig.outlier.mean() < 0.12
    errs = {}
    for robust in ("gm", "l2"):
        res = fit_multiview(bm, rig.cams, rig.uv, rig.conf, default_prior(), MultiviewConfig(robust=robust))
        errs[robust] = mpjpe(res.joints, rig.joints)
    # GM beats L2 by about 3x on such rigs (docs/results.md, "Multi-view fitting")
    assert errs["gm"] < 0.02
    assert errs["gm"] < 0.5 * errs["l2"], errs


def test_fit_rejects_wrong_shapes(bm, cams):
    with pytest.raises(ConfigError, match="detections"):
        fit_multiview(bm, cams, np.zeros((3, 5, 22, 2)), np.zeros((3, 5, 22)), default_prior())
    with pytest.raises(ConfigError, match="robust"):
        fit_multiview(bm, cams, np.zeros((4, 5, 22, 2)), np.zeros((4, 5, 22)), default_prior(),
                      MultiviewConfig(robust="huber"))


# ---- the CLI -----------------------------------------------------------------------------------

def write_rig(tmp_path, rig, layout="smplx22"):
    """The rig's cameras (JSON) and detections (npz, in `layout` order; keypoints the layout has
    but our joints lack are NaN)."""
    cams = save_cameras(tmp_path / "cams.json", rig.cams)
    kp = np.concatenate([rig.uv, rig.conf[..., None]], -1)                      # (C, T, 22, 3)
    idx = layout_to_joints(layout)
    out = np.full(kp.shape[:2] + (len(idx), 3), np.nan)
    out[:, :, idx >= 0] = kp[:, :, idx[idx >= 0]]
    np.savez(tmp_path / "kp.npz", keypoints=out, layout=layout, fps=30.0, camera_names=np.array(rig.cams.names))
    return cams, tmp_path / "kp.npz"


@pytest.mark.slow
def test_cli_end_to_end_coco_layout(tmp_path, bm):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from motiongen.capture.fit_multiview import main
    from motiongen.importers.amass import load_amass

    rig = make_rig(bm, T=30, cameras=5, noise_px=1.0, drop=0.05, seed=3)
    cams, kp = write_rig(tmp_path, rig, "coco17")
    out = tmp_path / "fit"
    main([f"cameras={cams}", f"keypoints2d={kp}", f"out={out}", "steps1=40", "steps2=30", "steps3=30"])
    report = json.loads((out / "report.json").read_text())
    assert report["layout"] == "coco17" and report["keypoints3d"] == "triangulated" and report["frames"] == 30
    assert set(report["stage_losses"]) == {"stage1", "stage2", "stage3"} and report["frames_per_second"] > 0
    amass = load_amass(out / "params.npz")                                       # AMASS layout, y-up
    assert amass.body_pose.shape == (30, 63) and amass.up == "y" and amass.fps == 30
    p = np.load(out / "params.npz")
    coco_joints = layout_to_joints("coco17")[layout_to_joints("coco17") >= 0]
    err = np.linalg.norm(p["joints"] - rig.joints, axis=-1)                      # (T, 22)
    assert err[:, coco_joints].mean() < 0.02                                      # the 12 observed joints
    assert err.mean() < 0.05                                                      # spine, head, feet: prior only
    e = np.load(out / "errors.npz")
    assert e["err3d"].shape == (30, 22) and e["err2d"].shape == (5, 30, 22)
    assert list(e["camera_names"]) == rig.cams.names
    assert np.isnan(e["err3d"][:, BODY_JOINT_NAMES.index("spine2")]).all()        # no target there
    assert np.nanmedian(e["err2d"]) < 3.0
    acc = EventAccumulator(str(out / "tb"))
    acc.Reload()
    tags = acc.Tags()["scalars"]
    assert {"stage1/L3D", "stage2/Lsmooth", "stage3/L2D", "stage3/total"} <= set(tags)
    assert acc.Scalars("stage3/L2D")[-1].value > 0 and acc.Scalars("stage1/L2D")[-1].value == 0


def test_cli_with_given_3d_keypoints_and_user_errors(tmp_path, bm, capsys):
    from motiongen.capture.fit_multiview import main

    rig = make_rig(bm, T=12, cameras=3, noise_px=1.0, drop=0.0, seed=4)
    cams, kp = write_rig(tmp_path, rig)
    rng = np.random.default_rng(0)
    x3 = np.concatenate([rig.joints + rng.normal(0, 0.003, rig.joints.shape), np.ones((12, 22, 1))], -1)
    np.savez(tmp_path / "k3.npz", keypoints3d=x3)
    out = tmp_path / "fit"
    base = [f"cameras={cams}", f"keypoints2d={kp}", f"out={out}"]
    main(base + [f"keypoints3d={tmp_path / 'k3.npz'}", "steps1=30", "steps2=20", "steps3=20", "tensorboard=false"])
    report = json.loads((out / "report.json").read_text())
    assert report["keypoints3d"] == "given" and not (out / "tb").exists()
    assert np.linalg.norm(np.load(out / "params.npz")["joints"] - rig.joints, axis=-1).mean() < 0.02
    # user mistakes: one line, exit 2, nothing (new) written
    bad_out = tmp_path / "bad"
    assert "does not exist" in user_error(capsys, fit_main, [f"cameras={tmp_path / 'no.json'}", f"keypoints2d={kp}", f"out={bad_out}"])
    np.savez(tmp_path / "two.npz", keypoints=np.zeros((2, 12, 22, 3)))
    assert "2 cameras of keypoints but 3" in user_error(capsys, fit_main, [f"cameras={cams}", f"keypoints2d={tmp_path / 'two.npz'}",
                                                            f"out={bad_out}"])
    assert "robust" in user_error(capsys, fit_main, base[:2] + [f"out={bad_out}", "robust=huber"])
    assert "unknown key" in user_error(capsys, fit_main, base + ["lambda3d=2"])
    assert "missing out=" in user_error(capsys, fit_main, base[:2])
    np.savez(tmp_path / "k3bad.npz", keypoints3d=x3[:5])
    assert "5 frames" in user_error(capsys, fit_main, base[:2] + [f"out={bad_out}", f"keypoints3d={tmp_path / 'k3bad.npz'}"])
    assert not bad_out.exists() or not any(bad_out.iterdir())
