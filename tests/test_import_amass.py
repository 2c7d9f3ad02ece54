"""AMASS-style SMPL-X / SMPL-H sequences as training data: files generated from the procedural
body model with known parameters, so the imported joints have a known answer."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from motiongen.body.fit import fit_joints, save_amass_npz
from motiongen.body.random_motion import sample_motion
from motiongen.data.format import MotionDataset
from motiongen.importers.amass import main as amass_main
from tests.helpers import user_error
from motiongen.importers.amass import import_amass
from motiongen.errors import DataError
from motiongen.skeleton import FOOT_JOINTS, HEAD, PELVIS

ROOT = Path(__file__).resolve().parents[1]
Y_TO_Z = Rotation.from_euler("x", 90, degrees=True)        # (x, y, z) -> (x, -z, y): y-up world -> z-up


def known_motion(bm, frames, fps, seed):
    """Parameters from the procedural motion sampler (y-up) and their joints (T, 22, 3) by FK."""
    p = sample_motion(frames, fps, np.random.default_rng(seed), gait=True)
    X = bm.joints(*(torch.as_tensor(p[k]) for k in ("global_orient", "body_pose", "transl", "betas"))).numpy()
    return p, X.astype(np.float64)


def write_amass(path, bm, p, fps, layout="smplx", rate_key="mocap_framerate", **extra):
    """An AMASS file (z-up) of the y-up parameters p: the root turns about the rest pelvis J0(β),
    so trans_z = R (transl + J0) − J0. Jaw, eyes and hands get random values (must be ignored),
    betas 16 coefficients (the last 6 beyond what the procedural model has)."""
    J0 = bm.rest_joints(torch.as_tensor(p["betas"]))[0].double().numpy()
    T = len(p["transl"])
    rng = np.random.default_rng(1)
    poses = rng.normal(scale=0.3, size=(T, 165 if layout == "smplx" else 156))
    poses[:, :3] = (Y_TO_Z * Rotation.from_rotvec(p["global_orient"])).as_rotvec()
    poses[:, 3:66] = p["body_pose"]
    fields = dict(poses=poses, trans=Y_TO_Z.apply(p["transl"] + J0) - J0, betas=np.r_[p["betas"], rng.normal(size=6)],
                  gender=np.array("female"), **{rate_key: np.array(float(fps))})
    fields.update(extra)
    np.savez(path, **{k: v for k, v in fields.items() if v is not None})
    return Path(path)


def assert_known_answer(m, X_at_30):
    """Imported joints = FK of the known parameters at the 30 fps frames, moved only up or down
    (y-up kept, floor at y = 0 under the feet)."""
    shift = m.joints - X_at_30                                         # (T, 22, 3)
    assert np.abs(shift - shift.mean((0, 1))).max() < 1e-4              # one rigid shift for all
    assert np.abs(shift.mean((0, 1))[[0, 2]]).max() < 1e-5              # ... and only vertical
    feet = m.joints[:, list(FOOT_JOINTS), 1].min(1)
    assert np.percentile(feet, 2) == pytest.approx(0.0, abs=1e-5) and feet.min() > -0.02
    assert (m.joints[:, HEAD, 1] > m.joints[:, PELVIS, 1] + 0.3).all()   # upright: y is up


@pytest.mark.parametrize("layout,rate_key,fps", [("smplx", "mocap_framerate", 120), ("smplh", "mocap_frame_rate", 60),
                                                 ("smplx", "mocap_frame_rate", 60), ("smplh", "mocap_framerate", 120)])
def test_amass_layouts_and_rates_give_the_known_joints(bm, tmp_path, layout, rate_key, fps):
    p, X = known_motion(bm, 2 * fps, fps, seed=fps + len(layout))
    m = import_amass(write_amass(tmp_path / "s.npz", bm, p, fps, layout, rate_key), bm)
    step = fps // 30
    assert (m.layout, m.source_fps, m.fps, m.gender, m.up, m.up_from) == (layout, fps, 30.0, "female", "z",
                                                                          "default (AMASS)")
    assert len(m.joints) == 60 and m.betas_used == 10
    assert_known_answer(m, X[::step])
    # the stored parameters reproduce the stored joints through the body model
    J = bm.joints(*(torch.as_tensor(m.params[k]) for k in ("global_orient", "body_pose", "transl", "betas")))
    assert np.abs(J.numpy() - m.joints).max() < 1e-5
    np.testing.assert_allclose(m.params["body_pose"], p["body_pose"][::step], atol=1e-5)


def test_non_integer_rate_interpolates_between_known_frames(bm, tmp_path):
    p, X = known_motion(bm, 100, 100.0, seed=5)                          # 1 s at 100 fps
    m = import_amass(write_amass(tmp_path / "s.npz", bm, p, 100.0), bm)
    assert len(m.joints) == 30                                           # t = 0 .. 29/30 s
    # every 3rd output frame falls on every 10th input frame: known answer there
    shift = m.joints[::3] - X[::10]
    assert np.abs(shift - shift.mean((0, 1))).max() < 1e-4
    # in between, interpolation stays within the path of the motion (no overshoot, no flips)
    step = np.linalg.norm(np.diff(m.joints, axis=0), axis=-1).max()
    assert step < 1.5 * np.linalg.norm(np.diff(X[::3], axis=0), axis=-1).max()


def test_our_own_export_round_trips(bm, tmp_path):
    p, X = known_motion(bm, 24, 30.0, seed=8)
    fit = fit_joints(X, bm, None, refine_steps=5)
    path = save_amass_npz(tmp_path / "fit.npz", fit, fps=30.0)
    m = import_amass(path, bm)
    assert (m.up, m.up_from) == ("y", "file")
    shift = m.joints - fit.joints
    assert np.abs(shift - [0, shift[..., 1].mean(), 0]).max() < 1e-5
    np.testing.assert_allclose(m.params["global_orient"], fit.global_orient, atol=1e-6)
    np.testing.assert_allclose(m.params["transl"] - fit.transl, np.broadcast_to([0, shift[..., 1].mean(), 0], (24, 3)),
                               atol=1e-5)
    # read as AMASS (z-up) it is a body lying on its back: refused, not written
    with pytest.raises(DataError, match=r"fit.npz: not a plausible standing human after import \(up z from given\): "
                                        r"head above pelvis above feet in 0% of frames.*check up="):
        import_amass(path, bm, up="z")


def test_y_up_file_without_up_key_is_refused(bm, tmp_path):
    p, _ = known_motion(bm, 30, 30.0, seed=2)
    path = tmp_path / "old_export.npz"
    poses = np.zeros((30, 165))
    poses[:, :3], poses[:, 3:66] = p["global_orient"], p["body_pose"]
    np.savez(path, poses=poses, trans=p["transl"], betas=p["betas"], mocap_framerate=np.array(30.0))
    with pytest.raises(DataError, match=r"old_export.npz: not a plausible .*\(up z from default \(AMASS\)\)"):
        import_amass(path, bm)
    assert import_amass(path, bm, up="y").up_from == "given"


def _bad(kind, path, bm, p):
    T = len(p["transl"])
    if kind == "missing trans":
        return write_amass(path, bm, p, 60, trans=None)
    if kind == "missing rate":
        return write_amass(path, bm, p, 60, mocap_framerate=None)
    if kind == "poses width":
        return write_amass(path, bm, p, 60, poses=np.zeros((T, 100)))
    if kind == "nan":
        f = write_amass(path, bm, p, 60)
        with np.load(f) as z:
            d = dict(z)
        d["poses"][7, 40] = np.nan
        np.savez(f, **d)
        return f
    if kind == "trans length":
        return write_amass(path, bm, p, 60, trans=np.zeros((T - 1, 3)))
    if kind == "rate":
        return write_amass(path, bm, p, 60, mocap_framerate=np.array(0.0))
    if kind == "up":
        return write_amass(path, bm, p, 60, up=np.array("north"))
    if kind == "pickled gender":
        return write_amass(path, bm, p, 60, gender=np.array({"g": "female"}, dtype=object))
    if kind == "not npz":
        path.write_text("poses")
        return path
    raise KeyError(kind)


BAD = [("missing trans", r"\[trans\]: required AMASS array is missing \(found: betas, gender, mocap_framerate, poses\)"),
       ("missing rate", r"\[mocap_framerate\]: frame rate is missing \(expected mocap_framerate or mocap_frame_rate\)"),
       ("poses width", r"\[poses\]: expected \(T, 165\) SMPL-X or \(T, 156\) SMPL-H axis-angle with T >= 1, found "
                       r"float64 \(60, 100\)"),
       ("nan", r"\[poses\]: non-finite value \(NaN or inf\) at frame 7"),
       ("trans length", r"\[trans\]: expected \(60, 3\) like poses, found float64 \(59, 3\)"),
       ("rate", r"\[mocap_framerate\]: expected a positive frame rate"),
       ("up", r"\[up\]: expected 'y' or 'z', found 'north'"),
       ("pickled gender", r"\[gender\]: stored as a pickled object array, which is not read"),
       ("not npz", r"s.npz: not a readable .npz file")]


@pytest.mark.parametrize("kind,message", BAD)
def test_bad_files_name_file_and_field(bm, tmp_path, kind, message):
    p, _ = known_motion(bm, 60, 60.0, seed=1)
    with pytest.raises(DataError, match=message):
        import_amass(_bad(kind, tmp_path / "s.npz", bm, p), bm)


def run_cli(*args):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "motiongen.importers.amass", *args],
                          capture_output=True, text=True, env=env, timeout=180)


def test_cli_writes_a_dataset_whose_parameters_reproduce_its_joints(bm, tmp_path):
    p1, X1 = known_motion(bm, 120, 60.0, seed=11)
    p2, X2 = known_motion(bm, 240, 120.0, seed=12)
    still = {"global_orient": np.zeros((30, 3)), "body_pose": np.zeros((30, 63)), "transl": np.tile([0.5, 1.3, 0.2], (30, 1)),
             "betas": p1["betas"]}                                          # standing still in the rest pose
    a = write_amass(tmp_path / "a.npz", bm, p1, 60.0, "smplx")
    b = write_amass(tmp_path / "b.npz", bm, p2, 120.0, "smplh", "mocap_frame_rate")
    c = write_amass(tmp_path / "c.npz", bm, still, 30.0)
    r = run_cli(f"inputs=[{a},{b},{c}]", f"out={tmp_path / 'ds'}", "split=test", "action=walk")
    assert r.returncode == 0, r.stderr
    ds = MotionDataset.open(tmp_path / "ds")
    seqs = ds.split_sequences("test")
    assert ds.fps == 30.0 and ds.meta["source"] == "amass" and [s.name for s in seqs] == ["a", "b", "c"]
    info = ds.meta["amass_import"]["sequences"]
    assert [(i["layout"], i["source_fps"], i["gender"], i["up"]) for i in info] == [
        ("smplx", 60.0, "female", "z"), ("smplh", 120.0, "female", "z"), ("smplx", 30.0, "female", "z")]
    J = bm.joints(*(torch.as_tensor(np.array(ds.smplx[k])) for k in ("global_orient", "body_pose", "transl", "betas")))
    assert np.abs(J.numpy() - np.asarray(ds.joints)).max() < 1e-5
    for s, X in zip(seqs, (X1[::2], X2[::4])):
        shift = np.asarray(ds.joints[s.start:s.end]) - X
        assert np.abs(shift - shift.mean((0, 1))).max() < 1e-4
    # contact from the floor: the still body stands on both feet in every frame; nothing else touches
    contact = np.asarray(ds.contact)
    assert contact[seqs[2].start:, list(FOOT_JOINTS)].all() and not np.delete(contact, list(FOOT_JOINTS), 1).any()


def test_cli_bad_input_exits_2_and_writes_nothing(bm, tmp_path, capsys):
    p, _ = known_motion(bm, 60, 60.0, seed=1)
    good = write_amass(tmp_path / "good.npz", bm, p, 60.0)
    bad = _bad("nan", tmp_path / "bad.npz", bm, p)
    for args, message in [((f"inputs=[{good},{bad}]",), f"error: {bad} [poses]: non-finite value"),
                          ((f"inputs=[{good}]", "up=x"), "error: up='x': expected z (AMASS) or y"),
                          ((f"inputs=[{good}]", f"body_model={tmp_path / 'none.npz'}"), f"error: {tmp_path / 'none.npz'}")]:
        line = user_error(capsys, amass_main, [*args, f"out={tmp_path / 'ds'}"])
        assert line.startswith(message), line
        assert not (tmp_path / "ds").exists() and not list(tmp_path.glob("ds.partial*"))


@pytest.mark.parametrize("fps, message", [("1e7", "fps: expected a number > 0 and <= 1000"), ("-30", "fps: expected")])
def test_cli_bounds_the_output_rate(bm, tmp_path, capsys, fps, message):
    """fps=1e7 ran for minutes; now one line before any file is read, nothing written."""
    p, _ = known_motion(bm, 60, 60.0, seed=3)
    src = write_amass(tmp_path / "s.npz", bm, p, 60.0)
    assert message in user_error(capsys, amass_main, [f"inputs=[{src}]", f"out={tmp_path / 'ds'}", f"fps={fps}"])
    assert not (tmp_path / "ds").exists()
