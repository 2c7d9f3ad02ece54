"""The camera panel's OpenGL renderer: its projection is `PinholeCamera.project`'s, the scene
and the body hide each other by depth, it renders in forked workers, and videos still come
out (through matplotlib and numpy) where no OpenGL context can be made."""

import multiprocessing as mp
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from motiongen.export import gl_render
from motiongen.export.camera import CAM_VIEW, CameraPath, PinholeCamera
from motiongen.export.video import render_video
from tests.helpers import standing_body_motion

pytest.importorskip("moderngl")
if not gl_render.available():
    pytest.skip("no EGL context on this machine", allow_module_level=True)

W, H = 200, 160
ROOT = Path(__file__).resolve().parents[1]
RED = (0.9, 0.1, 0.1)
CAM = PinholeCamera(np.array([0.0, 1.5, -4.0]), np.array([0.0, 1.0, 0.0]))


def _box(extents, centre) -> np.ndarray:
    """(12, 3, 3) triangles of an axis-aligned box."""
    b = trimesh.creation.box(extents)
    b.apply_translation(centre)
    return np.asarray(b.triangles)


def _body(centre=(0.0, 0.9, 0.0)):
    """A body-sized box as (vertices, faces, colour)."""
    b = trimesh.creation.box([0.4, 1.8, 0.3])
    b.apply_translation(centre)
    return np.asarray(b.vertices), np.asarray(b.faces), RED


def _pixel(cam, p, w=W, h=H) -> tuple[int, int]:
    """(row, col) of world point p (3,) by cam.project: columns span u in ±CAM_VIEW[0] left to
    right, rows v from +CAM_VIEW[1] at the top."""
    uv, _ = cam.project(np.asarray(p, float)[None])
    col = (uv[0, 0] + CAM_VIEW[0]) / (2 * CAM_VIEW[0]) * w - 0.5
    row = (CAM_VIEW[1] - uv[0, 1]) / (2 * CAM_VIEW[1]) * h - 0.5
    return int(round(row)), int(round(col))


def _is_red(px) -> bool:
    return px[0] > 120 and px[0] - px[2] > 60


def _is_scene(px) -> bool:
    return px[2] > px[0] + 8                       # the grey-blue scene; floor and sky are warm


@pytest.mark.parametrize("p", [(1.0, 1.6, 0.5), (-0.8, 0.4, -0.5), (0.3, 2.0, 2.0)])
def test_a_world_point_lands_on_the_pixel_pinhole_camera_predicts(p):
    r = gl_render.PanelRenderer((W, H))
    r.set_scene(_box([0.06, 0.06, 0.06], p))
    img = r.render(CAM)
    rows, cols = np.nonzero((img[..., 2].astype(int) - img[..., 0]) > 8)
    assert len(rows), "the cube is not in the image"
    row, col = _pixel(CAM, p)
    assert abs(rows.mean() - row) <= 1.0 and abs(cols.mean() - col) <= 1.0
    r.release()


def test_a_box_between_camera_and_body_hides_it():
    r = gl_render.PanelRenderer((W, H))
    r.set_floor((-5, -5), (5, 5))
    at = _pixel(CAM, (0.0, 0.9, 0.0))
    assert _is_red(r.render(CAM, [_body()])[at])                                  # seen without the box
    r.set_scene(_box([1.0, 1.0, 0.2], (0.0, 1.0, -1.5)))                            # between the camera and it
    img = r.render(CAM, [_body()])
    assert _is_scene(img[at]) and not _is_red(img[at])
    assert _is_red(img[_pixel(CAM, (0.0, 1.7, 0.0))])                              # the head shows over it
    r.release()


def test_the_body_in_front_of_a_wall_hides_the_wall():
    r = gl_render.PanelRenderer((W, H))
    r.set_scene(_box([4.0, 3.0, 0.2], (0.0, 1.5, 1.0)))                             # a wall behind the body
    img = r.render(CAM, [_body()])
    assert _is_red(img[_pixel(CAM, (0.0, 0.9, 0.0))])
    assert _is_scene(img[_pixel(CAM, (1.0, 0.9, 0.9))])                            # the wall beside it


def test_the_body_casts_a_shadow_and_discs_mark_the_floor():
    r = gl_render.PanelRenderer((W, H))
    r.set_floor((-5, -5), (5, 5))
    floor = r.render(CAM)
    disc = np.array([[[1.0, 0.002, 0.0], [1.2, 0.002, 0.0], [1.1, 0.002, 0.2]]])      # (1, 3, 3)
    img = r.render(CAM, [_body((0.0, 1.2, 0.0))], discs=disc).astype(int)           # 30 cm above the floor
    under = _pixel(CAM, (0.0, 0.0, -0.05))                                           # seen under it
    assert img[under].sum() < floor[under].astype(int).sum() - 60
    px = img[_pixel(CAM, (1.1, 0.0, 0.07))]
    assert px[1] > 200 and px[2] < 60                                                # lime


def _child_render(_):
    return _SHARED.render(CAM, [_body()])


def test_a_forked_child_renders_after_the_parent_did():
    global _SHARED
    _SHARED = gl_render.PanelRenderer((W, H))
    _SHARED.set_scene(_box([4.0, 3.0, 0.2], (0.0, 1.5, 1.0)))
    parent = _SHARED.render(CAM, [_body()])
    with mp.get_context("fork").Pool(1) as pool:
        child = pool.apply_async(_child_render, (0,)).get(timeout=120)      # a hang fails, not blocks
    assert np.array_equal(parent, child)
    assert np.array_equal(_SHARED.render(CAM, [_body()]), parent)                  # the parent's context still works
    _SHARED.release()


FIRST_RUN = """
import multiprocessing as mp
import numpy as np
from motiongen.export import gl_render
from tests.test_gl_render import CAM, W, H, _body

assert gl_render.available()                 # the parent's probe, as `render_video` makes it
renderer = gl_render.PanelRenderer((W, H))
with mp.get_context("fork").Pool(1) as pool:
    image = pool.apply_async(renderer.render, (CAM, [_body()])).get(timeout=60)
print("drawn", int((image[..., 0] > 150).sum()))
"""


def test_a_forked_child_renders_on_a_machine_whose_shader_cache_is_empty(tmp_path):
    """The first video on a fresh machine: its child compiles every shader, which Mesa queues
    for its cache's writer thread, absent in a forked child (it hung the main job)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MESA_SHADER_CACHE")}
    env["MESA_SHADER_CACHE_DIR"] = str(tmp_path / "empty")
    out = subprocess.run([sys.executable, "-c", FIRST_RUN], env=env, cwd=ROOT, capture_output=True, text=True,
                         timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]
    assert int(out.stdout.split()[-1]) > 100                          # the red body is in the image


# ---- in the video ---------------------------------------------------------------------

T = 6


@pytest.fixture(scope="module")
def motion(tmp_path_factory):
    bm, body, joints = standing_body_motion(tmp_path_factory.mktemp("body"), T)      # joints (1, T, 22, 3)
    pel = joints[0, :, 0].astype(np.float64)                                         # (T, 3)
    # A camera 4 m down -z from the pelvis, looking at it.
    camera = CameraPath(pel + np.array([0.0, 0.6, -4.0]), pel.copy())
    return bm, body, joints, camera


def _video(path, motion, **kw):
    import imageio.v2 as imageio

    bm, body, joints, camera = motion
    out = render_video(path, joints, 30.0, bodies=[body], body_model=bm, camera=camera, **kw)
    with imageio.get_reader(out) as r:
        frames = np.stack(list(r.iter_data())).astype(int)                          # (T, H, W, 3)
    f = frames[:, :, int(0.45 * frames.shape[2]):]                                   # the camera panel
    return ((f[..., 0] > 110) & (f[..., 0] - f[..., 1] > 60) & (f[..., 0] - f[..., 2] > 60)).sum((1, 2))


def test_a_scene_mesh_wall_hides_the_body_in_the_video(motion, tmp_path):
    pel = motion[3].target[0]
    wall = trimesh.creation.box([4.0, 3.0, 0.1])
    wall.apply_translation([pel[0], 1.5, pel[2] - 2.0])                             # between camera and body
    seen = _video(tmp_path / "open.mp4", motion)
    hidden = _video(tmp_path / "wall.mp4", motion, scene_mesh=wall)
    assert (seen > 1000).all() and (hidden == 0).all(), (seen, hidden)


def test_without_opengl_the_video_falls_back_and_warns_once(motion, tmp_path, monkeypatch, capsys):
    def no_context():
        raise RuntimeError("no EGL here")

    monkeypatch.setattr(gl_render, "_create_context", no_context)
    monkeypatch.setattr(gl_render, "_AVAILABLE", None)
    monkeypatch.setattr(gl_render, "_WARNED", False)
    red = _video(tmp_path / "a.mp4", motion)
    _video(tmp_path / "b.mp4", motion, style="skeleton")
    assert (red > 1000).all()                                                        # the numpy body
    assert capsys.readouterr().err.count("warning: no OpenGL") == 1
