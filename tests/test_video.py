"""The sample video: the body mesh at the motion's frame rate, floor contact marked, the stick
figure still available; and the rasteriser underneath (visibility, culling, decimation)."""

import multiprocessing as mp
import os
import time

import numpy as np
import pytest

from motiongen.export.render_body import cluster_decimate, contact_anchors, facing, rasterise
from motiongen.export.video import render_video
from tests.helpers import standing_body_motion

T = 20
CONTACT = [7, 10, 8, 11]          # ankles and toes
W, H = 800, 352                   # render_video's default size
CAM_X0 = int(0.45 * W)            # the camera panel starts at 45 % of the width


# ---- the rasteriser on known geometry -------------------------------------------------

def test_nearer_triangle_wins_whatever_the_drawing_order():
    xy = np.array([[[0, 0], [10, 0], [0, 10]], [[2, 2], [12, 2], [2, 12]]], float)      # (2, 3, 2) pixels
    rgb = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    for near in (0, 1):
        invz = np.full((2, 3), 1 / 4.0)
        invz[near] = 1 / 2.0                                                             # depth 2 m vs 4 m
        for order in ([0, 1], [1, 0]):
            img, cover = rasterise(xy[order], invz[order], rgb[order], 14, 14)
            assert img[3, 3].tolist() == rgb[near].tolist()                              # the overlap
            assert img[1, 1].tolist() == [1, 0, 0] and img[4, 8].tolist() == [0, 1, 0]   # one face only
            assert not cover[13, 13] and img[13, 13].tolist() == [0, 0, 0]


def test_depth_is_interpolated_per_pixel_not_per_face():
    """Two triangles crossing in depth: each wins on its own side of the crossing, which
    sorting whole faces (painter's algorithm) cannot get right."""
    xy = np.array([[[0, 0], [20, 0], [0, 20]], [[0, 0], [20, 0], [0, 20]]], float)
    a = np.array([[1 / 2.0, 1 / 6.0, 1 / 2.0]])              # nearer on the left, farther on the right
    b = np.array([[1 / 4.0, 1 / 4.0, 1 / 4.0]])              # flat at 4 m
    img, _ = rasterise(xy, np.concatenate([a, b]), np.array([[1.0], [2.0]]), 20, 20)
    assert img[5, 1, 0] == 1.0 and img[1, 15, 0] == 2.0


def test_facing_keeps_the_faces_turned_to_the_eye():
    import trimesh

    box = trimesh.creation.box([1.0, 1.0, 1.0])
    front, n = facing(np.asarray(box.vertices), np.asarray(box.faces), eye=np.array([0.0, 0.0, 5.0]))
    assert front.sum() == 2 and np.allclose(n[front], [0, 0, 1])


def test_decimation_never_joins_differently_labelled_parts():
    import trimesh

    a = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    b = a.copy()
    b.apply_translation([0.19, 0, 0])                        # 1 cm gap: shares lattice cells with a
    v = np.concatenate([a.vertices, b.vertices])
    f = np.concatenate([a.faces, b.faces + len(a.vertices)])
    labels = np.r_[np.zeros(len(a.vertices), int), np.ones(len(b.vertices), int)]
    ids, faces = cluster_decimate(v, f, labels, cell=0.04)
    assert len(ids) < len(v) / 4
    assert (labels[ids][faces] == labels[ids][faces][:, :1]).all()                     # no face spans both
    m = trimesh.Trimesh(v[ids], faces, process=False)
    assert m.volume == pytest.approx(2 * a.volume, rel=0.25)                           # outward, not a shell of holes


def test_contact_anchor_is_where_the_span_began():
    joints = np.zeros((1, 6, 12, 3))
    joints[0, :, 7, 0] = np.arange(6) * 0.1                  # the ankle slides along x
    planted = np.array([[0, 1, 1, 0, 1, 1]], bool)[..., None]
    a = contact_anchors(joints, planted, [7])                 # (1, 6, 1, 2)
    assert np.isnan(a[0, [0, 3], 0]).all()
    assert a[0, [1, 2], 0, 0].tolist() == pytest.approx([0.1, 0.1])
    assert a[0, [4, 5], 0, 0].tolist() == pytest.approx([0.4, 0.4])


# ---- videos ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def motion(tmp_path_factory):
    return standing_body_motion(tmp_path_factory.mktemp("body"), T)                  # joints (1, T, 22, 3)


def _frames(path):
    import imageio.v2 as imageio

    with imageio.get_reader(path) as r:
        return np.stack([f for f in r.iter_data()]), r.get_meta_data().get("fps")


def _cam(frames):
    return frames[:, :, CAM_X0:].astype(int)


def _lime(frames):
    """(N,) pixels of the contact colour in each frame's camera panel (after video compression)."""
    f = _cam(frames)
    r, g, b = f[..., 0], f[..., 1], f[..., 2]
    return ((g > 170) & (b < 110) & (g - r > 40) & (g - b > 110)).sum((1, 2))


def _red(frames, r: int = 0):
    """(N,) pixels of sample 0's colour (red, shaded) in each frame's camera panel; with r > 0
    only those whose whole (2r+1)^2 neighbourhood is red: the inside of a filled shape, which
    lines a few pixels wide do not have."""
    f = _cam(frames)
    red = (f[..., 0] > 110) & (f[..., 0] - f[..., 1] > 60) & (f[..., 0] - f[..., 2] > 60)    # (N, h, w)
    h, w = red.shape[1:]
    inner = red[:, r:h - r, r:w - r].copy()
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            inner &= red[:, r + dy:h - r + dy, r + dx:w - r + dx]
    return inner.sum((1, 2))


PLANTED = np.zeros((1, T, 4), bool)
PLANTED[0, :10] = True                                        # feet planted for the first 10 frames only


@pytest.fixture(scope="module")
def body_video(motion, tmp_path_factory):
    bm, body, joints = motion
    path = render_video(tmp_path_factory.mktemp("v") / "body.mp4", joints, 30.0, bodies=[body], body_model=bm,
                        planted=PLANTED, contact_joints=CONTACT)
    return _frames(path)


@pytest.fixture(scope="module")
def skeleton_video(motion, tmp_path_factory):
    bm, body, joints = motion
    path = render_video(tmp_path_factory.mktemp("v") / "skel.mp4", joints, 30.0, bodies=[body], body_model=bm,
                        planted=PLANTED, contact_joints=CONTACT, style="skeleton")
    return _frames(path)


def test_every_frame_at_the_motions_rate(body_video):
    frames, fps = body_video
    assert frames.shape == (T, H, W, 3) and fps == pytest.approx(30.0)


def test_the_body_is_drawn_where_the_camera_looks(body_video, skeleton_video):
    body, skel = _red(body_video[0]), _red(skeleton_video[0])
    assert (body > 1500).all() and (skel > 100).all()                                # both draw sample 0
    assert (_red(body_video[0], r=2) > 300).all()                                    # a filled body...
    assert (_red(skeleton_video[0], r=2) < 30).all()                                 # ...not lines (joints: a few)
    f = _cam(body_video[0][:1])[0].astype(int)
    cols = np.nonzero((f[..., 0] > 110) & (f[..., 0] - f[..., 1] > 60))[1] + CAM_X0
    assert abs(np.median(cols) - (0.45 + 0.99) / 2 * W) < 60                           # the camera follows the body


@pytest.mark.parametrize("video", ["body_video", "skeleton_video"])
def test_planted_feet_are_marked_only_while_planted(video, request):
    lime = _lime(request.getfixturevalue(video)[0])
    assert (lime[:10] > 25).all(), lime
    assert (lime[10:] == 0).all(), lime


def test_body_style_without_bodies_is_the_skeleton(motion, skeleton_video, tmp_path):
    _, _, joints = motion
    frames, _ = _frames(render_video(tmp_path / "fallback.mp4", joints, 30.0, planted=PLANTED, contact_joints=CONTACT))
    assert np.abs(frames.astype(int) - skeleton_video[0]).mean() < 1.0


def test_video_fps_override_and_bad_style(motion, tmp_path):
    bm, body, joints = motion
    frames, fps = _frames(render_video(tmp_path / "low.mp4", joints, 30.0, video_fps=5, bodies=[body], body_model=bm))
    assert len(frames) == 4 and fps == pytest.approx(5.0)                           # frames 0, 6, 12, 18
    with pytest.raises(ValueError, match="style"):
        render_video(tmp_path / "x.mp4", joints, 30.0, style="mesh")


def test_frames_drawn_by_worker_processes_arrive_in_order(monkeypatch):
    from motiongen.export import video

    monkeypatch.setattr(video, "FRAME_BLOCK", 4)
    idx = np.arange(0, 30, 2)                                                        # 15 frames, 4 blocks
    # Every block's first frame (t = 0, 8, 16, 24) waits for a second process to arrive: one
    # worker cannot take all blocks, however fast it draws (it would time out instead).
    meet = mp.get_context("fork").Barrier(2, timeout=60)

    def draw(t):
        if t % 8 == 0:
            meet.wait()
        return np.array([t, os.getpid()])

    out = list(video._frame_stream(draw, idx, workers=2))
    assert [int(f[0]) for f in out] == idx.tolist()
    assert len({int(f[1]) for f in out}) == 2 and os.getpid() not in {int(f[1]) for f in out}
    one = list(video._frame_stream(lambda t: np.array([t, os.getpid()]), idx, workers=1))
    assert {int(f[1]) for f in one} == {os.getpid()}


def test_workers_that_never_answer_leave_the_frames_to_this_process(monkeypatch, capsys):
    from motiongen.export import video

    monkeypatch.setattr(video, "FRAME_BLOCK", 4)
    monkeypatch.setattr(video, "BLOCK_TIMEOUT_S", 2.0)
    parent, idx = os.getpid(), np.arange(16)

    def draw(t):
        if os.getpid() != parent:
            time.sleep(120)                            # a stuck worker (terminated with the pool)
        return np.array([t, os.getpid()])

    start = time.perf_counter()
    out = list(video._frame_stream(draw, idx, workers=2))
    assert [int(f[0]) for f in out] == idx.tolist()
    assert {int(f[1]) for f in out} == {parent}
    assert time.perf_counter() - start < 30
    assert "drawing the remaining 16 frames in this process" in capsys.readouterr().err


def test_workers_draw_the_same_video_as_one_process(motion, tmp_path, monkeypatch):
    from motiongen.export import video

    bm, body, joints = motion
    monkeypatch.setattr(video, "FRAME_BLOCK", 8)                                     # 20 frames: 3 blocks
    kw = dict(bodies=[body], body_model=bm, planted=PLANTED, contact_joints=CONTACT)
    one, _ = _frames(render_video(tmp_path / "one.mp4", joints, 30.0, workers=1, **kw))
    two, _ = _frames(render_video(tmp_path / "two.mp4", joints, 30.0, workers=2, **kw))
    assert one.shape == (T, H, W, 3) and np.array_equal(one, two)


def test_the_saved_camera_is_the_one_each_frame_was_drawn_with(motion, tmp_path):
    # Two cameras by turns, both 3 m in front of the body, aimed 0.6 m to either side of it: the
    # body must appear where the camera arrays saved for motion.npz put it, frame by frame.
    from motiongen.export.camera import CameraPath, PinholeCamera
    from motiongen.skeleton import PELVIS

    bm, body, joints = motion
    pel = joints[0, :, PELVIS]                                                        # (T, 3)
    side = np.where(np.arange(T) % 2 == 0, 0.6, -0.6)                                 # (T,) metres
    eye = pel + np.array([0.0, 0.4, 3.0])
    target = pel + np.stack([side, np.full(T, 0.4), np.zeros(T)], -1)
    np.savez(tmp_path / "camera.npz", **CameraPath(eye, target, 1.6, "follow").arrays())
    path = render_video(tmp_path / "c.mp4", joints, 30.0, bodies=[body], body_model=bm, camera=CameraPath(eye, target))
    frames, _ = _frames(path)
    with np.load(tmp_path / "camera.npz") as z:
        cams = [PinholeCamera(z["camera_position"][t], z["camera_target"][t], z["camera_focal"][t]) for t in range(T)]
    # The panel (axes at 45-99 % of 800 px, 2 % up, 90 % high, equal aspect, x in ±1.0, y in ±0.8)
    # is limited by its height: 0.9 * 352 px for 1.6 units, centred at 72 % of the width.
    px_per_unit, centre = 0.9 * H / 1.6, 0.72 * W
    for t in range(T):
        u = cams[t].project(pel[t][None])[0][0, 0]
        assert abs(abs(u) - 0.6 * 1.6 / 3.0) < 0.05                                  # the saved camera aims beside the body
        f = frames[t].astype(int)
        red = (f[..., 0] > 110) & (f[..., 0] - f[..., 1] > 60) & (f[..., 0] - f[..., 2] > 60)
        red[:, :CAM_X0] = False
        cols = np.nonzero(red)[1]
        assert len(cols) > 500 and abs(np.median(cols) - (centre + u * px_per_unit)) < 20, (t, np.median(cols), u)
