"""Skinned bodies for the video's camera panel: meshes posed chunk by chunk, Lambert-shaded,
rasterised with a z-buffer in numpy and composited onto the frame matplotlib drew. That is the
fallback where OpenGL is unavailable; otherwise `gl_render` draws the bodies (`BodyLayer.posed`,
`BodyLayer.discs`) depth-tested with the scene.

Why numpy and not matplotlib polygons: a body is a few thousand faces per frame at 30 fps;
one vectorised z-buffer pass over the bodies' bounding box (every candidate pixel of every
face at once, `np.maximum.at` for the depth test) costs a few milliseconds, and it gives
per-pixel visibility where sorting whole faces (painter's algorithm) does not.

Why a decimated mesh: at video size a body is ~150-350 pixels tall, so the 10,475-vertex mesh
puts several faces on every pixel. Vertex clustering on a lattice (`cluster_decimate`) keeps
one vertex per cell and per dominant skinning joint, so only those vertices are posed
(`BodyModel.vertices(..., vertex_ids=)` where the model supports it) and faces never join two
limbs that merely touch in the rest pose.

Floor contact: a soft shadow (the body projected straight down onto y = 0, blurred), and for
every foot joint the motion holds planted a disc on the floor where the foot was put down (the
first frame of the planted span) with that part of the foot tinted in the same colour. A foot
that slides visibly leaves its disc.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter

from motiongen.skeleton import NUM_BODY_JOINTS
from motiongen.spans import true_runs

CONTACT_RGB = np.array([0.62, 1.0, 0.0])     # lime: no sample colour, not the goals' amber
DISC_RADIUS = 0.11                           # metres; wider than a foot so a rim shows round it
SHADOW_ALPHA = 0.45
NEAR = 0.5                                   # metres: nearer faces (a body walking through the
                                             # camera) would each cover the whole panel


def cluster_decimate(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray,
                     cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering. vertices (V, 3), faces (F, 3), labels (V,) int (dominant skinning
    joint). Vertices are merged within a `cell`-metre lattice cell and a label; each cluster
    keeps its member nearest the cluster mean. Returns the kept vertex ids (K,) and faces
    (F', 3) indexing into them, with degenerate and duplicate faces dropped; windings are kept."""
    key = np.concatenate([np.floor(vertices / cell).astype(np.int64), labels[:, None].astype(np.int64)], 1)
    _, cluster, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    cluster = cluster.reshape(-1)                                                    # (V,)
    mean = np.zeros((len(counts), 3))
    np.add.at(mean, cluster, vertices)
    mean /= counts[:, None]
    dist = np.linalg.norm(vertices - mean[cluster], axis=1)
    order = np.lexsort((dist, cluster))
    first = np.r_[True, cluster[order][1:] != cluster[order][:-1]]
    ids = order[first]                                                               # (K,), cluster k -> ids[k]
    f = cluster[faces]                                                               # (F, 3)
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
    # Rotate each face to start at its smallest index (same winding) so duplicates compare equal.
    r = np.argmin(f, 1)
    f = np.take_along_axis(f, (r[:, None] + np.arange(3)) % 3, 1)
    return ids, np.unique(f, axis=0)


class BodyMeshes:
    """Posed, decimated meshes of S bodies (objects with global_orient (T, 3), body_pose (T, 63),
    transl (T, 3), betas (nβ,)) of one BodyModel. Only the frames to be drawn (`frames`, in
    increasing order; default all) are posed, `chunk` of them at a time as they are asked
    for, so memory stays bounded whatever the motion's length."""

    def __init__(self, body_model, bodies, frames=None, cell: float = 0.03, chunk: int = 64):
        labels = body_model.skinning_weights[:, :NUM_BODY_JOINTS].argmax(1)            # (V,) body joint
        self.ids, self.faces = cluster_decimate(body_model.template_vertices, np.asarray(body_model.faces),
                                                labels, cell)
        self.part = labels[self.ids]                                                 # (K,) dominant joint
        self.face_part = self.part[self.faces[:, 0]]                                 # (F,)
        self.bm, self.bodies, self.chunk = body_model, list(bodies), chunk
        T = min(len(b.transl) for b in self.bodies)
        self.frames = np.arange(T) if frames is None else np.asarray(frames, np.int64)
        self._cache: dict[int, tuple[int, np.ndarray]] = {}

    def __len__(self) -> int:
        return len(self.bodies)

    def vertices(self, s: int, t: int) -> np.ndarray:
        """(K, 3) posed vertices of body s at frame t (one of `frames`)."""
        i = int(np.searchsorted(self.frames, t))
        if i == len(self.frames) or self.frames[i] != t:
            raise IndexError(f"frame {t} is not one of the frames to draw")
        start = i - i % self.chunk
        if self._cache.get(s, (None,))[0] != start:
            self._cache[s] = (start, self._pose(s, self.frames[start:start + self.chunk]))
        return self._cache[s][1][i - start]

    def _pose(self, s: int, idx: np.ndarray) -> np.ndarray:
        return self.bm.motion_vertices(self.bodies[s], idx, vertex_ids=self.ids).astype(np.float64)   # (n, K, 3)


def rasterise(xy: np.ndarray, invz: np.ndarray, colour: np.ndarray, height: int,
              width: int) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer rasterisation of triangles into a (height, width) image.

    xy (F, 3, 2) vertex positions in pixels (x right, y down; pixel (r, c) is sampled at its
    centre (c + 0.5, r + 0.5)); invz (F, 3) inverse depths (1/z is affine in screen space, so
    interpolating it is perspective-correct; larger is nearer); colour (F, C).
    Returns the image (H, W, C) float32 (zero where empty) and coverage (H, W) bool."""
    C = colour.shape[1]
    img = np.zeros((height * width, C), np.float32)
    cover = np.zeros(height * width, bool)
    x, y = xy[..., 0], xy[..., 1]                                                     # (F, 3)
    c0 = np.clip(np.ceil(x.min(1) - 0.5), 0, width).astype(np.int32)
    c1 = np.clip(np.floor(x.max(1) - 0.5), -1, width - 1).astype(np.int32)
    r0 = np.clip(np.ceil(y.min(1) - 0.5), 0, height).astype(np.int32)
    r1 = np.clip(np.floor(y.max(1) - 0.5), -1, height - 1).astype(np.int32)
    nx, ny = c1 - c0 + 1, r1 - r0 + 1
    ex1, ey1 = x[:, 1] - x[:, 0], y[:, 1] - y[:, 0]
    ex2, ey2 = x[:, 2] - x[:, 0], y[:, 2] - y[:, 0]
    area = ex1 * ey2 - ex2 * ey1                                                      # (F,) twice the signed area
    k = np.nonzero((nx > 0) & (ny > 0) & (np.abs(area) > 1e-9))[0]
    if not len(k):
        return img.reshape(height, width, C), cover.reshape(height, width)
    # Barycentrics b1, b2 and 1/z are affine in the pixel position; per face, their values at
    # the bounding box's first pixel centre and their steps per pixel in x and y.
    inv = 1.0 / area[k]
    a1, b1, a2, b2 = ey2[k] * inv, -ex2[k] * inv, -ey1[k] * inv, ex1[k] * inv
    ox, oy = c0[k] + 0.5 - x[k, 0], r0[k] + 0.5 - y[k, 0]
    u0, v0 = a1 * ox + b1 * oy, a2 * ox + b2 * oy
    dw1, dw2 = invz[k, 1] - invz[k, 0], invz[k, 2] - invz[k, 0]
    za, zb, z0 = a1 * dw1 + a2 * dw2, b1 * dw1 + b2 * dw2, invz[k, 0] + u0 * dw1 + v0 * dw2
    per = np.stack([u0, a1, b1, v0, a2, b2, z0, za, zb]).astype(np.float32)          # (9, F')
    nxk, n = nx[k], nx[k] * ny[k]
    # Every candidate pixel of every face at once (float32 / int32: this is the hot loop).
    fid = np.repeat(np.arange(len(k), dtype=np.int32), n)                              # (N,)
    local = np.arange(n.sum(), dtype=np.int32) - np.repeat(np.cumsum(n, dtype=np.int32) - n, n)
    dy, dx = np.divmod(local, nxk[fid])
    dx, dy = dx.astype(np.float32), dy.astype(np.float32)
    u = per[0][fid] + per[1][fid] * dx + per[2][fid] * dy
    v = per[3][fid] + per[4][fid] * dx + per[5][fid] * dy
    eps = 1e-5                                                  # shared edges: no pinholes
    inside = np.nonzero((u >= -eps) & (v >= -eps) & (u + v <= 1 + eps))[0]
    fid, dx, dy = fid[inside], dx[inside], dy[inside]
    iz = per[6][fid] + per[7][fid] * dx + per[8][fid] * dy
    pix = (r0[k][fid] + dy.astype(np.int32)) * width + c0[k][fid] + dx.astype(np.int32)
    zbuf = np.full(height * width, -np.inf, np.float32)
    np.maximum.at(zbuf, pix, iz)
    win = iz >= zbuf[pix]
    img[pix[win]] = colour[k][fid[win]]
    cover[pix[win]] = True
    return img.reshape(height, width, C), cover.reshape(height, width)


def facing(points: np.ndarray, faces: np.ndarray, eye: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Back-face culling: for (K, 3) points and outward-wound faces (F, 3), a (F,) bool of the
    faces turned towards the eye and their unit normals (F, 3)."""
    p = points[faces]                                                                  # (F, 3, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return ((eye - p[:, 0]) * n).sum(1) > 0, n


def light_direction(cam) -> np.ndarray:
    """(3,) unit vector towards the light: above, behind the camera and a little to its right
    (cam.R rows: image right, image up, forward)."""
    d = np.array([0.0, 1.0, 0.0]) - 0.7 * cam.R[2] + 0.3 * cam.R[0]
    return d / np.linalg.norm(d)


def planted_points(anchors: np.ndarray, t: int) -> np.ndarray:
    """(N, 2) floor points (x, z) of every sample's feet planted at frame t, from anchors
    (S, T, C, 2) (`contact_anchors`: NaN where not planted)."""
    a = anchors[:, t].reshape(-1, 2)
    return a[~np.isnan(a[:, 0])]


def contact_anchors(joints: np.ndarray, planted: np.ndarray, contact_joints) -> np.ndarray:
    """(S, T, C, 2) floor point (x, z) where each planted foot joint was put down (its position
    at the first frame of the current planted span); NaN where it is not planted.
    joints (S, T, J, 3), planted (S, T, C) bool."""
    S, T, C = planted.shape
    out = np.full((S, T, C, 2), np.nan)
    for s in range(S):
        for c, j in enumerate(contact_joints):
            for a, b in true_runs(planted[s, :, c]):
                out[s, a:b, c] = joints[s, a, j, [0, 2]]
    return out


def disc_triangles(anchors: np.ndarray, radius: float = DISC_RADIUS, n: int = 20) -> np.ndarray:
    """Floor discs (y = 2 mm) round points (N, 2) (x, z) as fans: triangles (N * n, 3, 3)."""
    if not len(anchors):
        return np.zeros((0, 3, 3))
    a = np.linspace(0, 2 * np.pi, n + 1)
    ring = np.stack([np.cos(a), np.sin(a)], -1) * radius                               # (n+1, 2)
    rim = anchors[:, None] + ring[None]                                                # (N, n+1, 2)
    centre = np.broadcast_to(anchors[:, None], (len(anchors), n, 2))
    tri = np.stack([centre, rim[:, :-1], rim[:, 1:]], 2)                               # (N, n, 3, 2)
    tri = np.stack([tri[..., 0], np.full(tri.shape[:-1], 0.002), tri[..., 1]], -1)    # (N, n, 3, 3)
    return tri.reshape(-1, 3, 3)


class BodyLayer:
    """What the camera panel shows of the bodies in body style: shadows, planted-foot discs
    and the shaded meshes, composited per frame onto the frame matplotlib drew.

    meshes: BodyMeshes; colours (S, 3) in [0, 1]; anchors (S, T, C, 2) from `contact_anchors`
    or None; contact_parts (C,) the body joint of each contact flag (-1: none to tint)."""

    def __init__(self, meshes: BodyMeshes, colours: np.ndarray, anchors: np.ndarray | None = None,
                 contact_parts=(), supersample: int = 2):
        self.meshes, self.anchors, self.ss = meshes, anchors, supersample
        # Lighter than the flat sample colour so Lambert shading can show the body's form.
        self.colours = 0.75 * np.asarray(colours, np.float64)[:, :3] + 0.25
        self.contact_parts = np.asarray(contact_parts, np.int64).reshape(-1)

    def posed(self, t: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per body at frame t: vertices (K, 3), faces (F, 3) and vertex colours (K, 3), the
        parts of a planted foot tinted (what `gl_render.PanelRenderer.render` draws)."""
        m, out = self.meshes, []
        for s in range(len(m)):
            rgb = np.broadcast_to(self.colours[s], (len(m.part), 3)).copy()               # (K, 3)
            tint = np.isin(m.part, self._planted_parts(s, t))
            rgb[tint] = 0.25 * rgb[tint] + 0.75 * CONTACT_RGB
            out.append((m.vertices(s, t), m.faces, rgb))
        return out

    def discs(self, t: int) -> np.ndarray:
        """(N, 3, 3) floor-disc triangles of every body's planted feet at frame t."""
        if self.anchors is None:
            return np.zeros((0, 3, 3))
        return disc_triangles(planted_points(self.anchors, t))

    def _planted_parts(self, s: int, t: int) -> np.ndarray:
        """The body joints (n,) whose parts body s holds planted at frame t."""
        if self.anchors is None:
            return np.zeros(0, np.int64)
        on = self.contact_parts[~np.isnan(self.anchors[s, t, :, 0])]
        return on[on >= 0]

    def draw(self, frame: np.ndarray, cam, to_px, box: tuple[int, int, int, int], t: int) -> None:
        """Composite frame t in place onto frame (H, W, 3) uint8 inside box (r0, r1, c0, c1).
        cam: .project((N, 3)) -> (uv (N, 2), depth (N,)), .eye (3,), .R (3, 3) (rows: image x,
        image y, view direction); to_px: uv (N, 2) -> frame pixels (N, 2) (x right, y down)."""
        m = self.meshes
        light = light_direction(cam)
        tris, rgbs, shadow = [], [], []
        for s in range(len(m)):
            v = m.vertices(s, t)                                                       # (K, 3)
            front, nrm = facing(v, m.faces, cam.eye)
            base = np.broadcast_to(self.colours[s], (len(m.faces), 3)).copy()          # (F, 3)
            tint = np.isin(m.face_part, self._planted_parts(s, t))
            base[tint] = 0.25 * base[tint] + 0.75 * CONTACT_RGB
            lum = 0.35 + 0.65 * np.clip(nrm @ light, 0.0, 1.0)                          # (F,) Lambert + ambient
            tris.append(v[m.faces[front]])
            rgbs.append(base[front] * lum[front, None])
            up = nrm[:, 1] > 0             # a closed mesh's up-facing faces cover its whole shadow
            shadow.append(v[m.faces[up]] * np.array([1.0, 0.0, 1.0]))
        d = self.discs(t)
        tris.append(d)
        rgbs.append(np.broadcast_to(CONTACT_RGB, (len(d), 3)))
        self._shadow(frame, np.concatenate(shadow), cam, to_px, box)
        self._bodies(frame, np.concatenate(tris), np.concatenate(rgbs), cam, to_px, box)

    @staticmethod
    def _screen(tri: np.ndarray, cam, to_px) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        uv, d = cam.project(tri.reshape(-1, 3))
        ok = (d.reshape(-1, 3) > NEAR).all(1)
        return to_px(uv).reshape(-1, 3, 2)[ok], 1.0 / d.reshape(-1, 3)[ok], ok

    @staticmethod
    def _crop(xy: np.ndarray, box, pad: int) -> tuple[int, int, int, int] | None:
        r0, r1, c0, c1 = box
        lo = np.floor(xy.reshape(-1, 2).min(0)).astype(int) - pad
        hi = np.ceil(xy.reshape(-1, 2).max(0)).astype(int) + pad
        cr = (max(r0, lo[1]), min(r1, hi[1]), max(c0, lo[0]), min(c1, hi[0]))
        return cr if cr[0] < cr[1] and cr[2] < cr[3] else None

    def _shadow(self, frame, tri, cam, to_px, box, blur: int = 2) -> None:
        if not len(tri):
            return
        xy, invz, _ = self._screen(tri, cam, to_px)
        cr = self._crop(xy, box, 2 * blur + 1) if len(xy) else None
        if cr is None:
            return
        r0, r1, c0, c1 = cr
        _, cover = rasterise(xy - [c0, r0], invz, np.zeros((len(xy), 0)), r1 - r0, c1 - c0)
        # Two box passes (zero outside the crop): a soft-edged, roughly Gaussian penumbra.
        size = 2 * blur + 1
        a = SHADOW_ALPHA * uniform_filter(uniform_filter(cover.astype(np.float32), size, mode="constant"), size,
                                          mode="constant")                                  # (h, w)
        sub = frame[r0:r1, c0:c1]
        sub[:] = (sub * (1.0 - a[..., None])).astype(np.uint8)

    def _bodies(self, frame, tri, rgb, cam, to_px, box) -> None:
        xy, invz, ok = self._screen(tri, cam, to_px)
        cr = self._crop(xy, box, 1) if len(xy) else None
        if cr is None:
            return
        r0, r1, c0, c1 = cr
        h, w, k = r1 - r0, c1 - c0, self.ss
        # Supersampled k x k, then averaged: coverage becomes alpha, so edges are anti-aliased.
        img, cover = rasterise((xy - [c0, r0]) * k, invz, rgb[ok], h * k, w * k)
        # Sums over the k x k sub-pixels as strided slices (much faster than .sum over axes).
        cover = cover.astype(np.float32)
        alpha = sum(cover[i::k, j::k] for i in range(k) for j in range(k)) / (k * k)     # (h, w)
        col = sum(img[i::k, j::k] for i in range(k) for j in range(k))                  # (h, w, 3) covered sum
        sub = frame[r0:r1, c0:c1]
        # Covered sub-pixels' colours are premultiplied: frame * (1 - alpha) + colour sum / k^2.
        sub[:] = (sub * (1 - alpha[..., None]) + (255.0 / (k * k)) * col).astype(np.uint8)
