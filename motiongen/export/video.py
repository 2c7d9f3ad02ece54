"""Motion videos: a top-down map and a perspective camera, drawn with matplotlib (Agg) and,
for the camera's 3D content, OpenGL.

Left panel: the scene's obstacles seen from above (from the occupancy grid), the planned path,
subgoals and goals, the trajectory so far, and the skeleton, in a window that follows the
body. Right panel: a perspective camera (by default behind and above the body, heading
smoothed so the camera does not shake with every step) showing the scene (its mesh, or the
occupancy as boxes), a floor with a 1 m grid and the skinned body (`style="body"`: shaded,
with its shadow and the planted feet marked on the floor) or the stick figure
(`style="skeleton"`), depth-tested together by `gl_render`; path and goals drawn over it.
Without OpenGL the panel falls back to matplotlib boxes (painter's algorithm, faces between
the camera and the body see-through) and the body rasterised in numpy (`render_body`). The
figure and its frames: `video_frame`; the cameras: `camera`, `follow_camera`; the obstacles:
`obstacles`.

Speed: one figure is built once and only artists' data change per frame; blocks of frames are
drawn by forked worker processes on Linux (one per core, up to 4, each with its own OpenGL
context) and stream in order to the encoder. Every frame of the motion is rendered unless
`video_fps` asks for fewer. Written as mp4 through imageio-ffmpeg when it is available,
otherwise as a gif.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import sys
from pathlib import Path
from typing import Sequence

import imageio.v2 as imageio
import numpy as np

from motiongen.export import render_body as rb
from motiongen.export.video_frame import FrameDrawer
from motiongen.forked import FORK_OK, one_thread
from motiongen.skeleton import BODY_PARENTS

# Frames go to the workers in blocks of this many (BodyMeshes poses its meshes in chunks of
# the same size, so no chunk is posed by two processes).
FRAME_BLOCK = 64
_DRAW = None     # the frame function of the render in progress, inherited by forked workers
# A block of 64 frames takes a worker seconds (~3 s for the main job's on 2 cores); one that has
# answered nothing in this long is stuck, not slow.
BLOCK_TIMEOUT_S = 300.0


def ffmpeg_available() -> bool:
    try:
        import imageio_ffmpeg  # optional: without it videos are written as gifs

        return Path(imageio_ffmpeg.get_ffmpeg_exe()).exists()
    except Exception:  # not installed or no binary for this platform
        return False


def video_suffix() -> str:
    """'.mp4' when imageio-ffmpeg can write it, else '.gif'."""
    return ".mp4" if ffmpeg_available() else ".gif"


def render_video(path: str | Path, joints: np.ndarray, fps: float, parents: Sequence[int] = BODY_PARENTS,
                 grid=None, walkable=None, path_xz: np.ndarray | None = None, subgoals: np.ndarray | None = None,
                 goals: np.ndarray | None = None, video_fps: float | None = None, size: tuple[int, int] = (800, 352),
                 title: str = "", max_frames: int | None = None, *, bodies: Sequence | None = None,
                 body_model=None, planted: np.ndarray | None = None, contact_joints: Sequence[int] = (),
                 style: str = "body", workers: int | None = None, camera=None, scene_mesh=None,
                 gl: bool | None = None) -> Path:
    """Render joints (S, T, J, 3) (or (T, J, 3)) to `path` (.mp4, or .gif when ffmpeg is missing
    or the suffix asks for it). Sample 0 drives the cameras; others are drawn alongside.

    video_fps: None renders every frame at the motion's fps; a lower rate keeps every
    round(fps / video_fps)-th frame. max_frames: None, or a cap that lowers the rate further.
    style "body" draws `bodies` (one per sample: global_orient (T, 3), body_pose (T, 63),
    transl (T, 3), betas (nβ,) of `body_model`, posing exactly `joints`) as meshes, falling back
    to the skeleton when either is None; "skeleton" draws the stick figure.
    planted (S, T, C) bool: the foot joints `contact_joints` (C,) held on the floor, marked
    per frame. workers: processes drawing frames on Linux (None: up to 4, one per available
    core; 1: this process only; elsewhere always this process); the frames are the same
    whichever process draws them. camera: `camera.CameraPath` of the camera panel, one camera
    per motion frame (None: the follow camera). scene_mesh: the scene as a y-up trimesh in
    metres in the joints' world frame, shown by the camera panel (None: the occupancy of
    grid/walkable as boxes). gl: draw the camera panel with OpenGL (None: where an EGL context
    can be made, else the matplotlib and numpy fallback, which shows boxes only; False: the
    fallback). Returns the path actually written (the suffix may change to .gif)."""
    if style not in ("body", "skeleton"):
        raise ValueError(f"style: expected 'body' or 'skeleton', got {style!r}")
    path = Path(path)
    if path.suffix.lower() != ".gif" and not ffmpeg_available():
        path = path.with_suffix(".gif")
    joints = np.asarray(joints, np.float64)
    if joints.ndim == 3:
        joints = joints[None]
    S, T, J, _ = joints.shape
    frames_idx, out_fps = _frames_to_draw(T, fps, video_fps, max_frames)
    meshes = None
    if style == "body" and bodies is not None and body_model is not None:
        if len(bodies) != S or any(len(b.transl) != T for b in bodies):
            raise ValueError(f"bodies: expected {S} bodies of {T} frames (one per sample of joints)")
        meshes = rb.BodyMeshes(body_model, bodies, frames_idx, chunk=FRAME_BLOCK)
    contact_joints = [int(c) for c in contact_joints]
    anchors = _contact_anchors(joints, planted, contact_joints)                             # (S, T, C, 2)
    bones = [(j, p) for j, p in enumerate(list(parents)[:J]) if p >= 0]
    drawer = FrameDrawer(joints, fps, bones, size, title, walkable=walkable, grid=grid, path_xz=path_xz,
                         subgoals=subgoals, goals=goals, anchors=anchors, meshes=meshes, contact_joints=contact_joints,
                         camera=camera, scene_mesh=scene_mesh, gl=gl)
    writer = _open_writer(path, out_fps)
    try:
        for frame in _frame_stream(drawer.draw, frames_idx, workers):
            writer.append_data(frame)
    finally:
        writer.close()
        drawer.close()
    return path


def _frames_to_draw(T: int, fps: float, video_fps: float | None, max_frames: int | None) -> tuple[np.ndarray, float]:
    """The motion frames (N,) the video shows and its frame rate."""
    step = 1 if video_fps is None else max(1, int(round(fps / video_fps)))
    if max_frames is not None:
        step = max(step, int(math.ceil(T / max_frames)))
    return np.arange(0, T, step), fps / step


def _contact_anchors(joints: np.ndarray, planted: np.ndarray | None, contact_joints: list[int]) -> np.ndarray | None:
    """(S, T, C, 2) where each planted foot joint was put down (`render_body.contact_anchors`),
    or None without planted flags."""
    if planted is None or not len(contact_joints):
        return None
    S, T = joints.shape[:2]
    planted = np.asarray(planted, bool)
    if planted.shape != (S, T, len(contact_joints)):
        raise ValueError(f"planted: expected (S, T, C) = {(S, T, len(contact_joints))}, got {planted.shape}")
    return rb.contact_anchors(joints, planted, contact_joints)


def _draw_block(ts) -> list[np.ndarray]:
    return [_DRAW(int(t)) for t in ts]


def _frame_stream(draw, frames_idx: np.ndarray, workers: int | None):
    """draw(t) for every t of frames_idx, in order. Matplotlib draws one frame on one core, so
    on Linux frames are drawn by forked worker processes (each inherits the figure); what they
    do not draw (one process, or workers that answer nothing for BLOCK_TIMEOUT_S) is drawn here."""
    if workers is None:
        workers = min(4, len(os.sched_getaffinity(0))) if FORK_OK else 1
    blocks = [frames_idx[i:i + FRAME_BLOCK] for i in range(0, len(frames_idx), FRAME_BLOCK)]
    drawn = 0                                  # blocks the workers drew
    if workers >= 2 and len(blocks) >= 2 and FORK_OK:
        drawn = yield from _drawn_by_workers(draw, blocks, workers)
    for t in frames_idx[drawn * FRAME_BLOCK:]:
        yield draw(int(t))


def _drawn_by_workers(draw, blocks: list[np.ndarray], workers: int):
    """Yields the frames of `blocks` drawn by forked workers, in order; returns how many blocks
    came back, all of them unless the workers stopped answering."""
    global _DRAW
    _DRAW = draw
    try:
        with mp.get_context("fork").Pool(min(workers, len(blocks)), initializer=one_thread) as pool:   # meshes posed with torch
            results = pool.imap(_draw_block, blocks)
            for done in range(len(blocks)):
                try:
                    frames = results.next(timeout=BLOCK_TIMEOUT_S)
                except mp.TimeoutError:
                    # A worker that never answers (a driver waiting for a thread the fork did not
                    # copy) must not hang the run: the rest is drawn here, slower but drawn.
                    left = sum(len(b) for b in blocks[done:])
                    print(f"warning: the video's worker processes drew no frames for {BLOCK_TIMEOUT_S:g} s; "
                          f"drawing the remaining {left} frames in this process", file=sys.stderr)
                    return done
                yield from frames
        return len(blocks)
    finally:
        _DRAW = None


def _open_writer(path: Path, fps: float):
    """A streaming frame writer: frames go to the encoder as they are drawn, never all in memory."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        # Frame duration in milliseconds for this writer (seconds gave 0 ms: frames as fast as possible).
        return imageio.get_writer(path, format="GIF", mode="I", duration=1000.0 / fps, loop=0)
    # veryfast: far less encoder CPU time than the default preset for a slightly larger file.
    return imageio.get_writer(path, format="FFMPEG", fps=fps, codec="libx264", quality=6, macro_block_size=16,
                              ffmpeg_log_level="error", output_params=["-preset", "veryfast"])
