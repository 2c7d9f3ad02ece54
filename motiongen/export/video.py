"""Motion videos: a top-down map and a follow camera, rendered with matplotlib (Agg).

Left panel: the scene's obstacles seen from above (from the occupancy grid), the planned path,
subgoals and goals, the trajectory so far, and the skeleton, in a window that follows the
body. Right panel: a perspective camera behind and above the body (heading smoothed so the
camera does not shake with every step), with a floor grid, obstacles as shaded boxes (faces
between the camera and the body drawn see-through) and the goals; the body itself is the
skinned mesh (`style="body"`, drawn by `render_body`: shaded, with its shadow and the planted
feet marked on the floor) or the stick figure (`style="skeleton"`).

Speed: one figure is built once and only artists' data change per frame; the mesh is
rasterised in numpy and composited onto the drawn frame; blocks of frames are drawn by forked
worker processes on Linux (one per core, up to 4) and stream in order to the encoder. Every
frame of the motion is rendered unless `video_fps` asks for fewer. Written as mp4 through
imageio-ffmpeg when it is available, otherwise as a gif.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from motiongen.skeleton import BODY_PARENTS, LEFT_HIP, NUM_BODY_JOINTS, PELVIS, RIGHT_HIP

CAM_VIEW = (1.0, 0.8)      # the camera panel shows image-plane x in ±1.0, y in ±0.8 (focal 1.6)
SAMPLE_COLOURS = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")


def ffmpeg_available() -> bool:
    try:
        import imageio_ffmpeg

        return Path(imageio_ffmpeg.get_ffmpeg_exe()).exists()
    except Exception:  # not installed or no binary for this platform
        return False


def video_suffix() -> str:
    """'.mp4' when imageio-ffmpeg can write it, else '.gif'."""
    return ".mp4" if ffmpeg_available() else ".gif"


def obstacle_columns(walkable=None, grid=None, cell: float = 0.1) -> np.ndarray:
    """(N, 3) obstacle columns (x, z, top height) on a `cell`-metre lattice, from an
    OccupancyGrid (`grid`) or, lacking it, a WalkableMap's blocked cells (height 1 m)."""
    if grid is not None:
        dense = np.asarray(grid.dense())                                                     # (X, Y, Z)
        f = max(1, int(round(cell / grid.voxel_size)))
        X, Y, Z = dense.shape
        Xc, Zc = X // f, Z // f
        if Xc == 0 or Zc == 0:
            return np.zeros((0, 3))
        ys = grid.origin[1] + (np.arange(Y) + 1) * grid.voxel_size                          # (Y,) voxel tops
        occ = dense[:Xc * f, :, :Zc * f].reshape(Xc, f, Y, Zc, f).any(axis=(1, 4))          # (Xc, Y, Zc)
        occ[:, ys <= 0.02, :] = False                                                       # ignore a floor slab
        top = np.where(occ.any(1), ys[np.argmax(np.where(occ, np.arange(Y)[None, :, None], -1), axis=1)], 0.0)
        i, k = np.nonzero(occ.any(1))
        x = grid.origin[0] + (i + 0.5) * f * grid.voxel_size
        z = grid.origin[2] + (k + 0.5) * f * grid.voxel_size
        return np.stack([x, z, top[i, k]], -1)
    if walkable is not None:
        f = max(1, int(round(cell / walkable.cell)))
        X, Z = walkable.open.shape
        blocked = ~walkable.open[: X // f * f, : Z // f * f].reshape(X // f, f, Z // f, f).all(axis=(1, 3))
        i, k = np.nonzero(blocked)
        return np.stack([walkable.origin[0] + (i + 0.5) * f * walkable.cell,
                         walkable.origin[1] + (k + 0.5) * f * walkable.cell, np.ones(len(i))], -1)
    return np.zeros((0, 3))


def obstacle_faces(columns: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Box faces of obstacle columns (N, 3) (x, z, top) on a `cell` lattice: the top of every
    column and the sides not hidden by an equally tall neighbour.
    Returns corners (F, 4, 3), outward normals (F, 3) and a brightness (F,) for flat shading."""
    if not len(columns):
        return np.zeros((0, 4, 3)), np.zeros((0, 3)), np.zeros(0)
    h = cell / 2
    key = {(round(x / cell), round(z / cell)): top for x, z, top in columns}
    corners, normals, shade = [], [], []
    for x, z, top in columns:
        corners.append([[x - h, top, z - h], [x + h, top, z - h], [x + h, top, z + h], [x - h, top, z + h]])
        normals.append([0.0, 1.0, 0.0])
        shade.append(1.0)
        i, k = round(x / cell), round(z / cell)
        for (di, dk), quad, lum in (((1, 0), [[x + h, 0, z - h], [x + h, 0, z + h], [x + h, top, z + h], [x + h, top, z - h]], 0.72),
                                    ((-1, 0), [[x - h, 0, z - h], [x - h, 0, z + h], [x - h, top, z + h], [x - h, top, z - h]], 0.72),
                                    ((0, 1), [[x - h, 0, z + h], [x + h, 0, z + h], [x + h, top, z + h], [x - h, top, z + h]], 0.85),
                                    ((0, -1), [[x - h, 0, z - h], [x + h, 0, z - h], [x + h, top, z - h], [x - h, top, z - h]], 0.85)):
            if key.get((i + di, k + dk), 0.0) < top:                       # exposed side
                corners.append(quad)
                normals.append([di, 0.0, dk])
                shade.append(lum)
    return np.asarray(corners, np.float64), np.asarray(normals, np.float64), np.asarray(shade)


def _heading(joints: np.ndarray, fps: float, tau: float = 0.8) -> np.ndarray:
    """(T,) camera yaw: the body's facing from the hips, exponentially smoothed (time constant
    tau seconds) on the unit circle so the camera turns calmly."""
    across = joints[:, LEFT_HIP] - joints[:, RIGHT_HIP]                                      # (T, 3)
    f = np.stack([-across[:, 2], across[:, 0]], -1)                                          # forward (x, z)
    f /= np.maximum(np.linalg.norm(f, axis=-1, keepdims=True), 1e-9)
    a = 1 - math.exp(-1.0 / (fps * tau))
    out = np.empty_like(f)
    out[0] = f[0]
    for t in range(1, len(f)):
        v = out[t - 1] + a * (f[t] - out[t - 1])
        out[t] = v / max(np.linalg.norm(v), 1e-9)
    return np.arctan2(out[:, 0], out[:, 1])


class _Camera:
    """Pinhole camera behind the body looking at the pelvis: world (N, 3) -> image (N, 2), depth."""

    def __init__(self, target: np.ndarray, yaw: float, dist: float = 3.2, height: float = 1.9, focal: float = 1.6):
        fwd = np.array([math.sin(yaw), 0.0, math.cos(yaw)])
        self.eye = target + np.array([0.0, height - target[1], 0.0]) - dist * fwd
        look = target + np.array([0.0, 0.9 - target[1], 0.0]) - self.eye
        z = look / np.linalg.norm(look)
        x = np.cross(np.array([0.0, 1.0, 0.0]), z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        self.R = np.stack([-x, y, z])          # image x to the right: world-left is body +x
        self.focal = focal

    def project(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = (p - self.eye) @ self.R.T                                                        # (N, 3)
        d = c[:, 2]
        uv = self.focal * c[:, :2] / np.maximum(d, 1e-3)[:, None]
        return uv, d


def _visible_faces(cam: "_Camera", body: np.ndarray, faces: np.ndarray, normals: np.ndarray, rgb: np.ndarray,
                   radius: float = 7.0, view: tuple[float, float] = CAM_VIEW) -> tuple[list, np.ndarray]:
    """Projected faces near the camera that face it, far to near (painter's algorithm), with
    faces between the camera and the body see-through so furniture never hides the person."""
    if not len(faces):
        return [], np.zeros((0, 4))
    centre = faces.mean(1)                                                                   # (F, 3)
    near = np.linalg.norm(centre - body, axis=-1) < radius
    facing = ((cam.eye - centre) * normals).sum(-1) > 0
    idx = np.nonzero(near & facing)[0]
    uv, d = cam.project(faces[idx].reshape(-1, 3))
    uv, d = uv.reshape(-1, 4, 2), d.reshape(-1, 4)
    ok = (d > 0.2).all(1) & (np.abs(uv) < 6).all(axis=(1, 2))
    # Faces wholly outside the panel's view cost matplotlib path building for nothing.
    ok &= (uv[..., 0].max(1) > -view[0]) & (uv[..., 0].min(1) < view[0]) & \
          (uv[..., 1].max(1) > -view[1]) & (uv[..., 1].min(1) < view[1])
    uv, d, idx = uv[ok], d[ok], idx[ok]
    order = np.argsort(-d.mean(1))
    body_depth = float(cam.project(body[None])[1][0])
    alpha = np.where(d.mean(1) < body_depth - 0.3, 0.25, 1.0)                                # (M,)
    colours = np.concatenate([rgb[idx], alpha[:, None]], -1)[order]                          # (M, 4)
    return list(uv[order]), colours


def render_video(path: str | Path, joints: np.ndarray, fps: float, parents: Sequence[int] = BODY_PARENTS,
                 grid=None, walkable=None, path_xz: np.ndarray | None = None, subgoals: np.ndarray | None = None,
                 goals: np.ndarray | None = None, video_fps: float | None = None, size: tuple[int, int] = (800, 352),
                 title: str = "", max_frames: int | None = None, *, bodies: Sequence | None = None,
                 body_model=None, planted: np.ndarray | None = None, contact_joints: Sequence[int] = (),
                 style: str = "body", workers: int | None = None) -> Path:
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
    whichever process draws them. Returns the path actually written (the suffix may change to
    .gif)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.figure import Figure

    from motiongen.export import render_body as rb

    if style not in ("body", "skeleton"):
        raise ValueError(f"style: expected 'body' or 'skeleton', got {style!r}")
    path = Path(path)
    if path.suffix.lower() != ".gif" and not ffmpeg_available():
        path = path.with_suffix(".gif")
    joints = np.asarray(joints, np.float64)
    if joints.ndim == 3:
        joints = joints[None]
    S, T, J, _ = joints.shape
    step = 1 if video_fps is None else max(1, int(round(fps / video_fps)))
    if max_frames is not None:
        step = max(step, int(math.ceil(T / max_frames)))
    frames_idx = np.arange(0, T, step)
    out_fps = fps / step
    parents = list(parents)[:J]
    bones = [(j, p) for j, p in enumerate(parents) if p >= 0]
    meshes = None
    if style == "body" and bodies is not None and body_model is not None:
        if len(bodies) != S or any(len(b.transl) != T for b in bodies):
            raise ValueError(f"bodies: expected {S} bodies of {T} frames (one per sample of joints)")
        meshes = rb.BodyMeshes(body_model, bodies, frames_idx, chunk=FRAME_BLOCK)
    contact_joints = [int(c) for c in contact_joints]
    anchors = None
    if planted is not None and len(contact_joints):
        planted = np.asarray(planted, bool)
        if planted.shape != (S, T, len(contact_joints)):
            raise ValueError(f"planted: expected (S, T, C) = {(S, T, len(contact_joints))}, got {planted.shape}")
        anchors = rb.contact_anchors(joints, planted, contact_joints)                   # (S, T, C, 2)

    W, H = size
    dpi = 80
    fig = Figure(figsize=(W / dpi, H / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    ax_top = fig.add_axes([0.01, 0.02, 0.42, 0.9])
    ax_cam = fig.add_axes([0.45, 0.02, 0.54, 0.9])
    if title:
        fig.text(0.01, 0.95, title, fontsize=9)
    time_text = fig.text(0.99, 0.95, "", fontsize=9, ha="right")
    contact_hex = matplotlib.colors.to_hex(rb.CONTACT_RGB)

    # -- top-down panel: static layers once --------------------------------------------
    if walkable is not None:
        (x0, z0), (x1, z1) = walkable.bounds
        img = np.where(walkable.open, 1.0, 0.25)
        img = np.where(walkable.open & ~walkable.free, 0.85, img)
        ax_top.imshow(img.T, origin="lower", extent=(x0, x1, z0, z1), cmap="gray", vmin=0, vmax=1,
                      interpolation="nearest")
    if path_xz is not None and len(path_xz):
        ax_top.plot(path_xz[:, 0], path_xz[:, 1], "--", color="#777777", lw=1)
    if subgoals is not None and len(subgoals):
        ax_top.plot(subgoals[:, 0], subgoals[:, 1], ".", color="#777777", ms=3)
    if goals is not None and len(goals):
        ax_top.plot(goals[:, 0], goals[:, 1], "*", color="#ffbf00", ms=12, mec="k", mew=0.5)
    ax_top.set_aspect("equal")
    ax_top.invert_yaxis()            # seen from above (+y): x right, z down
    ax_top.set_xticks([])
    ax_top.set_yticks([])
    trails = [ax_top.plot([], [], "-", color=SAMPLE_COLOURS[s % 8], lw=1, alpha=0.7)[0] for s in range(S)]
    top_bones = [LineCollection([], colors=SAMPLE_COLOURS[s % 8], linewidths=1.5) for s in range(S)]
    for lc in top_bones:
        ax_top.add_collection(lc)
    top_feet = ax_top.plot([], [], "o", color=contact_hex, ms=4, mec="k", mew=0.4, zorder=4)[0]

    # -- camera panel ------------------------------------------------------------------
    columns = obstacle_columns(walkable, grid, cell=0.2)                                             # (N, 3)
    pel = joints[0, :, PELVIS]                                                               # (T, 3)
    lo = np.minimum(pel[:, [0, 2]].min(0), goals.min(0) if goals is not None and len(goals) else np.inf) - 4
    hi = np.maximum(pel[:, [0, 2]].max(0), goals.max(0) if goals is not None and len(goals) else -np.inf) + 4
    gx = np.arange(math.floor(lo[0]), math.ceil(hi[0]) + 1, 1.0)
    gz = np.arange(math.floor(lo[1]), math.ceil(hi[1]) + 1, 1.0)
    grid_segs = [np.array([[x, 0, z0_], [x, 0, z1_]]) for x in gx for z0_, z1_ in zip(gz[:-1], gz[1:])] + \
                [np.array([[x0_, 0, z], [x1_, 0, z]]) for z in gz for x0_, x1_ in zip(gx[:-1], gx[1:])]
    grid_segs = np.stack(grid_segs) if grid_segs else np.zeros((0, 2, 3))                   # (N, 2, 3)
    faces, normals, shade = obstacle_faces(columns, 0.2)                                     # (F, 4, 3), (F, 3), (F,)
    face_rgb = np.array([0.55, 0.60, 0.68])[None] * shade[:, None]                           # (F, 3) flat shading
    cam_floor = LineCollection([], colors="#bbbbbb", linewidths=0.6, zorder=1)
    cam_faces = PolyCollection([], edgecolors="#56606e", linewidths=0.3, zorder=2)
    ax_cam.add_collection(cam_floor)
    ax_cam.add_collection(cam_faces)
    cam_path = ax_cam.plot([], [], "--", color="#777777", lw=1, zorder=3)[0]
    cam_goals = ax_cam.plot([], [], "*", color="#ffbf00", ms=12, mec="k", mew=0.5, zorder=3)[0]
    # Skeleton style: planted-foot discs as polygons under the bones (body style rasterises them).
    cam_discs = PolyCollection([], facecolors=contact_hex, edgecolors="none", zorder=3.5)
    ax_cam.add_collection(cam_discs)
    cam_bones = [LineCollection([], colors=SAMPLE_COLOURS[s % 8], linewidths=2.5, zorder=4) for s in range(S)]
    if meshes is None:
        for lc in cam_bones:
            ax_cam.add_collection(lc)
    ax_cam.set_xlim(-CAM_VIEW[0], CAM_VIEW[0])
    ax_cam.set_ylim(-CAM_VIEW[1], CAM_VIEW[1])
    ax_cam.set_aspect("equal")
    ax_cam.set_xticks([])
    ax_cam.set_yticks([])
    ax_cam.set_facecolor("#f4f1ea")

    heading = _heading(joints[0], fps)
    path3 = None if path_xz is None else np.stack([path_xz[:, 0], np.zeros(len(path_xz)), path_xz[:, 1]], -1)
    goals3 = None if goals is None or not len(goals) else np.stack([goals[:, 0], np.zeros(len(goals)), goals[:, 1]], -1)
    bone_idx = np.array(bones)                                                               # (B, 2)
    layer = None
    if meshes is not None:
        rgb = np.array([matplotlib.colors.to_rgb(SAMPLE_COLOURS[s % 8]) for s in range(S)])
        # Contact joints past the body joints (e.g. fingers) have no mesh part to tint.
        layer = rb.BodyLayer(meshes, rgb, anchors, [c if c < NUM_BODY_JOINTS else -1 for c in contact_joints])

    def proj_segments(cam, segs):                                                           # (N, 2, 3) -> (M, 2, 2)
        if not len(segs):
            return np.zeros((0, 2, 2))
        uv, d = cam.project(segs.reshape(-1, 3))
        uv, d = uv.reshape(-1, 2, 2), d.reshape(-1, 2)
        ok = (d > 0.2).all(1) & (np.abs(uv) < 4).all(axis=(1, 2))
        return uv[ok]

    def draw(t: int) -> np.ndarray:                                                     # frame t (H, W, 3) uint8
        # Every artist that changes is set here from t alone: any process can draw any frame.
        p = joints[0, t, PELVIS]
        half = 2.5
        ax_top.set_xlim(p[0] - half, p[0] + half)
        ax_top.set_ylim(p[2] + half * 0.95, p[2] - half * 0.95)
        for s in range(S):
            trails[s].set_data(joints[s, : t + 1, PELVIS, 0], joints[s, : t + 1, PELVIS, 2])
            top_bones[s].set_segments(joints[s, t][bone_idx][..., [0, 2]])                # (B, 2, 2)
        cam = _Camera(p, heading[t])
        cam_floor.set_segments(proj_segments(cam, grid_segs))
        verts, colours = _visible_faces(cam, p, faces, normals, face_rgb)
        cam_faces.set_verts(verts)
        cam_faces.set_facecolor(colours)
        if path3 is not None:
            uv, d = cam.project(path3)
            uv = np.where((d > 0.2)[:, None], uv, np.nan)
            cam_path.set_data(uv[:, 0], uv[:, 1])
        if goals3 is not None:
            uv, d = cam.project(goals3)
            uv = uv[d > 0.2]
            cam_goals.set_data(uv[:, 0], uv[:, 1])
        if anchors is not None:
            a = anchors[:, t].reshape(-1, 2)
            a = a[~np.isnan(a[:, 0])]                                                    # (N, 2) planted
            top_feet.set_data(a[:, 0], a[:, 1])
            if layer is None:
                uv, d = cam.project(rb.disc_triangles(a, n=16)[:, 1].reshape(-1, 3))     # rim points
                cam_discs.set_verts(list(uv.reshape(-1, 16, 2)) if (d > 0.2).all() else [])
        if layer is None:
            for s in range(S):
                uv, d = cam.project(joints[s, t])
                cam_bones[s].set_segments(uv[bone_idx][(d[bone_idx] > 0.2).all(1)])
        time_text.set_text(f"{t / fps:5.1f} s")
        fig.canvas.draw()
        frame = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()                     # (H, W, 3)
        if layer is not None:
            layer.draw(frame, cam, *_panel_pixels(ax_cam, frame.shape[0]), t)
        return frame

    writer = _open_writer(path, out_fps)
    try:
        for frame in _frame_stream(draw, frames_idx, workers):
            writer.append_data(frame)
    finally:
        writer.close()
    return path


# Frames go to the workers in blocks of this many (BodyMeshes poses its meshes in chunks of
# the same size, so no chunk is posed by two processes).
FRAME_BLOCK = 64
_DRAW = None     # the frame function of the render in progress, inherited by forked workers


def _one_thread() -> None:
    import torch

    torch.set_num_threads(1)       # the body meshes are posed with torch; one thread per worker


def _draw_block(ts) -> list[np.ndarray]:
    return [_DRAW(int(t)) for t in ts]


def _frame_stream(draw, frames_idx: np.ndarray, workers: int | None):
    """draw(t) for every t of frames_idx, in order. Matplotlib draws one frame on one core, so
    on Linux frames are drawn by forked worker processes (each inherits the figure)."""
    import multiprocessing as mp
    import os
    import sys

    global _DRAW
    # fork only on Linux: macOS offers it, but system frameworks may crash in a forked child.
    linux = sys.platform.startswith("linux")
    if workers is None:
        workers = min(4, len(os.sched_getaffinity(0))) if linux else 1
    blocks = [frames_idx[i:i + FRAME_BLOCK] for i in range(0, len(frames_idx), FRAME_BLOCK)]
    if workers < 2 or len(blocks) < 2 or not linux:
        for t in frames_idx:
            yield draw(int(t))
        return
    _DRAW = draw
    try:
        with mp.get_context("fork").Pool(min(workers, len(blocks)), initializer=_one_thread) as pool:
            for frames in pool.imap(_draw_block, blocks):
                yield from frames
    finally:
        _DRAW = None


def _panel_pixels(ax, height: int):
    """The axes' data -> frame pixel map (x right, y down) and its box (r0, r1, c0, c1) in the
    frame, as drawn (after aspect adjustment)."""
    M = ax.transData.get_affine().get_matrix()                                              # (3, 3) display = M @ data

    def to_px(uv):                                                                           # (N, 2) -> (N, 2)
        return np.stack([M[0, 0] * uv[:, 0] + M[0, 2], height - (M[1, 1] * uv[:, 1] + M[1, 2])], -1)

    x0, y0, x1, y1 = ax.bbox.extents
    box = (int(math.ceil(height - y1)), int(math.floor(height - y0)), int(math.ceil(x0)), int(math.floor(x1)))
    return to_px, box


def _open_writer(path: Path, fps: float):
    """A streaming frame writer: frames go to the encoder as they are drawn, never all in memory."""
    import imageio.v2 as imageio

    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        # Frame duration in milliseconds for this writer (seconds gave 0 ms: frames as fast as possible).
        return imageio.get_writer(path, format="GIF", mode="I", duration=1000.0 / fps, loop=0)
    # veryfast: half the encoder's CPU time of the default preset for a 3 % larger file (measured).
    return imageio.get_writer(path, format="FFMPEG", fps=fps, codec="libx264", quality=6, macro_block_size=16,
                              ffmpeg_log_level="error", output_params=["-preset", "veryfast"])
