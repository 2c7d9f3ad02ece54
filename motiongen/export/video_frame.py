"""The video's figure and how one frame of it is drawn (`FrameDrawer`).

Left panel: the scene's obstacles seen from above, the planned path, subgoals and goals, the
trajectory so far and the skeleton, in a window that follows the body. Right panel: the camera
(`camera.CameraPath`, by default `follow_camera`). Where OpenGL is available (`gl_render`) it
shows the scene (its mesh, or the occupancy as boxes), the floor with a 1 m grid, the skinned
bodies, their shadow and the planted-foot discs, depth-tested together, as an image under
matplotlib's path and goals (and the stick figure's bones). Without it: a floor grid, obstacles
as shaded boxes (painter's algorithm) and the body rasterised in numpy
(`render_body.BodyLayer`, composited onto the drawn frame). The figure is built once; per frame
only the artists' data change.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from motiongen.export import gl_render
from motiongen.export import render_body as rb
from motiongen.export.camera import CAM_VIEW, CameraPath, PinholeCamera
from motiongen.export.follow_camera import follow_path, project_segments, visible_faces
from motiongen.export.obstacles import obstacle_columns, obstacle_faces, quad_triangles
from motiongen.skeleton import NUM_BODY_JOINTS, PELVIS

SAMPLE_COLOURS = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")


def _matplotlib() -> SimpleNamespace:
    """matplotlib's Agg figure pieces."""
    # Imported here, when a video is drawn: matplotlib is heavy, and choosing its backend on
    # import would change it for every program that imports motiongen.
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # heavy, as above
    from matplotlib.collections import LineCollection, PolyCollection  # heavy, as above
    from matplotlib.figure import Figure  # heavy, as above

    return SimpleNamespace(colors=matplotlib.colors, FigureCanvasAgg=FigureCanvasAgg, Figure=Figure,
                           LineCollection=LineCollection, PolyCollection=PolyCollection)


class FrameDrawer:
    """The two-panel figure for joints (S, T, J, 3) at `fps`; `draw(t)` returns frame t.

    bones: (child, parent) joint pairs. anchors (S, T, C, 2) or None: where planted feet were
    put down (NaN when not planted). meshes: `render_body.BodyMeshes` of the samples, or None
    for the stick figure; contact_joints (C,): the joints of `anchors`' columns. camera: the
    camera panel's camera per frame (None: `follow_camera.follow_path` of sample 0).
    scene_mesh: the scene as a y-up trimesh in metres (None: the occupancy of grid/walkable as
    boxes); gl: draw the camera panel with OpenGL (None: where available; False: matplotlib
    and numpy, which never show the mesh itself). `close()` frees the OpenGL context."""

    def __init__(self, joints: np.ndarray, fps: float, bones: list[tuple[int, int]], size: tuple[int, int],
                 title: str = "", *, walkable=None, grid=None, path_xz: np.ndarray | None = None,
                 subgoals: np.ndarray | None = None, goals: np.ndarray | None = None,
                 anchors: np.ndarray | None = None, meshes=None, contact_joints: list[int] = (),
                 camera: CameraPath | None = None, scene_mesh=None, gl: bool | None = None):
        mpl = _matplotlib()
        self.joints, self.fps, self.anchors = joints, fps, anchors
        S = joints.shape[0]
        W, H = size
        dpi = 80
        self.fig = mpl.Figure(figsize=(W / dpi, H / dpi), dpi=dpi)
        mpl.FigureCanvasAgg(self.fig)
        self.ax_top = self.fig.add_axes([0.01, 0.02, 0.42, 0.9])
        self.ax_cam = self.fig.add_axes([0.45, 0.02, 0.54, 0.9])
        if title:
            self.fig.text(0.01, 0.95, title, fontsize=9)
        self.time_text = self.fig.text(0.99, 0.95, "", fontsize=9, ha="right")
        contact_hex = mpl.colors.to_hex(rb.CONTACT_RGB)
        self._top_panel(mpl, S, walkable, path_xz, subgoals, goals, contact_hex)
        columns = obstacle_columns(walkable, grid, cell=0.2)                                  # (N, 3)
        self.grid_segs = _floor_grid(joints[0, :, PELVIS], goals)                            # (N, 2, 3)
        self.faces, self.normals, shade = obstacle_faces(columns, 0.2)                       # (F, 4, 3), (F, 3), (F,)
        self.face_rgb = np.array(gl_render.SCENE_RGB)[None] * shade[:, None]                 # (F, 3) flat shading
        use_gl = gl_render.available() if gl is None else gl
        self._camera_panel(mpl, S, contact_hex, bones_drawn=meshes is None, gl=use_gl)
        if self.gl is not None:
            tri = quad_triangles(self.faces) if scene_mesh is None else np.asarray(scene_mesh.triangles)
            self.gl.set_scene(tri)                                                           # (F, 3, 3)
            bounds = None if scene_mesh is None else np.asarray(scene_mesh.bounds)           # (2, 3)
            self.gl.set_floor(*_floor_bounds(joints[0, :, PELVIS], goals, bounds))
        self.camera = follow_path(joints[0], fps) if camera is None else camera
        self.path3 = None if path_xz is None else np.stack([path_xz[:, 0], np.zeros(len(path_xz)), path_xz[:, 1]], -1)
        self.goals3 = None if goals is None or not len(goals) else \
            np.stack([goals[:, 0], np.zeros(len(goals)), goals[:, 1]], -1)
        self.bone_idx = np.array(bones)                                                      # (B, 2)
        self.layer = None
        if meshes is not None:
            rgb = np.array([mpl.colors.to_rgb(SAMPLE_COLOURS[s % 8]) for s in range(S)])
            # Contact joints past the body joints (e.g. fingers) have no mesh part to tint.
            self.layer = rb.BodyLayer(meshes, rgb, anchors, [c if c < NUM_BODY_JOINTS else -1 for c in contact_joints])

    def _top_panel(self, mpl: SimpleNamespace, S: int, walkable, path_xz, subgoals, goals, contact_hex: str) -> None:
        """The top-down map: the walkable map, path, subgoals and goals drawn once; per sample a
        trail and a skeleton, and the planted feet, whose data `draw` sets."""
        ax = self.ax_top
        if walkable is not None:
            (x0, z0), (x1, z1) = walkable.bounds
            img = np.where(walkable.open, 1.0, 0.25)
            img = np.where(walkable.open & ~walkable.free, 0.85, img)
            ax.imshow(img.T, origin="lower", extent=(x0, x1, z0, z1), cmap="gray", vmin=0, vmax=1,
                      interpolation="nearest")
        if path_xz is not None and len(path_xz):
            ax.plot(path_xz[:, 0], path_xz[:, 1], "--", color="#777777", lw=1)
        if subgoals is not None and len(subgoals):
            ax.plot(subgoals[:, 0], subgoals[:, 1], ".", color="#777777", ms=3)
        if goals is not None and len(goals):
            ax.plot(goals[:, 0], goals[:, 1], "*", color="#ffbf00", ms=12, mec="k", mew=0.5)
        ax.set_aspect("equal")
        ax.invert_yaxis()            # seen from above (+y): x right, z down
        ax.set_xticks([])
        ax.set_yticks([])
        self.trails = [ax.plot([], [], "-", color=SAMPLE_COLOURS[s % 8], lw=1, alpha=0.7)[0] for s in range(S)]
        self.top_bones = [mpl.LineCollection([], colors=SAMPLE_COLOURS[s % 8], linewidths=1.5) for s in range(S)]
        for lc in self.top_bones:
            ax.add_collection(lc)
        self.top_feet = ax.plot([], [], "o", color=contact_hex, ms=4, mec="k", mew=0.4, zorder=4)[0]

    def _camera_panel(self, mpl: SimpleNamespace, S: int, contact_hex: str, bones_drawn: bool, gl: bool) -> None:
        """The camera panel's artists (the OpenGL image, or the floor and obstacle faces; path,
        goals, planted-foot discs and, for the stick figure, the bones), empty until `draw`
        sets their data."""
        ax = self.ax_cam
        self.cam_floor = mpl.LineCollection([], colors="#bbbbbb", linewidths=0.6, zorder=1)
        self.cam_faces = mpl.PolyCollection([], edgecolors="#56606e", linewidths=0.3, zorder=2)
        if not gl:
            ax.add_collection(self.cam_floor)
            ax.add_collection(self.cam_faces)
        self.cam_path = ax.plot([], [], "--", color="#777777", lw=1, zorder=3)[0]
        self.cam_goals = ax.plot([], [], "*", color="#ffbf00", ms=12, mec="k", mew=0.5, zorder=3)[0]
        # Skeleton style: planted-foot discs as polygons under the bones (body style rasterises them).
        self.cam_discs = mpl.PolyCollection([], facecolors=contact_hex, edgecolors="none", zorder=3.5)
        ax.add_collection(self.cam_discs)
        self.cam_bones = [mpl.LineCollection([], colors=SAMPLE_COLOURS[s % 8], linewidths=2.5, zorder=4)
                          for s in range(S)]
        if bones_drawn:
            for lc in self.cam_bones:
                ax.add_collection(lc)
        ax.set_xlim(-CAM_VIEW[0], CAM_VIEW[0])
        ax.set_ylim(-CAM_VIEW[1], CAM_VIEW[1])
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_facecolor("#f4f1ea")
        self.gl, self.gl_box, self.overlays = None, None, []
        if gl:
            self._gl_setup(ax, bones_drawn)

    def _gl_setup(self, ax, bones_drawn: bool) -> None:
        """The OpenGL renderer of the frame pixels inside the panel (box r0, r1, c0, c1), its
        image plane extent exactly theirs, so its image goes into the frame 1:1 and cam.project
        lines up with it. Path, goals and bones become overlays that `draw` puts on top of it
        (animated: the figure's draw leaves them out)."""
        H = int(round(self.fig.get_figheight() * self.fig.dpi))
        ax.apply_aspect()                          # the panel's box as drawn (equal aspect)
        _, self.gl_box = _panel_pixels(ax, H)
        r0, r1, c0, c1 = self.gl_box
        M = ax.transData.get_affine().get_matrix()                                          # (3, 3)
        u = (np.array([c0, c1]) - M[0, 2]) / M[0, 0]
        v = (H - np.array([r1, r0]) - M[1, 2]) / M[1, 1]
        self.gl = gl_render.PanelRenderer((c1 - c0, r1 - r0), (u[0], u[1], v[0], v[1]))
        self.overlays = [self.cam_path, self.cam_goals] + (self.cam_bones if bones_drawn else [])
        for a in self.overlays:
            a.set_animated(True)

    def close(self) -> None:
        """Frees this process's OpenGL context, if any."""
        if self.gl is not None:
            self.gl.release()

    def draw(self, t: int) -> np.ndarray:
        """Frame t (H, W, 3) uint8."""
        # Every artist that changes is set here from t alone: any process can draw any frame.
        p = self.joints[0, t, PELVIS]
        self._draw_top(t, p)
        cam = self.camera.at(t)
        self._draw_camera(t, p, cam)
        self.time_text.set_text(f"{t / self.fps:5.1f} s")
        self.fig.canvas.draw()
        if self.gl is not None:
            # The panel's image written into the canvas, then the overlays drawn on it (blitting).
            r0, r1, c0, c1 = self.gl_box
            np.asarray(self.fig.canvas.buffer_rgba())[r0:r1, c0:c1, :3] = self._gl_panel(t, cam)
            for a in self.overlays:
                self.ax_cam.draw_artist(a)
        frame = np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()                # (H, W, 3)
        if self.layer is not None and self.gl is None:
            self.layer.draw(frame, cam, *_panel_pixels(self.ax_cam, frame.shape[0]), t)
        return frame

    def _draw_top(self, t: int, p: np.ndarray) -> None:
        """The map's window around the pelvis p (3,), trails up to t and skeletons at t."""
        half = 2.5
        self.ax_top.set_xlim(p[0] - half, p[0] + half)
        self.ax_top.set_ylim(p[2] + half * 0.95, p[2] - half * 0.95)
        for s in range(self.joints.shape[0]):
            self.trails[s].set_data(self.joints[s, : t + 1, PELVIS, 0], self.joints[s, : t + 1, PELVIS, 2])
            self.top_bones[s].set_segments(self.joints[s, t][self.bone_idx][..., [0, 2]])  # (B, 2, 2)

    def _draw_camera(self, t: int, p: np.ndarray, cam: PinholeCamera) -> None:
        """The camera panel at frame t: floor, obstacles, path, goals, planted feet and bones."""
        if self.gl is None:
            self.cam_floor.set_segments(project_segments(cam, self.grid_segs))
            verts, colours = visible_faces(cam, p, self.faces, self.normals, self.face_rgb)
            self.cam_faces.set_verts(verts)
            self.cam_faces.set_facecolor(colours)
        if self.path3 is not None:
            uv, d = cam.project(self.path3)
            uv = np.where((d > 0.2)[:, None], uv, np.nan)
            self.cam_path.set_data(uv[:, 0], uv[:, 1])
        if self.goals3 is not None:
            uv, d = cam.project(self.goals3)
            uv = uv[d > 0.2]
            self.cam_goals.set_data(uv[:, 0], uv[:, 1])
        if self.anchors is not None:
            a = rb.planted_points(self.anchors, t)                                       # (N, 2)
            self.top_feet.set_data(a[:, 0], a[:, 1])
            if self.layer is None and self.gl is None:
                uv, d = cam.project(rb.disc_triangles(a, n=16)[:, 1].reshape(-1, 3))     # rim points
                self.cam_discs.set_verts(list(uv.reshape(-1, 16, 2)) if (d > 0.2).all() else [])
        if self.layer is None:
            for s in range(self.joints.shape[0]):
                uv, d = cam.project(self.joints[s, t])
                self.cam_bones[s].set_segments(uv[self.bone_idx][(d[self.bone_idx] > 0.2).all(1)])

    def _gl_panel(self, t: int, cam: PinholeCamera) -> np.ndarray:
        """The OpenGL camera panel (h, w, 3) uint8 at frame t: bodies (body style) and discs."""
        if self.layer is not None:
            return self.gl.render(cam, self.layer.posed(t), self.layer.discs(t))
        discs = None if self.anchors is None else rb.disc_triangles(rb.planted_points(self.anchors, t))
        return self.gl.render(cam, (), discs)


def _floor_bounds(pel: np.ndarray, goals: np.ndarray | None, scene_bounds: np.ndarray | None = None):
    """Floor rectangle (x, z) lo (2,), hi (2,): 4 m beyond the pelvis path pel (T, 3), the goals
    (G, 2) and the scene's bounds (2, 3), if given."""
    lo = np.minimum(pel[:, [0, 2]].min(0), goals.min(0) if goals is not None and len(goals) else np.inf) - 4
    hi = np.maximum(pel[:, [0, 2]].max(0), goals.max(0) if goals is not None and len(goals) else -np.inf) + 4
    if scene_bounds is not None:
        lo, hi = np.minimum(lo, scene_bounds[0, [0, 2]]), np.maximum(hi, scene_bounds[1, [0, 2]])
    return lo, hi


def _floor_grid(pel: np.ndarray, goals: np.ndarray | None) -> np.ndarray:
    """(N, 2, 3) segments of a 1 m floor grid 4 m beyond the pelvis path pel (T, 3) and goals."""
    lo, hi = _floor_bounds(pel, goals)
    gx = np.arange(math.floor(lo[0]), math.ceil(hi[0]) + 1, 1.0)
    gz = np.arange(math.floor(lo[1]), math.ceil(hi[1]) + 1, 1.0)
    grid_segs = [np.array([[x, 0, z0_], [x, 0, z1_]]) for x in gx for z0_, z1_ in zip(gz[:-1], gz[1:])] + \
                [np.array([[x0_, 0, z], [x1_, 0, z]]) for z in gz for x0_, x1_ in zip(gx[:-1], gx[1:])]
    return np.stack(grid_segs) if grid_segs else np.zeros((0, 2, 3))


def _panel_pixels(ax, height: int):
    """The axes' data -> frame pixel map (x right, y down) and its box (r0, r1, c0, c1) in the
    frame, as drawn (after aspect adjustment)."""
    M = ax.transData.get_affine().get_matrix()                                              # (3, 3) display = M @ data

    def to_px(uv):                                                                           # (N, 2) -> (N, 2)
        return np.stack([M[0, 0] * uv[:, 0] + M[0, 2], height - (M[1, 1] * uv[:, 1] + M[1, 2])], -1)

    x0, y0, x1, y1 = ax.bbox.extents
    box = (int(math.ceil(height - y1)), int(math.floor(height - y0)), int(math.ceil(x0)), int(math.floor(x1)))
    return to_px, box
