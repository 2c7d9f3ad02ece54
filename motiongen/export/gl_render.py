"""The video's camera panel rendered with OpenGL (moderngl on an offscreen EGL context; on a
machine without a GPU that is Mesa's llvmpipe): the scene, a floor with a 1 m grid, the posed
bodies, their shadow and the planted-foot discs, depth-tested together so walls hide the body
and the body hides what is behind it.

Why OpenGL and not the numpy rasteriser (`render_body.rasterise`) for the whole panel: a scene
mesh has tens of thousands of faces and most of them land on screen; a z-buffer in numpy pays
for every candidate pixel in Python-visible arrays, llvmpipe's compiled rasteriser does not
(`benchmarks/video.py` prints both). The numpy path stays as the fallback where no EGL
context can be made.

Projection: exactly `camera.PinholeCamera.project` (u = focal * x / z, v = focal * y / z in
the camera frame), with the image's columns spanning u in [extent[0], extent[1]] left to
right and its rows v in [extent[3], extent[2]] top to bottom, so matplotlib overlays drawn
with `cam.project` line up with the image.

Processes: an EGL context must not cross a fork, so the context is made lazily in the process
that renders (`os.getpid()` remembered; a forked child makes its own), llvmpipe is asked to
rasterise in the calling thread and Mesa's shader cache is off (their worker threads do not
exist in a forked child, which would wait for them forever).
"""

from __future__ import annotations

import os
import sys
from types import SimpleNamespace
from typing import Sequence

import numpy as np

from motiongen.export.camera import CAM_VIEW
from motiongen.export.render_body import CONTACT_RGB, SHADOW_ALPHA, light_direction

SCENE_RGB = (0.55, 0.60, 0.68)          # the occupancy boxes' grey-blue of the old panel
FLOOR_RGB = (0.87, 0.86, 0.83)
GRID_RGB = (0.68, 0.68, 0.68)
SKY_RGB = (0.957, 0.945, 0.918)         # the old panel's background (#f4f1ea)
FLOOR_Y = -0.003                        # just under y = 0: a scene's own floor at 0 wins the depth test
SHADOW_TEXELS = 64                      # top-down shadow map over the bodies' footprint: ~3 cm texels
MSAA_SAMPLES = 0                        # 4x MSAA costs 2-3x the panel's render time on llvmpipe
NEAR = 0.05                             # metres

_VERTEX = """
#version 330
uniform mat4 mvp;
in vec3 in_pos;
in vec3 in_nrm;
in vec4 in_col;
out vec3 wp;
out vec3 nrm;
out vec4 col;
void main() {
    wp = in_pos;
    nrm = in_nrm;
    col = in_col;
    gl_Position = mvp * vec4(in_pos, 1.0);
}
"""

# in_nrm zero: flat shading from the screen-space derivatives of the world position (scene
# meshes' windings and normals cannot be trusted). col.a: how much Lambert shading applies
# (0: the colour as given, e.g. the floor and the planted-foot discs). Normals are turned to
# the eye, so either side of a face is lit. `ground` (floor and scene draws): fragments on the
# floor (the floor's, or a scene's floor slab) get the floor colour, grid lines and the bodies'
# shadow.
_FRAGMENT = """
#version 330
uniform vec3 eye;
uniform vec3 light;
uniform float ground;
uniform vec3 grid_rgb;
uniform vec3 floor_rgb;
uniform sampler2D shadow;
uniform vec3 shadow_rect;     // x0, z0, 1 / side
uniform float shadow_alpha;
in vec3 wp;
in vec3 nrm;
in vec4 col;
out vec4 frag;
void main() {
    vec3 flat_n = cross(dFdx(wp), dFdy(wp));
    vec2 fw = fwidth(wp.xz);
    vec3 n = dot(nrm, nrm) > 0.0 ? nrm : flat_n;
    n = normalize(n);
    if (dot(n, eye - wp) < 0.0) n = -n;
    float lum = mix(1.0, 0.35 + 0.65 * max(dot(n, light), 0.0), col.a);
    vec3 c = col.rgb * lum;
    if (ground > 0.0 && wp.y < 0.02 && n.y > 0.9) {
        c = floor_rgb;                                                // a scene's floor slab too
        vec2 g = abs(fract(wp.xz + 0.5) - 0.5) / max(fw, 1e-6);     // distance to a line, pixels
        c = mix(c, grid_rgb, 1.0 - min(min(g.x, g.y), 1.0));
        vec2 st = (wp.xz - shadow_rect.xy) * shadow_rect.z;
        if (all(greaterThan(st, vec2(0.0))) && all(lessThan(st, vec2(1.0)))) {
            // One bilinear tap of a coarse map gives the soft edge (more taps cost more than
            // the rest of the shader on llvmpipe).
            c *= 1.0 - shadow_alpha * texture(shadow, st).r;
        }
    }
    frag = vec4(c, 1.0);
}
"""

_SHADOW_VERTEX = """
#version 330
uniform vec3 shadow_rect;
in vec3 in_pos;
void main() {
    gl_Position = vec4((in_pos.xz - shadow_rect.xy) * shadow_rect.z * 2.0 - 1.0, 0.0, 1.0);
}
"""

_SHADOW_FRAGMENT = """
#version 330
out float cover;
void main() { cover = 1.0; }
"""

_WARNED = False
_AVAILABLE: bool | None = None     # per process: None until tried


def _create_context():
    """A headless OpenGL 3.3 context (EGL)."""
    # Imported here: moderngl is needed only when a video is drawn, and its absence is handled
    # by `available` (the numpy fallback).
    import moderngl

    # A forked worker inherits the EGL display but none of the driver's threads, and waits for
    # them forever: llvmpipe's rasteriser threads, and the shader cache's writer thread, which a
    # first run on a machine (an empty cache, every shader compiled and queued for writing)
    # uses. Video frames are drawn one process per core, so neither is needed.
    os.environ["LP_NUM_THREADS"] = "0"
    os.environ["MESA_SHADER_CACHE_DISABLE"] = "true"
    return moderngl.create_standalone_context(backend="egl", require=330)


def available() -> bool:
    """Whether an EGL context can be made in this process (tried once); warns once if not."""
    global _AVAILABLE, _WARNED
    if _AVAILABLE is None:
        try:
            _create_context().release()
            _AVAILABLE = True
        except Exception as e:  # no moderngl, no libEGL, no usable device: the numpy fallback
            _AVAILABLE = False
            if not _WARNED:
                _WARNED = True
                print(f"warning: no OpenGL for the video's camera panel ({type(e).__name__}: {e}); "
                      f"drawing it with matplotlib and numpy", file=sys.stderr)
    return _AVAILABLE


def view_matrix(cam) -> np.ndarray:
    """(4, 4) world -> camera frame (x image right, y image up, z forward)."""
    m = np.eye(4)
    m[:3, :3] = cam.R
    m[:3, 3] = -cam.R @ cam.eye
    return m


def projection_matrix(focal: float, extent: Sequence[float], near: float, far: float) -> np.ndarray:
    """(4, 4) camera frame -> clip space: NDC x = -1..1 is u = extent[0]..extent[1] and NDC
    y = -1..1 is v = extent[2]..extent[3], where (u, v) = focal * (x, y) / z (z forward, so
    w = z); depth -1..1 over near..far."""
    u0, u1, v0, v1 = extent
    return np.array([[2 * focal / (u1 - u0), 0, -(u1 + u0) / (u1 - u0), 0],
                     [0, 2 * focal / (v1 - v0), -(v1 + v0) / (v1 - v0), 0],
                     [0, 0, (far + near) / (far - near), -2 * far * near / (far - near)],
                     [0, 0, 1, 0]])


def vertex_normals(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(K, 3) unit area-weighted vertex normals of vertices v (K, 3) and faces (F, 3)."""
    p = v[faces]                                                                         # (F, 3, 3)
    a, b = (p[:, 1] - p[:, 0]).T, (p[:, 2] - p[:, 0]).T                                  # (3, F) each
    # Written out: np.cross's argument handling costs more than the product for one body.
    fn = np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]], -1)
    # fn (F, 3): twice the face areas along the face normals; summed onto each face's corners.
    n = np.stack([np.bincount(faces.reshape(-1), np.repeat(fn[:, i], 3), minlength=len(v)) for i in range(3)], -1)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def _rows(pos: np.ndarray, nrm, rgb, lit: float) -> np.ndarray:
    """(N, 10) float32 vertex rows: position, normal (zero: flat), colour and Lambert weight."""
    out = np.empty((len(pos), 10), np.float32)
    out[:, :3] = pos
    out[:, 3:6] = nrm
    out[:, 6:9] = rgb
    out[:, 9] = lit
    return out


class PanelRenderer:
    """Offscreen renderer of the camera panel's 3D content at `size` (W, H) pixels, whose
    columns span image-plane u in extent[0]..extent[1] and rows v in extent[3]..extent[2]
    (default: the whole panel, ±CAM_VIEW). samples: MSAA samples (None: MSAA_SAMPLES; 0: none).

    The scene and floor are set once (`set_scene`, `set_floor`); `render` draws one frame."""

    def __init__(self, size: tuple[int, int], extent: Sequence[float] | None = None, samples: int | None = None):
        self.size = (int(size[0]), int(size[1]))
        self.extent = tuple(float(e) for e in (extent or (-CAM_VIEW[0], CAM_VIEW[0], -CAM_VIEW[1], CAM_VIEW[1])))
        self.samples = MSAA_SAMPLES if samples is None else int(samples)
        self._static = {"scene": np.zeros((0, 10), np.float32), "floor": np.zeros((0, 10), np.float32)}
        self._far = 100.0
        self._pid, self._gl, self._dirty = None, None, True

    # ---- static geometry -------------------------------------------------------------

    def set_scene(self, triangles: np.ndarray, rgb: Sequence[float] = SCENE_RGB) -> None:
        """The scene as triangles (N, 3, 3) (world metres, y up), flat-shaded in `rgb`."""
        tri = np.asarray(triangles, np.float64).reshape(-1, 3)
        self._static["scene"] = _rows(tri, 0.0, rgb, 1.0)
        self._far = max(self._far, 2.0 * float(np.abs(tri).max(initial=0.0)) + 50.0)
        self._dirty = True

    def set_floor(self, lo: Sequence[float], hi: Sequence[float]) -> None:
        """A floor rectangle (x, z) lo (2,) .. hi (2,) just under y = 0, with a 1 m grid (as
        on any upward face of the scene at floor height)."""
        (x0, z0), (x1, z1) = lo, hi
        quad = np.array([[x0, FLOOR_Y, z0], [x1, FLOOR_Y, z0], [x1, FLOOR_Y, z1],
                         [x0, FLOOR_Y, z0], [x1, FLOOR_Y, z1], [x0, FLOOR_Y, z1]])
        self._static["floor"] = _rows(quad, (0.0, 1.0, 0.0), FLOOR_RGB, 0.0)
        self._far = max(self._far, 2.0 * float(np.abs(quad).max()) + 50.0)
        self._dirty = True

    # ---- one frame -------------------------------------------------------------------

    def render(self, cam, bodies: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]] = (),
               discs: np.ndarray | None = None, disc_rgb: Sequence[float] = tuple(CONTACT_RGB)) -> np.ndarray:
        """The panel (H, W, 3) uint8 seen by `cam` (a `PinholeCamera`).

        bodies: per body (vertices (K, 3), faces (F, 3), colours (K, 3) or (3,) in [0, 1]),
        smooth-shaded and casting a shadow on the floor; discs: triangles (N, 3, 3) drawn
        unshaded in disc_rgb (the planted-foot marks)."""
        gl = self._context()
        body_rows, body_idx = self._bodies(bodies)
        if discs is not None and len(discs):
            body_idx = np.concatenate([body_idx, len(body_rows) + np.arange(3 * len(discs), dtype=np.int32)])
            body_rows = np.concatenate([body_rows, _rows(np.reshape(discs, (-1, 3)), (0.0, 1.0, 0.0), disc_rgb, 0.0)])
        n_idx = self._upload_dynamic(gl, body_rows, body_idx)
        self._draw(gl, cam, self._shadow(gl, bodies, n_idx), n_idx)
        if gl.target is not gl.out:
            gl.ctx.copy_framebuffer(gl.out, gl.target)           # resolves the multisampled image
        W, H = self.size
        img = np.frombuffer(gl.out.read(components=3, alignment=1), np.uint8).reshape(H, W, 3)
        return img[::-1].copy()                                   # GL's rows run bottom to top

    def _draw(self, gl, cam, shadow_rect: tuple[float, float, float], n_idx: int) -> None:
        """Floor and scene, then the bodies and discs (n_idx indices), depth-tested."""
        mvp = projection_matrix(cam.focal, self.extent, NEAR, self._far) @ view_matrix(cam)
        prog = gl.prog
        prog["mvp"].write(mvp.T.astype("f4").tobytes())          # GL reads matrices column by column
        prog["eye"].value = tuple(cam.eye)
        prog["light"].value = tuple(light_direction(cam))
        prog["shadow_rect"].value = shadow_rect
        gl.target.use()
        gl.target.clear(*SKY_RGB, 1.0, depth=1.0)
        gl.ctx.enable(gl.ctx.DEPTH_TEST)
        gl.shadow_tex.use(0)
        prog["ground"].value = 1.0
        for name in ("floor", "scene"):
            if gl.static_n[name]:
                gl.static_vao[name].render(vertices=gl.static_n[name])
        prog["ground"].value = 0.0
        if n_idx:
            gl.body_vao.render(vertices=n_idx)

    @staticmethod
    def _bodies(bodies) -> tuple[np.ndarray, np.ndarray]:
        rows, idx, k = [], [], 0
        for v, f, rgb in bodies:
            v, f = np.asarray(v, np.float64), np.asarray(f, np.int64)
            rows.append(_rows(v, vertex_normals(v, f), rgb, 1.0))
            idx.append((f + k).reshape(-1).astype(np.int32))
            k += len(v)
        if not rows:
            return np.zeros((0, 10), np.float32), np.zeros(0, np.int32)
        return np.concatenate(rows), np.concatenate(idx)

    def _shadow(self, gl, bodies, n_idx: int) -> tuple[float, float, float]:
        """Draws the bodies seen from straight above into the shadow map; returns the map's
        square on the floor (x0, z0, 1 / side)."""
        gl.shadow_fbo.use()
        gl.shadow_fbo.clear(0.0)
        n_body = sum(3 * len(f) for _, f, _ in bodies)        # body triangles only, not the discs
        if not n_body:
            return (0.0, 0.0, 1.0)
        xz = np.concatenate([np.asarray(v)[:, [0, 2]] for v, _, _ in bodies])
        lo, hi = xz.min(0) - 0.2, xz.max(0) + 0.2
        side = float((hi - lo).max())
        rect = (float(lo[0]), float(lo[1]), 1.0 / side)
        gl.ctx.disable(gl.ctx.DEPTH_TEST)
        gl.shadow_prog["shadow_rect"].value = rect
        gl.shadow_vao.render(vertices=min(n_body, n_idx))
        return rect

    # ---- the context, per process ----------------------------------------------------

    def _context(self) -> SimpleNamespace:
        if self._pid != os.getpid():
            # A context inherited through fork belongs to the parent: left alone (not released:
            # its EGL calls would act on the parent's state), a new one made here.
            self._gl, self._pid, self._dirty = self._build(_create_context()), os.getpid(), True
        if self._dirty:
            self._upload_static(self._gl)
            self._dirty = False
        return self._gl

    def _build(self, ctx) -> SimpleNamespace:
        W, H = self.size
        gl = SimpleNamespace(ctx=ctx)
        gl.prog = ctx.program(vertex_shader=_VERTEX, fragment_shader=_FRAGMENT)
        gl.prog["grid_rgb"].value = GRID_RGB
        gl.prog["floor_rgb"].value = FLOOR_RGB
        gl.prog["shadow_alpha"].value = SHADOW_ALPHA
        gl.prog["shadow"].value = 0
        gl.shadow_prog = ctx.program(vertex_shader=_SHADOW_VERTEX, fragment_shader=_SHADOW_FRAGMENT)
        gl.out = ctx.framebuffer(ctx.renderbuffer((W, H), 3), ctx.depth_renderbuffer((W, H)))
        gl.target = gl.out if self.samples < 2 else ctx.framebuffer(
            ctx.renderbuffer((W, H), 3, samples=self.samples), ctx.depth_renderbuffer((W, H), samples=self.samples))
        gl.shadow_tex = ctx.texture((SHADOW_TEXELS, SHADOW_TEXELS), 1, dtype="f1")
        gl.shadow_tex.repeat_x = gl.shadow_tex.repeat_y = False
        gl.shadow_fbo = ctx.framebuffer([gl.shadow_tex])
        gl.body_vbo, gl.body_ibo, gl.body_vao, gl.shadow_vao = None, None, None, None
        gl.static_vao, gl.static_vbo, gl.static_n = {}, {}, {}
        return gl

    def _upload_static(self, gl) -> None:
        for obj in (*gl.static_vao.values(), *gl.static_vbo.values()):
            obj.release()
        gl.static_vao, gl.static_vbo, gl.static_n = {}, {}, {}
        for name, rows in self._static.items():
            gl.static_n[name] = len(rows)
            if len(rows):
                gl.static_vbo[name] = vbo = gl.ctx.buffer(rows.tobytes())
                gl.static_vao[name] = gl.ctx.vertex_array(gl.prog, [(vbo, "3f 3f 4f", "in_pos", "in_nrm", "in_col")])

    def _upload_dynamic(self, gl, rows: np.ndarray, idx: np.ndarray) -> int:
        """Writes the frame's vertex rows and indices, growing the buffers when they are too
        small; returns the number of indices."""
        if not len(idx):
            return 0
        if gl.body_vbo is None or gl.body_vbo.size < rows.nbytes or gl.body_ibo.size < idx.nbytes:
            for obj in (gl.body_vao, gl.shadow_vao, gl.body_vbo, gl.body_ibo):
                if obj is not None:
                    obj.release()
            gl.body_vbo = gl.ctx.buffer(reserve=2 * rows.nbytes)
            gl.body_ibo = gl.ctx.buffer(reserve=2 * idx.nbytes)
            fmt = [(gl.body_vbo, "3f 3f 4f", "in_pos", "in_nrm", "in_col")]
            gl.body_vao = gl.ctx.vertex_array(gl.prog, fmt, index_buffer=gl.body_ibo, index_element_size=4)
            gl.shadow_vao = gl.ctx.vertex_array(gl.shadow_prog, [(gl.body_vbo, "3f 28x", "in_pos")],
                                                index_buffer=gl.body_ibo, index_element_size=4)
        gl.body_vbo.write(rows.tobytes())
        gl.body_ibo.write(idx.astype(np.int32).tobytes())
        return len(idx)

    def release(self) -> None:
        """Frees this process's context (a context inherited through fork is left alone)."""
        if self._gl is not None and self._pid == os.getpid():
            self._gl.ctx.release()
        self._gl, self._pid = None, None
