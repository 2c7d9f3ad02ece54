"""BVH import/export on real CMU mocap (Debian's assimp-testmodels) and malformed files.

CI installs `assimp-testmodels`; without it the real-mocap tests skip (the synthetic and
malformed-file tests still run).
"""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from motiongen.body.model import forward_kinematics, load_body_model
from motiongen.body.random_motion import sample_motion
from motiongen.body.rotations import axis_angle_to_matrix
from motiongen.bvh.file_format import BVH, load_bvh, parse_bvh, write_bvh
from motiongen.bvh.retarget import bvh_to_body, import_bvh, resample
from motiongen.bvh.detect import detect_up
from motiongen.data.format import MotionDataset
from motiongen.errors import DataError
from motiongen.importers.bvh import main as bvh_main
from tests.helpers import user_error
from motiongen.metrics import foot_skating_ratio
from motiongen.bvh.export import TEMPLATE, joints_to_bvh, smplx_to_bvh
from motiongen.skeleton import BODY_JOINT_NAMES, BODY_PARENTS

BVH_DIR = Path("/usr/share/assimp/models/BVH")
CMU = ["01_01", "01_03"]
needs_mocap = pytest.mark.skipif(not (BVH_DIR / "01_01.bvh").is_file(),
                                 reason="apt-get install assimp-testmodels for real CMU mocap")
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def clips():
    """{name: (BVH, ImportedMotion)} for the three assimp clips, parsed once."""
    out = {}
    for name in CMU + ["Boxing_Toes"]:
        b = load_bvh(BVH_DIR / f"{name}.bvh")
        out[name] = (b, bvh_to_body(b))
    return out


def bone_lengths(j):
    """(T, 21) lengths of the SMPL-X bones."""
    return np.stack([np.linalg.norm(j[:, c] - j[:, p], axis=-1) for c, p in enumerate(BODY_PARENTS) if p >= 0], 1)


# --- real mocap --------------------------------------------------------------------------

@needs_mocap
@pytest.mark.parametrize("name,layout,unit", [("01_01", "cmu", "cmu"), ("01_03", "cmu", "cmu"),
                                              ("Boxing_Toes", "biovision", "cm")])
def test_real_mocap_is_human_sized(clips, name, layout, unit):
    b, m = clips[name]
    assert (m.layout, m.unit, m.up_axis, m.fps) == (layout, unit, "+y", 30.0)
    # stature: toe tip to head-top End Site, 95th percentile over frames (standing upright)
    world = b.fk() * {"cmu": 0.0254 / 0.45, "cm": 0.01}[unit]
    stature = np.percentile(np.ptp(world[..., 1], axis=1), 95)
    assert 1.5 <= stature <= 2.0, stature
    L = bone_lengths(m.joints)
    med = dict(zip(BODY_JOINT_NAMES[1:], np.median(L, 0)))
    for bone in ("left_knee", "right_knee", "left_ankle", "right_ankle"):      # thigh, shin
        assert 0.33 <= med[bone] <= 0.5, (bone, med[bone])
    for bone in ("left_elbow", "right_elbow", "left_wrist", "right_wrist"):   # upper arm, forearm
        assert 0.18 <= med[bone] <= 0.35, (bone, med[bone])
    assert L.std(0).max() < 1e-4                                              # rigid skeleton
    assert m.joints[..., 1].min() == pytest.approx(0.0)                       # on the floor


@needs_mocap
@pytest.mark.parametrize("name", CMU + ["Boxing_Toes"])
def test_real_mocap_barely_skates(clips, name):
    # Measured: 01_01 0.026, 01_03 0.071 (climbing/hanging: feet shuffle on the playground
    # frame near the floor), Boxing_Toes 0.080 (boxing footwork pivots on the toes).
    assert foot_skating_ratio(clips[name][1].joints, 30.0) < 0.1


@needs_mocap
@pytest.mark.parametrize("name,order", [("01_01", "ZXY"), ("01_03", "XYZ"), ("Boxing_Toes", "ZXY")])
def test_round_trip_import_export_import(clips, tmp_path, name, order):
    m = clips[name][1]
    path = write_bvh(tmp_path / "rt.bvh", joints_to_bvh(m.joints, 30.0, order=order))
    back = import_bvh(path)
    assert (back.layout, back.unit, back.fps) == ("smplx", "m", 30.0)
    assert np.abs(back.joints - m.joints).max() < 1e-3
    # Blender-style files: every body joint is a JOINT with 3 rotation channels, root also 3 positions
    b = load_bvh(path)
    assert b.channels[0][:3] == ("Xposition", "Yposition", "Zposition")
    assert all(len(c) == 3 for c, e in zip(b.channels[1:], b.is_end[1:]) if not e)


@needs_mocap
def test_cmu_spine_needs_a_helper_joint(clips):
    # CMU's spine turns against its hips (LowerBack); one pelvis rotation cannot carry both.
    m = clips["01_01"][1]
    with_helper = joints_to_bvh(m.joints, 30.0)
    assert "pelvis_to_spine1" in with_helper.names
    idx = [with_helper.index(n) for n in BODY_JOINT_NAMES]
    assert np.abs(with_helper.fk()[:, idx] - m.joints).max() < 1e-5
    plain = joints_to_bvh(m.joints, 30.0, helpers=False)
    idx = [plain.index(n) for n in BODY_JOINT_NAMES]
    assert 0.01 < np.abs(plain.fk()[:, idx] - m.joints).max() < 0.1


@needs_mocap
def test_z_up_inches_and_mixamo_names(clips, tmp_path):
    """The CMU skeleton re-expressed z-up, in inches, with mixamo-style names, imports to the
    same joints."""
    b, m = clips["01_01"]
    Q = Rotation.from_euler("x", 90, degrees=True)          # y-up -> z-up
    rot, trans = b.local_transforms()
    T, J = rot.shape[:2]
    local = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_matrix().reshape(T, J, 3, 3)
    q = Q.as_matrix()
    local = q @ local @ q.T                                  # conjugate every joint: FK' = Q FK
    s = 0.0254 / 0.45 / 0.0254                               # CMU units -> inches
    motion = np.concatenate([(Q.apply(trans[:, 0]) * s),
                             Rotation.from_matrix(local.reshape(-1, 3, 3)).as_euler("ZYX", degrees=True)
                             .reshape(T, J, 3)[:, ~b.is_end].reshape(T, -1)], 1)
    z = BVH([n if e else f"mixamorig:{n}" for n, e in zip(b.names, b.is_end)], b.parents, Q.apply(b.offsets) * s,
            [(("Xposition", "Yposition", "Zposition") if p < 0 else ()) + (() if e else ("Zrotation", "Yrotation", "Xrotation"))
             for p, e in zip(b.parents, b.is_end)], b.is_end, motion, b.frame_time)
    got = import_bvh(write_bvh(tmp_path / "z.bvh", z))
    assert (got.layout, got.unit, got.up_axis) == ("cmu", "inch", "+z")
    assert np.abs(got.joints - m.joints).max() < 1e-4


# --- synthetic --------------------------------------------------------------------------------

def test_smplx_parameters_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    T = 5
    rest = TEMPLATE + [0, 0.95, 0]
    aa = rng.normal(scale=0.4, size=(T, 22, 3))
    transl = rng.normal(size=(T, 3))
    # reference SMPL-X forward kinematics
    R = Rotation.from_rotvec(aa.reshape(-1, 3)).as_matrix().reshape(T, 22, 3, 3)
    W, X = np.empty_like(R), np.empty((T, 22, 3))
    for j, p in enumerate(BODY_PARENTS):
        if p < 0:
            W[:, j], X[:, j] = R[:, j], rest[j] + transl
        else:
            W[:, j] = W[:, p] @ R[:, j]
            X[:, j] = X[:, p] + W[:, p] @ (rest[j] - rest[p])
    b = load_bvh(write_bvh(tmp_path / "s.bvh", smplx_to_bvh(rest, aa, transl, 30.0, order="XYZ")))
    assert np.abs(b.fk()[:, [b.index(n) for n in BODY_JOINT_NAMES]] - X).max() < 1e-5


def test_rest_pose_is_a_t_pose():
    # a still rest pose exports with zero rotations everywhere except the root position
    j = np.broadcast_to(TEMPLATE + [0, 1.0, 0], (3, 22, 3))
    b = joints_to_bvh(j, 30.0)
    assert np.abs(b.motion[:, 3:]).max() < 1e-6
    np.testing.assert_allclose(b.rest_positions()[[b.index(n) for n in BODY_JOINT_NAMES]], TEMPLATE, atol=1e-9)


MINI = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Chest
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 5 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.0333333
0 90 0 90 0 0 0 0 0
1 90 0 0 0 0 0 90 0
0 0 0 90 0 90 0 0 0
"""


def test_parse_and_fk_conventions():
    b = parse_bvh(MINI)
    assert b.names == ["Hips", "Chest", "Chest_end"] and list(b.parents) == [-1, 0, 1]
    P = b.fk()
    # frame 0: root turned 90 degrees about z: +y offsets point to -x
    np.testing.assert_allclose(P[0], [[0, 90, 0], [-10, 90, 0], [-15, 90, 0]], atol=1e-9)
    # frame 1: Chest's channels are Z X Y, so "0 90 0" is Xrotation 90: its +y End Site turns to +z
    np.testing.assert_allclose(P[1], [[1, 90, 0], [1, 100, 0], [1, 100, 5]], atol=1e-9)
    # frame 2: root Z 90 then X 90, intrinsic (R = Rz Rx): +y -> +z. Extrinsic would give -x.
    np.testing.assert_allclose(P[2, 1], [0, 0, 10], atol=1e-9)


def test_resampling_to_30_fps():
    t = np.arange(121) / 120.0                                 # 1 s at 120 fps
    pos = np.stack([t, t ** 3, np.sin(t)], -1)[:, None]       # (121, 1, 3)
    out = resample(pos, 120.0, 30.0)
    t30 = np.arange(31) / 30.0
    np.testing.assert_allclose(out[:, 0], np.stack([t30, t30 ** 3, np.sin(t30)], -1), atol=1e-6)


def test_mapping_to_an_end_site_is_an_error():
    mapping = {n: "Hips" for n in BODY_JOINT_NAMES}
    mapping["head"] = "Chest_end"                              # End Sites are not mappable joints
    with pytest.raises(DataError, match="does not have"):
        bvh_to_body(parse_bvh(MINI), mapping, unit="cm")


# --- generated skeletons in every convention: up axis, unit, rest pose ----------------------------

# Our joints under Mixamo names (the `mixamo` layout), End Sites as (parent, canonical offset m).
MIXAMO = dict(zip(BODY_JOINT_NAMES, [
    "Hips", "LeftUpLeg", "RightUpLeg", "Spine", "LeftLeg", "RightLeg", "Spine1", "LeftFoot", "RightFoot", "Spine2",
    "LeftToeBase", "RightToeBase", "Neck", "LeftShoulder", "RightShoulder", "Head", "LeftArm", "RightArm",
    "LeftForeArm", "RightForeArm", "LeftHand", "RightHand"]))
ENDS = {15: (0, 0.12, 0), 10: (0, 0, 0.05), 11: (0, 0, 0.05), 20: (0.08, 0, 0), 21: (-0.08, 0, 0)}
MAIN_CHILD = {0: 3, 9: 12}           # pelvis -> spine1, spine3 -> neck; other joints have one child
UNIT_M = {"m": 1.0, "cm": 0.01, "inch": 0.0254}


@pytest.fixture(scope="module")
def walk():
    """A procedural SMPL-X walk, canonical y-up / facing +z / metres: joints X (T, 22, 3),
    global joint rotations W (T, 22, 3, 3), rest joints (22, 3)."""
    bm = load_body_model()
    p = sample_motion(60, 30.0, np.random.default_rng(3), gait=True)
    rest = bm.rest_joints(torch.as_tensor(p["betas"]))
    R = torch.cat([axis_angle_to_matrix(torch.as_tensor(p["global_orient"]))[:, None],
                   axis_angle_to_matrix(torch.as_tensor(p["body_pose"]).reshape(-1, 21, 3))], 1)  # (T, 22, 3, 3)
    P, G = forward_kinematics(R, rest, BODY_PARENTS)
    X = P + torch.as_tensor(p["transl"])[:, None]
    return X.double().numpy(), G.double().numpy(), rest.double().numpy()


def file_axes(up: str, forward: str) -> np.ndarray:
    """(3, 3) Q taking canonical axes (y up, z forward, x = y cross z) to the file's."""
    e = {f"{s}{a}": (1.0 if s == "+" else -1.0) * np.eye(3)["xyz".index(a)] for s in "+-" for a in "xyz"}
    u, f = e[up], e[forward]
    return np.stack([np.cross(u, f), u, f], 1)


def synth_bvh(path, X, W, rest, up="+y", forward="+z", unit="m", rest_pose="tpose", fps=30.0):
    """Write a BVH (Mixamo names, ZXY channels) whose FK is Q·X / scale for the canonical walk
    (X, W, rest); also returns the canonical End Site positions (T, 5, 3).

    Each joint j gets a rest frame C_j: the identity ('tpose': the zero pose is the canonical
    T-pose, in file axes) or a frame whose +x runs along the joint's main bone ('x': the
    zero pose lays every bone along +x, as LAFAN1-style rigs do). Offsets o_j = C_pᵀ Q r_j / s
    and global rotations G_j = Q W_j Qᵀ C_j give G_p o_j = Q W_p r_j / s: the canonical bone in
    file axes and units. The motion channels hold the local rotations G_pᵀ G_j."""
    Q, s = file_axes(up, forward), UNIT_M[unit]
    parents = list(BODY_PARENTS) + list(ENDS)
    bones = [rest[j] - rest[p] if p >= 0 else np.zeros(3) for j, p in enumerate(BODY_PARENTS)]
    bones += [np.array(o, float) for o in ENDS.values()]
    C = np.broadcast_to(np.eye(3), (22, 3, 3)).copy()
    if rest_pose == "x":
        for j in range(22):
            kids = [c for c, p in enumerate(parents) if p == j]
            d = Q @ bones[MAIN_CHILD.get(j, kids[0])]
            C[j] = Rotation.align_vectors([d / np.linalg.norm(d)], [[1.0, 0, 0]])[0].as_matrix()
    offsets = np.stack([C[p].T @ Q @ b / s if p >= 0 else np.zeros(3) for b, p in zip(bones, parents)])
    G = Q @ W @ Q.T @ C                                                     # (T, 22, 3, 3)
    L = np.concatenate([G[:, :1], np.swapaxes(G[:, list(BODY_PARENTS[1:])], -1, -2) @ G[:, 1:]], 1)
    T = len(X)
    euler = Rotation.from_matrix(L.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True).reshape(T, 22 * 3)
    motion = np.concatenate([X[:, 0] @ Q.T / s, euler], 1)
    rot = ("Zrotation", "Xrotation", "Yrotation")
    b = BVH([MIXAMO[n] for n in BODY_JOINT_NAMES] + [f"{MIXAMO[BODY_JOINT_NAMES[p]]}_end" for p in ENDS],
            np.array(parents), offsets, [("Xposition", "Yposition", "Zposition") + rot] + [rot] * 21 + [()] * len(ENDS),
            np.arange(len(parents)) >= 22, motion, 1.0 / fps)
    ends = X[:, list(ENDS)] + np.einsum("tjab,jb->tja", W[:, list(ENDS)], np.array(list(ENDS.values())))
    return write_bvh(path, b, precision=8), ends


def horizontal_fit(a, b):
    """Max residual after the best rotation about y + shift taking points a onto b (N, 3)."""
    a, b = a[:, [0, 2]] - a[:, [0, 2]].mean(0), b[:, [0, 2]] - b[:, [0, 2]].mean(0)
    U, _, Vt = np.linalg.svd(a.T @ b)
    R = (U @ Vt).T
    assert np.linalg.det(R) > 0                          # a rotation, not a mirror
    return np.abs(a @ R.T - b).max()


@pytest.mark.parametrize("rest_pose", ["tpose", "x"])
@pytest.mark.parametrize("unit", ["m", "cm", "inch"])
@pytest.mark.parametrize("up,forward", [("+y", "+z"), ("+z", "-y"), ("+y", "+x"), ("+z", "+x")])
def test_any_convention_imports_upright_with_the_right_height(walk, tmp_path, up, forward, unit, rest_pose):
    X, W, rest = walk
    path, ends = synth_bvh(tmp_path / "w.bvh", X, W, rest, up, forward, unit, rest_pose)
    b = load_bvh(path)
    Q = file_axes(up, forward)
    got = b.fk()[:, [b.index(MIXAMO[n]) for n in BODY_JOINT_NAMES]] * UNIT_M[unit]
    assert np.abs(got - X @ Q.T).max() < 1e-6                      # the generator writes what it says
    if rest_pose == "x":                                             # the zero pose lies along +x
        assert np.ptp(b.rest_positions()[:, 0]) > 5 * np.ptp(b.rest_positions()[:, 1:], axis=0).max()
    m = import_bvh(path)
    assert (m.layout, m.unit, m.up_axis, m.up_from, m.unit_from) == ("mixamo", unit, up, "motion", "leg length")
    # upright: heights are the canonical ones (lowest joint on the floor), the floor plan is X's turned about y
    np.testing.assert_allclose(m.joints[..., 1], X[..., 1] - X[..., 1].min(), atol=1e-5)
    assert horizontal_fit(X.reshape(-1, 3), m.joints.reshape(-1, 3)) < 1e-5
    # stature: head-top End Site above the lowest joint or End Site, 95th percentile
    pts = np.concatenate([X, ends], 1)
    expect = np.percentile(ends[:, 0, 1] - pts[..., 1].min(1), 95)
    assert m.height == pytest.approx(expect, abs=1e-5) and 1.5 < m.height < 1.9


@pytest.mark.parametrize("size", [0.8, 1.2])
def test_short_and_tall_people_laid_along_x(walk, tmp_path, size):
    """A 1.3 m and a 1.95 m person, rest pose along +x, cm. Before the motion decided, the tall
    one was written silently lying on its side (up +x, pelvis 1.3 m above the floor)."""
    X, W, rest = (a * (size if a.ndim != 4 else 1.0) for a in walk)
    path, ends = synth_bvh(tmp_path / "w.bvh", X, W, rest, "+y", "+z", "cm", "x")
    m = import_bvh(path)
    assert (m.unit, m.up_axis) == ("cm", "+y")
    np.testing.assert_allclose(m.joints[..., 1], X[..., 1] - X[..., 1].min(), atol=1e-5)
    assert np.median(m.joints[:, 15, 1] - m.joints[:, 0, 1]) > 0.4 * size        # head well above pelvis
    pts = np.concatenate([X, ends], 1)
    assert m.height == pytest.approx(np.percentile(ends[:, 0, 1] - pts[..., 1].min(1), 95), abs=1e-5)


def test_lying_motion_is_refused(walk, tmp_path):
    """The same walk lying on its side throughout, written y-up with an upright rest pose: the
    motion's head is beside the feet, the rest pose says +y; neither guess is written."""
    X, W, rest = walk
    lie = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    X, W = X @ lie.T, lie @ W
    X[..., 1] -= X[..., 1].min() - 0.1
    path, _ = synth_bvh(tmp_path / "lying.bvh", X, W, rest)
    with pytest.raises(DataError, match=r"lying.bvh: cannot tell the up axis: the head is above the feet along "
                                        r"-x over the motion but the rest pose stands along \+y; pass up="):
        import_bvh(path)
    with pytest.raises(DataError, match=r"not a plausible standing human after import \(up \+y from given.*"
                                        r"head above pelvis above feet in \d+% of frames.*height 0.\d+ m"):
        import_bvh(path, up="y")


def test_floating_motion_is_refused(walk, tmp_path):
    X, W, rest = walk
    X = X + np.linspace(0, 3, len(X))[:, None, None] * [0, 1, 0]      # rises 3 m: no floor
    path, _ = synth_bvh(tmp_path / "fly.bvh", X, W, rest, "+z", "+x", "cm", "x")
    with pytest.raises(DataError, match=r"the lowest foot is within 0.25 m of one floor in \d+% of frames"):
        import_bvh(path)


def test_wrong_overrides_and_unhuman_sizes_are_refused(walk, tmp_path):
    X, W, rest = walk
    path, _ = synth_bvh(tmp_path / "w.bvh", X, W, rest, "+z", "+x", "cm", "x")
    with pytest.raises(DataError, match=r"unit mm from given\): .*height 0.1\d+ m \(expected 1.0-2.3 m\)"):
        import_bvh(path, unit="mm")
    with pytest.raises(DataError, match=r"up \+x from given.*head above pelvis above feet in \d+% of frames.*height 0.\d+ m"):
        import_bvh(path, up="x")
    with pytest.raises(DataError, match=r"\[up\]: expected x, y or z"):
        import_bvh(path, up="north")
    # a 'human' 4 m tall in metres and 0.23 m in CMU units: no unit makes it a human
    giant, _ = synth_bvh(tmp_path / "giant.bvh", X * 4.0, W, rest * 4.0)
    with pytest.raises(DataError, match=r"giant.bvh: cannot detect units: a leg \(hip-knee-ankle\) of 3.\d+ file units"):
        import_bvh(giant)


def test_rest_pose_is_only_a_hint():
    """Unit test of the vote: an ambiguous motion falls back on an upright rest pose, a clear
    motion needs none, and with neither the import asks for up=."""
    rest = np.zeros((22, 3))
    rest[15], rest[[7, 8, 10, 11]] = [0, 0, 1.5], [0, 0, -0.9]               # z-up standing rest pose
    tilted = np.zeros((4, 22, 3))
    tilted[:, 15] = [[1, 0, 0.4], [-1, 0, 0.4], [0, 1, 0.4], [0, -1, 0.4]]    # mostly horizontal
    assert detect_up(tilted, rest)[:2] == ("+z", "rest pose")
    upright = tilted.copy()
    upright[:, 15] = [0, 0, 1.5]
    assert detect_up(upright, np.zeros((22, 3)))[:2] == ("+z", "motion")
    with pytest.raises(DataError, match="cannot find the up axis.*pass up="):
        detect_up(tilted, np.zeros((22, 3)))


@needs_mocap
def test_cmu_with_a_wrong_up_axis_is_refused():
    with pytest.raises(DataError, match=r"01_01.bvh: not a plausible standing human after import \(up \+z from given"):
        import_bvh(BVH_DIR / "01_01.bvh", up="z")


# --- the CLI, including malformed files ------------------------------------------------------

def run_cli(*args):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "motiongen.importers.bvh", *args],
                          capture_output=True, text=True, env=env, timeout=120)


def broken(kind: str) -> str:
    if kind == "bad hierarchy":
        return MINI.replace("  JOINT Chest\n  {", "  JOINT Chest\n  OFFSET")
    if kind == "wrong channel count":
        return MINI.replace("1 90 0 0 0 0 0 90 0", "1 90 0 0 0 0 0 90")
    if kind == "truncated motion":
        return MINI[:MINI.rindex("1 90 0 0") + 6]     # cut inside frame 1
    if kind == "empty motion":
        return MINI.replace("Frames: 3", "Frames: 0").split("0 90 0 90")[0]
    if kind == "unknown joints":
        return MINI
    raise KeyError(kind)


@pytest.mark.parametrize("kind,message", [
    ("bad hierarchy", r"line 7: expected '\{', found 'OFFSET'"),
    ("wrong channel count", "line 20: frame 1 has 8 values, the hierarchy declares 9 channels"),
    ("truncated motion", r"truncated motion block: header says 3 frames, found 2 \(last line 20 has 3 of 9"),
    ("empty motion", r"empty motion \(Frames: 0\)"),
    ("unknown joints", "match no known layout.*pass mapping=FILE"),
])
def test_cli_malformed_bvh_exits_2_with_one_line(tmp_path, kind, message):
    f = tmp_path / "bad.bvh"
    f.write_text(broken(kind))
    r = run_cli(f"inputs=[{f}]", f"out={tmp_path / 'ds'}")
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {f}"), r.stderr
    assert re.search(message, lines[0]), lines[0]
    assert not (tmp_path / "ds").exists()


def test_cli_refuses_an_implausible_clip_and_writes_nothing(walk, tmp_path):
    X, W, rest = walk
    good, _ = synth_bvh(tmp_path / "good.bvh", X, W, rest, "+z", "+x", "inch", "x")
    r = run_cli(f"inputs=[{good}]", f"out={tmp_path / 'ds'}")
    assert r.returncode == 0, r.stderr
    info = MotionDataset.open(tmp_path / "ds").meta["bvh_import"][0]
    assert (info["unit"], info["unit_from"], info["up_axis"], info["up_from"]) == ("inch", "leg length", "+z", "motion")
    lie = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    lying, _ = synth_bvh(tmp_path / "lying.bvh", X @ lie.T, lie @ W, rest)
    for args, message in [((f"inputs=[{good}]", "up=x"), f"error: {good}: not a plausible standing human after import"),
                          ((f"inputs=[{good},{lying}]",), f"error: {lying}: cannot tell the up axis"),
                          ((f"inputs=[{good}]", "up=north"), "error: up='north': expected x, y or z")]:
        r = run_cli(*args, f"out={tmp_path / 'bad'}")
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith(message), r.stderr
        assert not (tmp_path / "bad").exists() and not list(tmp_path.glob("bad.partial*"))


def test_cli_user_mapping(tmp_path):
    """A skeleton with made-up names imports with mapping=FILE, and not without it."""
    j = np.broadcast_to(TEMPLATE + [0, 1.0, 0], (4, 22, 3)).copy()
    j[:, :, 0] += np.linspace(0, 0.3, 4)[:, None]
    b = joints_to_bvh(j, 30.0, unit="cm")
    rename = {n: f"bone{i}" for i, n in enumerate(BODY_JOINT_NAMES)}
    b.names = [rename.get(n, n) for n in b.names]
    src = write_bvh(tmp_path / "odd.bvh", b)
    assert run_cli(f"inputs=[{src}]", f"out={tmp_path / 'no'}").returncode == 2
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps(rename))
    r = run_cli(f"inputs=[{src},{src}]", f"out={tmp_path / 'ds'}", f"mapping={mapping}", "split=test", "action=walk")
    assert r.returncode == 0, r.stderr
    ds = MotionDataset.open(tmp_path / "ds")
    assert [s.name for s in ds.split_sequences("test")] == ["odd", "odd_1"]
    assert ds.action_names == ["walk"] and ds.actions[:].all()
    on_floor = j - [0, j[..., 1].min(), 0]                     # the import puts the lowest joint at y = 0
    np.testing.assert_allclose(np.asarray(ds.joints[:4]), on_floor, atol=1e-5)
    assert ds.grid(0).occupied(np.array([[0.0, 1.0, 0.0]]))[0] == False  # noqa: E712  empty floor scene
    bad = tmp_path / "badmap.json"
    bad.write_text(json.dumps({"pelvis": "bone0"}))
    r = run_cli(f"inputs=[{src}]", f"out={tmp_path / 'x'}", f"mapping={bad}")
    assert r.returncode == 2 and "missing" in r.stderr and len(r.stderr.strip().splitlines()) == 1


@needs_mocap
def test_cli_imports_cmu(tmp_path):
    r = run_cli(f"inputs=[{BVH_DIR / '01_01.bvh'}]", f"out={tmp_path / 'ds'}")
    assert r.returncode == 0, r.stderr
    ds = MotionDataset.open(tmp_path / "ds")
    assert ds.fps == 30.0 and ds.num_frames == 688 and ds.meta["bvh_import"][0]["layout"] == "cmu"
    # feet are labelled in contact for a good part of a clip that is mostly standing and jumping
    assert 0.2 < ds.contact[:, [10, 11]].mean() < 0.95


@pytest.mark.parametrize("fps, message", [("0", "fps: expected a number > 0"), ("1e9", "and <= 1000, got 1000000000.0"),
                                          ("nan", "fps: expected a number > 0")])
def test_cli_bounds_the_output_rate(walk, tmp_path, capsys, fps, message):
    """fps=1e9 asked for billions of frames of every clip; now one line, nothing written."""
    X, W, rest = walk
    good, _ = synth_bvh(tmp_path / "good.bvh", X, W, rest)
    assert message in user_error(capsys, bvh_main, [f"inputs=[{good}]", f"out={tmp_path / 'ds'}", f"fps={fps}"])
    assert not (tmp_path / "ds").exists()
