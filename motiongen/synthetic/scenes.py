"""Procedural furnished rooms: layouts of TRUMANS object types built from boxes, their meshes,
exact occupancy grids, and where a person can sit, lie down or pick something up.

Furniture is rotated by multiples of 90 degrees only, so every primitive stays an axis-aligned
box and the occupancy grid is exact (a voxel is occupied iff it overlaps a box). Small objects
(cups, bottles, books) are movable: they are separate meshes with per-frame poses, not part of
the scene grid or mesh.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from motiongen.scene.occupancy import OccupancyGrid

VOXEL = 0.02
GRID_HEIGHT = 2.0      # TRUMANS grids cover y in [0, 2] m
WALL = 0.1             # wall thickness, inside the room extents
WALL_MESH_HEIGHT = 2.5
MAX_OBJECTS = 4        # movable objects per scene = object slots per frame


@dataclass
class Seat:
    """Somewhere to sit: stand at `stand_xz` facing `yaw`, then lower the pelvis onto `surface`."""
    surface: np.ndarray    # (3,) point of the seat surface under the seated pelvis, world
    yaw: float             # facing while seated
    stand_xz: np.ndarray   # (2,) pelvis (x, z) standing in front of the seat
    pre_xz: np.ndarray     # (2,) a free point the walking path ends at before the final approach


@dataclass
class Bed:
    edge: Seat             # sitting on the side of the mattress
    lie_surface: np.ndarray  # (3,) mattress surface under the pelvis when lying on the centre line
    head_dir: np.ndarray   # (3,) unit, horizontal, towards the headboard


@dataclass
class Item:
    """A movable small object resting on a surface."""
    type: str
    mesh: trimesh.Trimesh  # local frame: origin at the object's centre
    rest: np.ndarray       # (4, 4) resting pose, world
    radius: float          # bounding radius, m
    stand_xz: np.ndarray   # (2,) where to stand to reach it
    pre_xz: np.ndarray     # (2,)
    yaw: float             # facing while reaching


@dataclass
class Scene:
    id: int
    size: tuple[float, float]  # room (width along x, depth along z), m, walls included
    boxes: np.ndarray          # (B, 2, 3) world min/max corners of every static primitive
    furniture: list[str]       # type of each furniture piece placed
    seats: list[Seat] = field(default_factory=list)
    beds: list[Bed] = field(default_factory=list)
    items: list[Item] = field(default_factory=list)

    def grid(self) -> OccupancyGrid:
        W, D = self.size
        origin = np.array([-W / 2, 0.0, -D / 2])
        shape = tuple(int(round(v / VOXEL)) for v in (W, GRID_HEIGHT, D))
        dense = np.zeros(shape, bool)  # (X, Y, Z)
        lo = np.floor((self.boxes[:, 0] - origin) / VOXEL + 1e-6).astype(int)
        hi = np.ceil((self.boxes[:, 1] - origin) / VOXEL - 1e-6).astype(int)
        lo, hi = np.clip(lo, 0, shape), np.clip(hi, 0, shape)
        for (i0, j0, k0), (i1, j1, k1) in zip(lo, hi):
            dense[i0:i1, j0:j1, k0:k1] = True
        return OccupancyGrid.from_dense(dense, origin, VOXEL)

    def mesh(self) -> trimesh.Trimesh:
        W, D = self.size
        floor = np.array([[-W / 2, -0.05, -D / 2], [W / 2, 0.0, D / 2]])
        return trimesh.util.concatenate([_box_mesh(b) for b in [floor, *self.boxes]])


def _box_mesh(b: np.ndarray) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=b[1] - b[0], transform=trimesh.transformations.translation_matrix((b[0] + b[1]) / 2))


def _b(x0, x1, y0, y1, z0, z1) -> np.ndarray:
    return np.array([[x0, y0, z0], [x1, y1, z1]], float)


# ---------------------------------------------------------------------------------------
# Furniture in its own frame: footprint centred on the origin, front towards +z, floor y=0.
# Each builder returns (boxes, footprint half extents (hx, hz), approach zones, anchors);
# a zone is (x0, x1, z0, z1) that must stay clear of other furniture.


def _leg_boxes(hx, hz, h, t=0.04):
    """Four square legs of side t in the corners of a (2hx, 2hz) footprint."""
    out = []
    for sx in (-1, 1):
        for sz in (-1, 1):
            cx, cz = sx * (hx - t / 2), sz * (hz - t / 2)
            out.append(_b(cx - t / 2, cx + t / 2, 0, h, cz - t / 2, cz + t / 2))
    return out


def chair(rng):
    w, d, h = rng.uniform(0.42, 0.5), rng.uniform(0.42, 0.5), rng.uniform(0.42, 0.48)
    hx, hz = w / 2, d / 2
    boxes = _leg_boxes(hx, hz, h - 0.04) + [_b(-hx, hx, h - 0.04, h, -hz, hz),
                                            _b(-hx, hx, h, h + rng.uniform(0.4, 0.5), -hz, -hz + 0.04)]
    zones = [(-0.4, 0.4, hz, hz + 0.9)]
    seats = [(np.array([0.0, h, -0.03]), np.array([0.0, hz + 0.15]), np.array([0.0, hz + 0.6]))]
    return boxes, (hx, hz), zones, {"seats": seats}


def sofa(rng):
    w, d, h = rng.uniform(1.6, 2.2), rng.uniform(0.8, 0.95), rng.uniform(0.4, 0.45)
    hx, hz, arm = w / 2, d / 2, 0.15
    boxes = [_b(-hx + arm, hx - arm, 0, h, -hz + 0.2, hz),          # seat base
             _b(-hx, hx, 0, h + 0.42, -hz, -hz + 0.2),              # back
             _b(-hx, -hx + arm, 0, h + 0.2, -hz + 0.2, hz),         # arms
             _b(hx - arm, hx, 0, h + 0.2, -hz + 0.2, hz)]
    n = 3 if w > 1.9 else 2
    xs = np.linspace(-hx + arm, hx - arm, 2 * n + 1)[1::2]
    seats = [(np.array([x, h, -hz + 0.42]), np.array([x, hz + 0.15]), np.array([x, hz + 0.6])) for x in xs]
    return boxes, (hx, hz), [(-hx, hx, hz, hz + 0.9)], {"seats": seats}


def bed(rng, side: int):
    """Headboard at -z; the person gets in from the `side` (+1: +x, -1: -x) long edge."""
    w, L, h = rng.uniform(1.4, 1.8), 2.05, rng.uniform(0.45, 0.55)
    hx, hz = w / 2, L / 2
    boxes = [_b(-hx, hx, 0, h, -hz + 0.06, hz), _b(-hx, hx, 0, 1.0, -hz, -hz + 0.06)]
    zp = -hz + 0.06 + 0.15 + 0.74 * 1.05          # pelvis along the bed for a ~1.8 m sleeper
    edge = (np.array([side * (hx - 0.2), h, zp]), np.array([side * (hx + 0.15), zp]), np.array([side * (hx + 0.6), zp]))
    zone = (hx, hx + 0.9, zp - 0.45, zp + 0.45) if side > 0 else (-hx - 0.9, -hx, zp - 0.45, zp + 0.45)
    return boxes, (hx, hz), [zone], {"bed": (edge, np.array([0.0, h, zp]), side)}


def table(rng):
    w, d, h = rng.uniform(1.0, 1.6), rng.uniform(0.7, 0.9), rng.uniform(0.72, 0.78)
    hx, hz = w / 2, d / 2
    boxes = _leg_boxes(hx, hz, h - 0.04) + [_b(-hx, hx, h - 0.04, h, -hz, hz)]
    zones = [(-hx, hx, hz, hz + 0.8), (-hx, hx, -hz - 0.8, -hz)]
    return boxes, (hx, hz), zones, {"top": (h, hx - 0.12)}


def cabinet(rng):
    w, d, h = rng.uniform(0.6, 1.0), rng.uniform(0.4, 0.5), rng.uniform(0.8, 1.15)
    hx, hz = w / 2, d / 2
    return [_b(-hx, hx, 0, h, -hz, hz)], (hx, hz), [(-max(hx, 0.4), max(hx, 0.4), hz, hz + 0.8)], {"top": (h, hx - 0.1)}


def small_object(kind: str, rng) -> tuple[trimesh.Trimesh, float, float]:
    """Mesh centred on the origin, its height, its bounding radius."""
    if kind == "cup":
        r, h = rng.uniform(0.035, 0.045), rng.uniform(0.09, 0.11)
        m = trimesh.creation.cylinder(radius=r, height=h, sections=16)
    elif kind == "bottle":
        r, h = rng.uniform(0.03, 0.04), rng.uniform(0.22, 0.28)
        m = trimesh.creation.cylinder(radius=r, height=h, sections=16)
    else:  # book, lying flat
        a, h, c = rng.uniform(0.18, 0.24), rng.uniform(0.025, 0.045), rng.uniform(0.13, 0.17)
        m = trimesh.creation.box(extents=(a, h, c))
        return m, h, float(np.linalg.norm([a, h, c]) / 2)
    # trimesh cylinders run along z; stand them up along y
    m.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))
    return m, h, float(np.hypot(r, h / 2))


SMALL_TYPES = ("cup", "bottle", "book")


# ---------------------------------------------------------------------------------------
# Layout


class _Placed:
    """A furniture piece in the room: yaw k*90deg, then translation (x, z)."""

    def __init__(self, kind, boxes, half, zones, anchors, k, x, z):
        self.kind, self.k, self.x, self.z, self.anchors = kind, k, x, z, anchors
        self.yaw = k * np.pi / 2
        self.boxes = np.stack([self._box(b) for b in boxes])
        self.foot = self._rect(-half[0], half[0], -half[1], half[1])
        self.zones = [self._rect(*zn) for zn in zones]

    def point(self, p_local: np.ndarray) -> np.ndarray:
        """Local point (..., 3) or (x, z) (..., 2) -> world."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        if p_local.shape[-1] == 2:
            x, z = p_local[..., 0], p_local[..., 1]
            return np.stack([c * x + s * z + self.x, -s * x + c * z + self.z], -1)
        x, y, z = p_local[..., 0], p_local[..., 1], p_local[..., 2]
        return np.stack([c * x + s * z + self.x, y, -s * x + c * z + self.z], -1)

    def dir(self, d_local: np.ndarray) -> np.ndarray:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([c * d_local[0] + s * d_local[2], d_local[1], -s * d_local[0] + c * d_local[2]])

    def _rect(self, x0, x1, z0, z1) -> np.ndarray:
        pts = self.point(np.array([[x0, z0], [x1, z1]]))
        return np.array([pts.min(0), pts.max(0)])  # (2, 2) [min, max] of (x, z)

    def _box(self, b: np.ndarray) -> np.ndarray:
        pts = self.point(b)
        return np.array([np.minimum(pts[0], pts[1]), np.maximum(pts[0], pts[1])])


def _overlap(a: np.ndarray, b: np.ndarray, gap: float = 0.0) -> bool:
    return bool(np.all(a[0] < b[1] + gap) and np.all(b[0] < a[1] + gap))


def _inside(a: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    return bool(np.all(a[0] >= lo - 1e-9) and np.all(a[1] <= hi + 1e-9))


def _try_place(rng, placed: list[_Placed], lo, hi, kind, builder, against_wall: bool, tries=40):
    for _ in range(tries):
        boxes, half, zones, anchors = builder(rng)
        k = int(rng.integers(4))
        if against_wall:
            # Back (-z local) to the wall: yaw k faces away from wall k.
            ext = half[1] if k % 2 == 0 else half[0]
            along = half[0] if k % 2 == 0 else half[1]
            if k == 0:
                x, z = rng.uniform(lo[0] + along, hi[0] - along), lo[1] + ext
            elif k == 2:
                x, z = rng.uniform(lo[0] + along, hi[0] - along), hi[1] - ext
            elif k == 1:
                x, z = lo[0] + ext, rng.uniform(lo[1] + along, hi[1] - along)
            else:
                x, z = hi[0] - ext, rng.uniform(lo[1] + along, hi[1] - along)
        else:
            x, z = rng.uniform(lo[0] + 0.6, hi[0] - 0.6), rng.uniform(lo[1] + 0.6, hi[1] - 0.6)
        p = _Placed(kind, boxes, half, zones, anchors, k, x, z)
        if not _inside(p.foot, lo, hi):
            continue
        if any(_overlap(p.foot, q.foot, 0.1) or any(_overlap(p.foot, zq) for zq in q.zones) for q in placed):
            continue
        # A table needs one clear side to be reachable; others need all their zones.
        ok = [zn for zn in p.zones if _inside(zn, lo, hi) and not any(_overlap(zn, q.foot) for q in placed)]
        if (kind == "table" and not ok) or (kind != "table" and len(ok) != len(p.zones)):
            continue
        p.zones = ok
        p.anchors = dict(p.anchors, open_sides=[int(np.sign(((zn[0] + zn[1]) / 2 - (p.x, p.z)) @ p.dir(np.array([0, 0, 1.0]))[[0, 2]]))
                                                for zn in ok])
        placed.append(p)
        return p
    return None


def make_scene(scene_id: int, rng: np.random.Generator) -> Scene:
    W, D = round(rng.uniform(4.0, 6.0), 1), round(rng.uniform(5.0, 8.0), 1)
    lo = np.array([-W / 2 + WALL, -D / 2 + WALL])
    hi = -lo
    placed: list[_Placed] = []
    plan = []
    if rng.random() < 0.7:
        plan.append(("bed", lambda r, s=int(rng.choice([-1, 1])): bed(r, s), True))
    if rng.random() < 0.65:
        plan.append(("sofa", sofa, True))
    plan += [("cabinet", cabinet, True)] * int(rng.integers(1, 3))
    plan += [("table", table, False)] * int(rng.integers(1, 3))
    plan += [("chair", chair, rng.random() < 0.3) for _ in range(int(rng.integers(2, 5)))]
    for kind, builder, wall in plan:
        _try_place(rng, placed, lo, hi, kind, builder, wall)

    walls = [_b(-W / 2, W / 2, 0, WALL_MESH_HEIGHT, -D / 2, -D / 2 + WALL), _b(-W / 2, W / 2, 0, WALL_MESH_HEIGHT, D / 2 - WALL, D / 2),
             _b(-W / 2, -W / 2 + WALL, 0, WALL_MESH_HEIGHT, -D / 2, D / 2), _b(W / 2 - WALL, W / 2, 0, WALL_MESH_HEIGHT, -D / 2, D / 2)]
    scene = Scene(scene_id, (W, D), np.concatenate([np.stack(walls)] + [p.boxes for p in placed]),
                  [p.kind for p in placed])
    surfaces = []
    for p in placed:
        for pel, stand, pre in p.anchors.get("seats", []):
            scene.seats.append(Seat(p.point(pel), p.yaw, p.point(stand), p.point(pre)))
        if "bed" in p.anchors:
            (pel, stand, pre), lie, side = p.anchors["bed"]
            edge = Seat(p.point(pel), p.yaw + side * np.pi / 2, p.point(stand), p.point(pre))
            scene.beds.append(Bed(edge, p.point(lie), p.dir(np.array([0.0, 0.0, -1.0]))))
        if "top" in p.anchors:
            surfaces += [(p, side) for side in p.anchors["open_sides"]]
    _place_items(scene, surfaces, rng)
    return scene


def _place_items(scene: Scene, surfaces, rng) -> None:
    """Put up to MAX_OBJECTS small objects near the open edges of tables and cabinets."""
    if not surfaces:
        return
    n = int(rng.integers(2, MAX_OBJECTS + 1))
    used: list[np.ndarray] = []
    for _ in range(n * 4):
        if len(scene.items) >= n:
            break
        p, side = surfaces[int(rng.integers(len(surfaces)))]
        top, half_x = p.anchors["top"]
        hz = (p.foot[1] - p.foot[0])[0 if p.k % 2 else 1] / 2
        x = rng.uniform(-half_x, half_x)
        z = side * (hz - rng.uniform(0.08, 0.16))
        kind = SMALL_TYPES[int(rng.integers(len(SMALL_TYPES)))]
        mesh, h, radius = small_object(kind, rng)
        centre = p.point(np.array([x, top + h / 2, z]))
        if any(np.linalg.norm(centre[[0, 2]] - u[[0, 2]]) < 0.25 for u in used):
            continue
        used.append(centre)
        rest = np.eye(4)
        rest[:3, :3] = _yaw_mat(p.yaw + rng.uniform(-0.5, 0.5))
        rest[:3, 3] = centre
        stand, pre = p.point(np.array([x, side * (hz + 0.3)])), p.point(np.array([x, side * (hz + 0.65)]))
        # standing on local side +z means facing local -z
        scene.items.append(Item(kind, mesh, rest, radius, stand, pre, p.yaw + (np.pi if side > 0 else 0.0)))


def _yaw_mat(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
