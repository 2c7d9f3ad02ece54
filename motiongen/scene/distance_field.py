"""Distances from points to surfaces: the project's one scene-distance interface, used by the
metrics, the evaluation protocol, contact annotation and augmentation. An occupancy grid's
field is built once and kept with it: `surface_distance(grid)`.

Every field answers, for points (N, 3) in its world frame (or, with ``pose``, for a field that
moves rigidly: the object's local frame is mapped onto the world by ``pose``):

    q = field.query(points, max_distance=inf, pose=None)           -> SurfaceQuery
    q.distance  (N,)   signed distance, metres: > 0 outside, < 0 inside. Outside points
                       farther than ``max_distance`` may come back as +inf (not computed).
    q.direction (N, 3) unit vector from the point towards its nearest surface point (the way
                       out for inside points; the inward surface normal for points on it)
    q.nearest   (N, 3) = points + |distance| * direction (NaN where distance is inf)
    field(points (..., 3)) -> (...,) signed distances  (the `SignedDistance` call convention)
    field.error        bound on |distance error| in metres (0 for exact fields)

Fields:
* `PlaneField`  — the floor, y < height is solid. Exact.
* `MeshField`   — a triangle mesh. Exact: trimesh closest points, computed only for points that
  can matter. A k-d tree of surface samples (spacing s) rules out points farther than
  ``max_distance`` from the surface (its distance is off by at most 2 s), and a solid occupancy
  grid of the mesh's closed parts (`voxelize_mesh`) says which of the points ruled out are
  inside (exact for them: they are further from the surface than half a voxel diagonal). Near
  the surface, inside-ness is the generalised winding number (meshes up to ``winding_faces``
  faces: right for unions of overlapping closed parts, such as furniture built from boxes),
  else the side of the closest face.
* `GridField`   — an occupancy grid alone (the TRUMANS scenes): distance to the nearest
  boundary-voxel centre less half a voxel, from k-d trees; accurate to about half a voxel
  diagonal (`error`). Points off the grid are free.
* `UnionField`  — the union of solids (the scene and the floor): the nearer surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage
from scipy.spatial import cKDTree

from motiongen.scene.occupancy import OccupancyGrid, near_occupied
from motiongen.scene.voxelize import solid_faces, voxelize_mesh

SQRT3_2 = float(np.sqrt(3.0) / 2.0)
BOX_TEST_FACES = 4096        # meshes up to this size find candidate faces by a numpy box test, larger by r-tree
NEAR_VOXEL = 0.04            # m: voxel of the coarse mask that spares most points the k-d tree query
OBJECT_VOXEL = 0.01          # m: objects are small: a finer solid grid than a scene's


@dataclass
class SurfaceQuery:
    distance: np.ndarray    # (N,) signed distance, m (+inf: outside and beyond max_distance)
    direction: np.ndarray   # (N, 3) unit vector towards the nearest surface point (0 where unknown)
    points: np.ndarray      # (N, 3) the query points, in the caller's frame

    @property
    def nearest(self) -> np.ndarray:
        """(N, 3) nearest surface points (NaN where the distance was not computed)."""
        d = np.abs(self.distance)
        out = self.points + np.where(np.isfinite(d), d, np.nan)[:, None] * self.direction
        return out

    @property
    def inside(self) -> np.ndarray:
        return self.distance < 0


class SurfaceField:
    """Base class: subclasses implement `_local(points (N,3) float64, max_distance)` ->
    (distance (N,), direction (N,3)) in the field's own frame."""

    error: float = 0.0

    def query(self, points, max_distance: float = np.inf, pose: np.ndarray | None = None) -> SurfaceQuery:
        p = np.asarray(points, np.float64).reshape(-1, 3)
        if pose is None:
            d, u = self._local(p, float(max_distance))
            return SurfaceQuery(d, u, p)
        M = np.asarray(pose, np.float64)
        R, t = M[:3, :3], M[:3, 3]
        d, u = self._local((p - t) @ R, float(max_distance))                  # world -> local: Rᵀ(p - t)
        return SurfaceQuery(d, u @ R.T, p)

    def __call__(self, points) -> np.ndarray:
        p = np.asarray(points, np.float64)
        return self.query(p.reshape(-1, 3)).distance.reshape(p.shape[:-1])

    def _local(self, p: np.ndarray, max_distance: float) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError


class PlaneField(SurfaceField):
    """The half-space y < height is solid (the floor)."""

    def __init__(self, height: float = 0.0):
        self.height = float(height)

    def _local(self, p, max_distance):
        d = p[:, 1] - self.height
        u = np.zeros_like(p)
        u[:, 1] = np.where(d >= 0, -1.0, 1.0)
        return d, u


class GridField(SurfaceField):
    """Signed distance to the occupied region of an `OccupancyGrid` (outside the grid is free).

    Outside points: distance to the nearest occupied voxel centre that has a free 6-neighbour,
    less half a voxel; inside points: minus the distance to the nearest free voxel centre next
    to an occupied one, less half a voxel. The "nearest centre" is the mean of the centres that
    are nearly as near and lie on the same side: in front of a flat face that is the foot of
    the perpendicular, so the direction is the face normal rather than a staircase diagonal."""

    def __init__(self, grid: OccupancyGrid):
        occ = grid.dense()                                                        # (X, Y, Z) bool
        self.grid, self.voxel_size = grid, float(grid.voxel_size)
        self.error = SQRT3_2 * self.voxel_size
        centres = lambda m: grid.origin + (np.argwhere(m) + 0.5) * self.voxel_size  # noqa: E731
        surf = occ & ~ndimage.binary_erosion(occ, border_value=0)
        free_surf = ~occ & ~ndimage.binary_erosion(~occ, border_value=1)
        self._occ = cKDTree(centres(surf)) if surf.any() else None
        self._free = cKDTree(centres(free_surf)) if free_surf.any() else None
        self._surf = surf
        self._near: dict[float, OccupancyGrid] = {}

    def _near_grid(self, radius: float) -> OccupancyGrid:
        """Voxels whose centre is within `radius` (+ a voxel diagonal) of a boundary voxel centre:
        free points elsewhere are further than `radius` and skip the k-d tree."""
        key = round(radius, 6)
        if key not in self._near:
            near = near_occupied(self._surf, radius / self.voxel_size + np.sqrt(3.0))
            self._near[key] = OccupancyGrid.from_dense(near, self.grid.origin, self.voxel_size)
        return self._near[key]

    def _local(self, p, max_distance):
        half = 0.5 * self.voxel_size
        inside = self.grid.occupied(p, outside=False)                             # (N,)
        d = np.full(len(p), np.inf)
        u = np.zeros_like(p)
        outside = ~inside
        if np.isfinite(max_distance) and self._occ is not None:
            outside &= self._near_grid(max_distance + half).occupied(p, outside=True)   # off the grid: ask the tree
        for tree, sel, sign in ((self._occ, outside, 1.0), (self._free, inside, -1.0)):
            if tree is None or not sel.any():
                continue
            bound = max_distance + half + self.error if sign > 0 else np.inf
            dist, idx = tree.query(p[sel], k=12, distance_upper_bound=bound)         # (n, 12)
            ok = np.isfinite(dist[:, 0])
            rows = np.flatnonzero(sel)[ok]
            dist, idx = dist[ok], idx[ok]
            to = tree.data[np.minimum(idx, tree.n - 1)] - p[rows, None]               # (n, 12, 3)
            unit = to / np.maximum(np.linalg.norm(to, axis=-1, keepdims=True), 1e-12)
            # near-ties (a ring round the foot of the perpendicular, whatever the staircase) on
            # the nearest one's side: not across a medial axis, not round a corner
            tie = (dist <= dist[:, :1] + half) & (np.einsum("nkc,nc->nk", unit, unit[:, 0]) >= 0.5)
            c = p[rows] + (to * tie[..., None]).sum(1) / tie.sum(1, keepdims=True)
            v = c - p[rows]
            n = np.linalg.norm(v, axis=-1, keepdims=True)
            u[rows] = v / np.maximum(n, 1e-12)
            d[rows] = sign * np.maximum(n[:, 0] - half, 0.0)
        if self._free is None:            # the whole grid is occupied: depth unknown, at least half a voxel
            d[inside] = -half
        return d, u


class UnionField(SurfaceField):
    """The union of the fields' solids: distance and direction of the nearest surface (inside
    any solid: the deepest, i.e. the smallest signed distance). Poses apply to the union."""

    def __init__(self, *fields: SurfaceField):
        self.fields = fields
        self.error = max((f.error for f in fields), default=0.0)

    def _local(self, p, max_distance):
        parts = [f._local(p, max_distance) for f in self.fields]
        d = np.stack([x[0] for x in parts])                                       # (F, N)
        k = np.argmin(d, axis=0)                                                  # (N,)
        u = np.stack([x[1] for x in parts])[k, np.arange(len(p))]                 # (N, 3)
        return d[k, np.arange(len(p))], u


def lattice_samples(triangles: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points on triangles (F, 3, 3) such that every surface point is within 2 * `spacing` of
    one: per triangle, the lattice A + (i/m) AB + (j/n) AC (i/m + j/n <= 1) from its
    widest-angled corner A, with steps of at most `spacing` along both edges. (A point lies in a
    lattice cell, or in a cell cut by the far edge, whose kept corner is at most one step along
    each edge away.) Returns the points (S, 3) and the triangle each lies on (S,)."""
    tri = np.asarray(triangles, np.float64)
    # widest angle at the corner opposite the longest edge
    edge = np.linalg.norm(np.roll(tri, -1, axis=1) - np.roll(tri, 1, axis=1), axis=-1)   # (F, 3): opposite each corner
    a = edge.argmax(1)
    F = np.arange(len(tri))
    A, B, C = tri[F, a], tri[F, (a + 1) % 3], tri[F, (a + 2) % 3]
    m = np.maximum(np.ceil(np.linalg.norm(B - A, axis=-1) / spacing), 1).astype(np.int64)
    n = np.maximum(np.ceil(np.linalg.norm(C - A, axis=-1) / spacing), 1).astype(np.int64)
    out, owner = [tri.reshape(-1, 3)], [np.repeat(F, 3)]
    big = (m > 1) | (n > 1)
    for mm, nn in {(int(x), int(y)) for x, y in zip(m[big], n[big])}:
        sel = big & (m == mm) & (n == nn)
        i, j = np.meshgrid(np.arange(mm + 1) / mm, np.arange(nn + 1) / nn, indexing="ij")
        keep = i + j <= 1 + 1e-9
        w = np.stack([i[keep], j[keep]], -1)                                             # (k, 2)
        pts = A[sel, None] + w[None, :, :1] * (B - A)[sel, None] + w[None, :, 1:] * (C - A)[sel, None]
        out.append(pts.reshape(-1, 3))
        owner.append(np.repeat(F[sel], len(w)))
    return np.concatenate(out), np.concatenate(owner)


def winding_numbers(points: np.ndarray, triangles: np.ndarray, chunk: int = 1 << 21) -> np.ndarray:
    """Generalised winding numbers (P,) of points (P, 3) with respect to triangles (F, 3, 3)
    (solid angles, Van Oosterom & Strackee): ~1 inside a closed surface, ~0 outside, 2 where
    two closed parts overlap."""
    out = np.zeros(len(points))
    step = max(1, chunk // max(len(triangles), 1))
    for s in range(0, len(points), step):
        a = triangles[None, :, 0] - points[s:s + step, None]                     # (p, F, 3)
        b = triangles[None, :, 1] - points[s:s + step, None]
        c = triangles[None, :, 2] - points[s:s + step, None]
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        num = np.einsum("pfc,pfc->pf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pfc,pfc->pf", a, b) * lc + np.einsum("pfc,pfc->pf", b, c) * la
               + np.einsum("pfc,pfc->pf", c, a) * lb)
        out[s:s + step] = np.arctan2(num, den).sum(-1) / (2 * np.pi)
    return out


class MeshField(SurfaceField):
    """Exact signed distance to a triangle mesh (see the module docstring).

    spacing: surface-sample spacing of the culling k-d tree (default: voxel_size / 2);
    voxel_size: voxel of the solid occupancy grid that classifies points far from the surface;
    winding_faces: meshes with at most this many faces decide inside-ness near the surface by
    winding number (exact for overlapping parts), larger ones by the side of the closest face.
    """

    def __init__(self, mesh: trimesh.Trimesh, voxel_size: float = 0.02, spacing: float | None = None,
                 winding_faces: int = 5000):
        if len(mesh.faces) == 0:
            raise ValueError("mesh has no faces")
        self.voxel_size = float(voxel_size)
        self.spacing = float(spacing) if spacing else self.voxel_size / 2
        tri = np.asarray(mesh.triangles, np.float64)                              # (F, 3, 3)
        closed = solid_faces(mesh)                                               # (F,) bool
        self._solid = None
        if closed.any():
            sub = trimesh.Trimesh(mesh.vertices, np.asarray(mesh.faces)[closed], process=False)
            self._solid = voxelize_mesh(sub, self.voxel_size, mode="solid")
        self._winding = bool(closed.all()) and len(tri) <= winding_faces
        self._tri = tri
        if self._winding:
            # Faces buried inside another closed part (a chair leg's top inside its seat) are not
            # on the surface of the union: drop them, or they would be "nearest" to points inside.
            # A point just outside a face (off its centroid along the normal) is in no part iff
            # the face is on the union's surface; faces shared by touching parts go as well.
            probe = tri.mean(1) + 1e-5 * np.asarray(mesh.face_normals, np.float64)
            keep = winding_numbers(probe, tri) < 0.5
            if keep.any() and not keep.all():
                mesh = trimesh.Trimesh(mesh.vertices, np.asarray(mesh.faces)[keep], process=False)
        self.mesh = mesh
        self._normals = np.asarray(mesh.face_normals, np.float64)                 # (F', 3)
        self._mesh_tri = np.asarray(mesh.triangles, np.float64)                   # (F', 3, 3)
        self._box_lo, self._box_hi = self._mesh_tri.min(1), self._mesh_tri.max(1)  # (F', 3) each
        self._samples, self._owner = lattice_samples(self._mesh_tri, self.spacing)  # (S, 3), (S,)
        self._kd = cKDTree(self._samples)
        self._near: dict[float, OccupancyGrid] = {}
        if len(self._mesh_tri) > BOX_TEST_FACES:
            mesh.triangles_tree                                                    # noqa: B018 (build the r-tree once)

    def _near_grid(self, radius: float) -> OccupancyGrid:
        """Coarse voxels (NEAR_VOXEL) within `radius` of the surface, with room to spare: every
        point within `radius` of the surface lies in one. A lookup there is far cheaper than the
        k-d tree query, which then runs on those points only."""
        key = round(radius, 6)
        if key not in self._near:
            h = max(NEAR_VOXEL, self.voxel_size)
            pad = radius + 2 * self.spacing + 2 * np.sqrt(3.0) * h
            lo = np.floor((self._samples.min(0) - pad) / h) * h
            shape = tuple(int(v) for v in np.ceil((self._samples.max(0) + pad - lo) / h).astype(np.int64) + 1)
            occ = np.zeros(shape, bool)
            ijk = np.floor((self._samples - lo) / h).astype(np.int64)
            occ[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
            # centre-to-centre: a point to its voxel centre and a sample to its voxel centre are
            # each within half a diagonal
            occ = near_occupied(occ, (radius + 2 * self.spacing) / h + np.sqrt(3.0))
            self._near[key] = OccupancyGrid.from_dense(occ, lo, h)
        return self._near[key]

    def _closest(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Exact closest points (n, 3), distances (n,) and triangles (n,) of points q (n, 3).

        The nearest surface sample is at least as far as the nearest triangle, so every
        triangle that can be the closest has its bounding box within that distance of q: one
        vectorised r-tree query per point with that box (trimesh's own query boxes reach the
        nearest mesh *vertex*, metres away on a room's floor, and then try most triangles)."""
        nn, _ = self._kd.query(q)                                                  # (n,) >= true distance
        r = (nn + 1e-9)[:, None]
        F = len(self._mesh_tri)
        if F <= BOX_TEST_FACES:                    # a numpy box test beats the r-tree's per-box calls
            pts, tris = [], []
            step = max(1, (1 << 22) // F)
            for s in range(0, len(q), step):
                lo, hi = q[s:s + step] - r[s:s + step], q[s:s + step] + r[s:s + step]       # (m, 3)
                hit = (self._box_lo[:, 0] <= hi[:, :1]) & (self._box_hi[:, 0] >= lo[:, :1])   # (m, F)
                for a in (1, 2):
                    hit &= (self._box_lo[:, a] <= hi[:, a:a + 1]) & (self._box_hi[:, a] >= lo[:, a:a + 1])
                i, j = np.nonzero(hit)
                pts.append(i + s)
                tris.append(j)
            pt, tri = np.concatenate(pts), np.concatenate(tris)
        else:
            tri, counts = self.mesh.triangles_tree.intersection_v(q - r, q + r)
            pt = np.repeat(np.arange(len(q)), np.asarray(counts, np.int64))
        return self._closest_of(q, pt, np.asarray(tri, np.int64), F)

    def _closest_of(self, q, pt, tri, n_tri):
        """Closest of the candidate (point, triangle) pairs, per point (points without pairs: inf)."""
        key = np.unique(pt * n_tri + tri)
        pt, tri = key // n_tri, key % n_tri
        c = trimesh.triangles.closest_point(self._mesh_tri[tri], q[pt])
        d = np.linalg.norm(c - q[pt], axis=-1)
        order = np.lexsort((d, pt))                                              # per point, nearest first
        first = order[np.r_[True, pt[order][1:] != pt[order][:-1]]]
        out_c, out_d, out_t = np.zeros_like(q), np.full(len(q), np.inf), np.zeros(len(q), np.int64)
        rows = pt[first]
        out_c[rows], out_d[rows], out_t[rows] = c[first], d[first], tri[first]
        return out_c, out_d, out_t

    def _local(self, p, max_distance):
        N = len(p)
        d = np.full(N, np.inf)
        u = np.zeros_like(p)
        # Beyond `reach` from the surface, a point's voxel centre is on the same side as it.
        reach = max(max_distance, SQRT3_2 * self.voxel_size if self._solid is not None else 0.0)
        exact = self._near_grid(reach).occupied(p, outside=False) if np.isfinite(reach) else np.ones(N, bool)
        if exact.any() and np.isfinite(reach):
            kd_d, _ = self._kd.query(p[exact], distance_upper_bound=reach + 2 * self.spacing)
            exact[exact] = np.isfinite(kd_d)
        solid = self._solid.occupied(p, outside=False) if self._solid is not None else np.zeros(N, bool)
        exact |= solid                                                            # deep inside: depth wanted
        if not exact.any():
            return d, u
        rows = np.flatnonzero(exact)
        q = p[rows]
        c, dist, tri_id = self._closest(q)
        n = self._normals[tri_id]
        inside = solid[rows].copy()
        near = dist <= SQRT3_2 * self.voxel_size if self._solid is not None else np.ones(len(q), bool)
        if near.any():
            # The side of the closest face is exact when the closest point is inside that face;
            # on an edge or a corner the faces there can disagree: winding number (small meshes).
            inside[near] = np.einsum("nc,nc->n", q[near] - c[near], n[near]) < 0
            if self._winding:
                bary = trimesh.triangles.points_to_barycentric(self._mesh_tri[tri_id[near]], c[near])
                edge = np.flatnonzero(near)[bary.min(1) < 1e-6]
                if len(edge):
                    inside[edge] = winding_numbers(q[edge], self._tri) > 0.5
        v = c - q
        ok = dist > 1e-9
        u[rows] = np.where(ok[:, None], v / np.maximum(dist, 1e-12)[:, None], -n)
        d[rows] = np.where(inside, -dist, dist)
        return d, u


def surface_distance(grid: OccupancyGrid, floor_y: float | None = None):
    """The grid's signed distance field (`GridField`: call it for distances, `.query` for
    directions and nearest points), built on first use and kept with the grid (a field costs
    a KD-tree over every boundary voxel); `floor_y` adds the floor half-space y < floor_y."""
    if grid._distance is None:
        grid._distance = GridField(grid)
    return grid._distance if floor_y is None else UnionField(grid._distance, PlaneField(floor_y))
