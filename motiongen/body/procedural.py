"""A procedurally generated SMPL-X body-model file (official `.npz` layout, no licence needed).

Real SMPL-X files are licensed and never shipped, so tests and the embedded default use this
one. It is not a learned model, only the same *layout* with plausible content:

- 55 joints with SMPL-X names/order/kintree and adult proportions (about 1.7 m, y-up, facing
  +z, T-pose, pelvis at y = -0.35 like the real template);
- a coarse mesh of per-bone tubes (skinned to their bone, blended across each joint), refined
  to exactly 10475 vertices so that code indexing SMPL-X vertex ids (the `smplx` package's
  extra joints and landmarks) runs on it;
- 10 shape directions that change height, limb, torso, arm, shoulder and hip lengths, girth
  and head size (plus 10 tiny expression directions), pose blend shapes (a bulge at bent
  joints), identity hand PCA, landmark faces.

Each joint is regressed as the mean of a vertex ring centred on it, so J_regressor · v is
exact for every shape, and the `smplx` package loads the file and agrees with our kinematics.
The file is generated deterministically into the cache (`ensure_procedural_model`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from motiongen.paths import cache_dir

PROCEDURAL_VERSION = 1
NUM_VERTICES = 10475  # as in SMPL-X
NUM_JOINTS = 55
NUM_BETAS = 10
NUM_EXPRESSION = 10

SMPLX_JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck",
    "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "jaw", "left_eye_smplhf",
    "right_eye_smplhf",
    *[f"left_{f}{i}" for f in ("index", "middle", "pinky", "ring", "thumb") for i in (1, 2, 3)],
    *[f"right_{f}{i}" for f in ("index", "middle", "pinky", "ring", "thumb") for i in (1, 2, 3)],
)
SMPLX_PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15,
    20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38,
    21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50, 21, 52, 53,
)

# Rest offset from the parent (metres) for the centre line and left side; right mirrors x.
_OFFSETS = {
    "left_hip": (0.065, -0.09, 0.0), "spine1": (0.0, 0.11, -0.02),
    "left_knee": (0.035, -0.38, 0.005), "spine2": (0.0, 0.13, 0.0),
    "left_ankle": (-0.01, -0.40, -0.04), "spine3": (0.0, 0.055, 0.02),
    "left_foot": (0.02, -0.055, 0.12), "neck": (0.0, 0.21, -0.03),
    "left_collar": (0.07, 0.12, -0.01), "head": (0.0, 0.09, 0.05),
    "left_shoulder": (0.11, 0.035, -0.01), "left_elbow": (0.26, -0.01, -0.02),
    "left_wrist": (0.25, 0.01, 0.0), "jaw": (0.0, -0.02, 0.03),
    "left_eye_smplhf": (0.032, 0.06, 0.08),
    "left_index1": (0.095, 0.0, 0.025), "left_index2": (0.035, 0.0, 0.0), "left_index3": (0.025, 0.0, 0.0),
    "left_middle1": (0.1, 0.0, 0.005), "left_middle2": (0.038, 0.0, 0.0), "left_middle3": (0.027, 0.0, 0.0),
    "left_pinky1": (0.085, 0.0, -0.035), "left_pinky2": (0.025, 0.0, 0.0), "left_pinky3": (0.02, 0.0, 0.0),
    "left_ring1": (0.095, 0.0, -0.015), "left_ring2": (0.035, 0.0, 0.0), "left_ring3": (0.025, 0.0, 0.0),
    "left_thumb1": (0.025, -0.012, 0.03), "left_thumb2": (0.03, -0.005, 0.025), "left_thumb3": (0.025, 0.0, 0.02),
}
_PELVIS_REST = (0.0, -0.35, 0.0)

# (radius across x-ish, radius across the other axis) of the tube ending at each joint.
def _tube_radius(name: str) -> tuple[float, float]:
    base = name.replace("left_", "").replace("right_", "")
    table = {"hip": (0.08, 0.08), "spine1": (0.13, 0.10), "knee": (0.075, 0.075), "spine2": (0.14, 0.10),
             "ankle": (0.05, 0.05), "spine3": (0.15, 0.10), "foot": (0.045, 0.035), "neck": (0.05, 0.05),
             "collar": (0.05, 0.05), "head": (0.055, 0.055), "shoulder": (0.05, 0.05), "elbow": (0.045, 0.045),
             "wrist": (0.035, 0.03), "jaw": (0.02, 0.02), "eye_smplhf": (0.012, 0.012)}
    if base in table:
        return table[base]
    return (0.009, 0.008)  # fingers


def _rest_joints() -> np.ndarray:
    """(55, 3) rest joint positions."""
    J = np.zeros((NUM_JOINTS, 3))
    J[0] = _PELVIS_REST
    for j in range(1, NUM_JOINTS):
        name = SMPLX_JOINT_NAMES[j]
        off = np.array(_OFFSETS[name.replace("right_", "left_")], dtype=float)
        if name.startswith("right_"):
            off[0] = -off[0]
        J[j] = J[SMPLX_PARENTS[j]] + off
    return J


def _bone_scale_dirs() -> np.ndarray:
    """(55, 10) fractional change of each bone's length per unit of each beta."""
    S = np.zeros((NUM_JOINTS, NUM_BETAS))
    idx = {n: i for i, n in enumerate(SMPLX_JOINT_NAMES)}

    def both(base):
        return [idx[f"left_{base}"], idx[f"right_{base}"]] if f"left_{base}" in idx else [idx[base]]

    S[1:, 0] = 0.06                                   # overall size / height
    for b in ("knee", "ankle"):
        S[both(b), 1] += 0.07                         # leg length
    for b in ("spine1", "spine2", "spine3", "neck"):
        S[both(b), 1] -= 0.02
        S[both(b), 2] += 0.06                         # torso length
    S[both("hip"), 3] += 0.04                         # girth widens the hips a little
    fingers = [i for i, n in enumerate(SMPLX_JOINT_NAMES) if i >= 25]
    for b in ("elbow", "wrist"):
        S[both(b), 4] += 0.07                         # arm length
    S[fingers, 4] += 0.03
    for b in ("collar", "shoulder"):
        S[both(b), 5] += 0.08                         # shoulder width
    S[both("hip"), 6] += 0.10                         # hip width
    S[both("neck"), 7] += 0.08                        # neck / head
    S[both("head"), 7] += 0.05
    rng = np.random.default_rng(1234)
    for k in (8, 9):                                  # small symmetric per-bone variations
        for j in range(1, 22):
            name = SMPLX_JOINT_NAMES[j]
            if name.startswith("right_"):
                continue
            v = rng.uniform(-0.02, 0.02)
            S[both(name.replace("left_", "")), k] = v
    return S


def _girth_dirs() -> np.ndarray:
    """(10,) fractional change of tube radii per unit beta."""
    g = np.zeros(NUM_BETAS)
    g[0], g[3], g[7] = 0.04, 0.12, 0.02
    return g


def _frame(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to the unit direction d (and to each other)."""
    ref = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(ref, d)
    u /= np.linalg.norm(u)
    return u, np.cross(d, u)


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


class _TubeMesh:
    """The coarse body mesh being built, tube by tube: per-vertex lists of positions (3,), shape
    directions (3, 10), skinning weights (55,) and bulge rows (4,: normal * amount, joint), the
    faces, and the vertex ring regressed to each joint."""

    def __init__(self, girth: np.ndarray):
        self.girth = girth                                # (10,) fractional radius change per beta
        self.verts, self.sdirs, self.weights, self.faces, self.bulge = [], [], [], [], []
        self.regress: dict[int, list[int]] = {}           # joint -> vertex ids of the ring centred on it
        self.nv = 0

    def add_tube(self, a, b, Da, Db, ja, jb, radius, n_rings, n_around, leaf, regress_start=None, regress_end=None):
        """Tube from point a to b; rigid with joint ja, blending into jb near b unless leaf.
        Da, Db: (3, 10) shape directions of the end points."""
        d = b - a
        d = d / np.linalg.norm(d)
        u, v = _frame(d)
        phi = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
        ring_ids = []
        for t in np.linspace(0.0, 1.0, n_rings):
            # a slightly bulging profile so tubes look like limbs, not pipes
            prof = 1.0 + 0.15 * np.sin(np.pi * t) if n_rings > 2 else 1.0
            rho = (radius[0] * prof * np.cos(phi))[:, None] * u + (radius[1] * prof * np.sin(phi))[:, None] * v
            ring_ids.append(self._ring(a + t * (b - a), rho, Da + t * (Db - Da), ja, jb, t, leaf))
        for r in range(n_rings - 1):
            A, B = np.array(ring_ids[r]), np.array(ring_ids[r + 1])
            An, Bn = np.roll(A, -1), np.roll(B, -1)
            self.faces.append(np.stack([A, An, B], 1))
            self.faces.append(np.stack([An, Bn, B], 1))
        self._cap(a, Da, ja, ring_ids[0], first=True)
        self._cap(b, Db, ja, ring_ids[-1], first=False)
        if regress_start is not None:
            self.regress[regress_start] = ring_ids[0]
        if regress_end is not None:
            self.regress[regress_end] = ring_ids[-1]

    def _ring(self, centre, rho, D, ja, jb, t, leaf) -> list[int]:
        """One ring of vertices centre + rho (n, 3) at fraction t along the tube; returns their ids."""
        n_around = len(rho)
        w = np.zeros((n_around, NUM_JOINTS))
        blend = 0.0 if leaf else 0.5 * _smoothstep((t - 0.7) / 0.3)
        w[:, ja] = 1 - blend
        if not leaf:
            w[:, jb] += blend
        ids = list(range(self.nv, self.nv + n_around))
        self.verts.append(centre + rho)
        # shape: the centre follows the joints, the radial offset scales with girth
        self.sdirs.append(D[None] + rho[:, :, None] * self.girth[None, None, :])
        self.weights.append(w)
        nrm = rho / np.linalg.norm(rho, axis=1, keepdims=True)
        self.bulge.append(np.concatenate([nrm * blend, np.full((n_around, 1), jb if not leaf else -1)], 1))
        self.nv += n_around
        return ids

    def _cap(self, c, D, ja, ids, first: bool) -> None:
        """A fan closing an end ring `ids` around its centre c (rigid with joint ja)."""
        w = np.zeros((1, NUM_JOINTS))
        w[0, ja] = 1.0
        self.verts.append(c[None])
        self.sdirs.append(D[None])
        self.weights.append(w)
        self.bulge.append(np.array([[0.0, 0.0, 0.0, -1]]))
        A = np.array(ids)
        tri = np.stack([np.full_like(A, self.nv), np.roll(A, -1), A], 1) if first else \
            np.stack([np.full_like(A, self.nv), A, np.roll(A, -1)], 1)
        self.faces.append(tri)
        self.nv += 1


def _joint_shape_dirs(J: np.ndarray, parents: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(55, 3, 10) joint shape directions: each bone (J_j - J_parent) scales by S (55, 10)."""
    D = np.zeros((NUM_JOINTS, 3, NUM_BETAS))
    for j in range(1, NUM_JOINTS):
        p = parents[j]
        D[j] = D[p] + (J[j] - J[p])[:, None] * S[j][None, :]
    return D


def _add_body_tubes(mesh: _TubeMesh, J: np.ndarray, D: np.ndarray, S: np.ndarray, parents: np.ndarray) -> None:
    """A tube per bone, then leaf extensions: skull, toes, finger tips, jaw/eye ends (rigid with
    their joint)."""
    children = {j: [c for c in range(NUM_JOINTS) if parents[c] == j] for j in range(NUM_JOINTS)}
    for j in range(1, NUM_JOINTS):
        p = parents[j]
        big = j < 22
        mesh.add_tube(J[p], J[j], D[p], D[j], p, j, _tube_radius(SMPLX_JOINT_NAMES[j]),
                      n_rings=7 if big else 3, n_around=20 if big else 8, leaf=not children[j],
                      regress_start=0 if j == 3 else None, regress_end=j)
    ext = {15: (np.array([0.0, 0.2, 0.02]), (0.085, 0.095), 9, 24)}
    for j in range(NUM_JOINTS):
        if children[j] or j in ext:
            continue
        p = parents[j]
        bone = J[j] - J[p]
        length = {10: 0.06, 11: 0.06}.get(j, 0.6 * np.linalg.norm(bone))
        ext[j] = (bone / np.linalg.norm(bone) * length, _tube_radius(SMPLX_JOINT_NAMES[j]), 3, 8 if j >= 22 else 12)
    for j, (vec, rad, n_r, n_a) in sorted(ext.items()):
        # the extension scales like the bone it continues
        Dend = D[j] + vec[:, None] * S[j][None, :]
        mesh.add_tube(J[j], J[j] + vec, D[j], Dend, j, j, rad, n_r, n_a, leaf=True)


def _pose_blend_shapes(bl: np.ndarray) -> np.ndarray:
    """(V, 3, 486) posedirs from the bulge rows bl (V, 4). The diagonal of (R_j - I) sums to
    2(cos θ - 1), so a bent joint's nearby vertices bulge outwards by about 5 mm * (1 - cos θ) * 2."""
    posedirs = np.zeros((NUM_VERTICES, 3, 9 * (NUM_JOINTS - 1)))
    has = bl[:, 3] >= 1
    jj = bl[has, 3].astype(int)
    for k in (0, 4, 8):
        posedirs[np.nonzero(has)[0], :, 9 * (jj - 1) + k] = -0.005 * bl[has, :3]
    return posedirs


def build_procedural_model() -> dict[str, np.ndarray]:
    """Arrays of the procedural SMPL-X model, keyed as in the official `.npz`."""
    J = _rest_joints()
    parents = np.array(SMPLX_PARENTS)
    S = _bone_scale_dirs()
    D = _joint_shape_dirs(J, parents, S)
    mesh = _TubeMesh(_girth_dirs())
    _add_body_tubes(mesh, J, D, S, parents)
    v = np.concatenate(mesh.verts)            # (V0, 3)
    sd = np.concatenate(mesh.sdirs)           # (V0, 3, 10)
    w = np.concatenate(mesh.weights)          # (V0, 55)
    bl = np.concatenate(mesh.bulge)           # (V0, 4): bulge normal * amount, joint
    f = np.concatenate(mesh.faces).astype(np.int64)
    v, sd, w, bl, f = _refine_to(NUM_VERTICES, v, sd, w, bl, f)

    Jreg = np.zeros((NUM_JOINTS, NUM_VERTICES))
    for j, ids in mesh.regress.items():
        Jreg[j, ids] = 1.0 / len(ids)
    assert len(mesh.regress) == NUM_JOINTS
    posedirs = _pose_blend_shapes(bl)

    rng = np.random.default_rng(99)
    expr = np.zeros((NUM_VERTICES, 3, NUM_EXPRESSION))
    head = np.nonzero(w[:, 15] > 0.99)[0]
    expr[head] = rng.normal(0, 0.002, size=(len(head), 3, NUM_EXPRESSION))
    shapedirs = np.concatenate([sd, expr], -1)  # (V, 3, 20): 10 shape then 10 expression

    head_faces = np.nonzero(np.all(w[f][:, :, 15] > 0.99, axis=1))[0]
    lmk_faces_idx = head_faces[np.linspace(0, len(head_faces) - 1, 51).astype(int)]
    dyn = head_faces[np.linspace(0, len(head_faces) - 1, 79 * 17).astype(int)].reshape(79, 17)
    kintree = np.stack([np.array(SMPLX_PARENTS, dtype=np.int64), np.arange(NUM_JOINTS)])
    kintree[0, 0] = 4294967295  # the official files store the root's parent as uint32 -1
    return {
        "v_template": v.astype(np.float64),
        "shapedirs": shapedirs.astype(np.float64),
        "posedirs": posedirs.astype(np.float32),
        "J_regressor": Jreg.astype(np.float64),
        "weights": w.astype(np.float64),
        "kintree_table": kintree.astype(np.int64),
        "f": f.astype(np.int32),
        "hands_componentsl": np.eye(45), "hands_componentsr": np.eye(45),
        "hands_meanl": np.zeros(45), "hands_meanr": np.zeros(45),
        "lmk_faces_idx": lmk_faces_idx.astype(np.int64),
        "lmk_bary_coords": np.full((51, 3), 1.0 / 3.0),
        "dynamic_lmk_faces_idx": dyn.astype(np.int64),
        "dynamic_lmk_bary_coords": np.full((79, 17, 3), 1.0 / 3.0),
        "joint_names": np.array(SMPLX_JOINT_NAMES),
        "motiongen_procedural": np.array(PROCEDURAL_VERSION),
    }


def _refine_to(n_target, v, sd, w, bl, f):
    """Split faces at their centroids (one new vertex each) until there are n_target vertices.

    New vertices average their face's attributes and are never regressed to joints."""
    k = n_target - len(v)
    assert 0 <= k <= len(f), (len(v), len(f))
    pick = np.unique(np.linspace(0, len(f) - 1, k).round().astype(int))
    assert len(pick) == k
    tri = f[pick]                                        # (k, 3)
    new = np.arange(len(v), len(v) + k)
    v = np.concatenate([v, v[tri].mean(1)])
    sd = np.concatenate([sd, sd[tri].mean(1)])
    w = np.concatenate([w, w[tri].mean(1)])
    blnew = np.concatenate([np.zeros((k, 3)), np.full((k, 1), -1.0)], 1)
    bl = np.concatenate([bl, blnew])
    keep = np.ones(len(f), bool)
    keep[pick] = False
    a, b, c = tri.T
    f = np.concatenate([f[keep], np.stack([a, b, new], 1), np.stack([b, c, new], 1), np.stack([c, a, new], 1)])
    return v, sd, w, bl, f


def default_model_path() -> Path:
    return cache_dir() / "body" / f"SMPLX_NEUTRAL_procedural_v{PROCEDURAL_VERSION}.npz"


def ensure_procedural_model(path: str | Path | None = None) -> Path:
    """Generate the procedural model file at `path` (default: in the cache) unless present.

    Deterministic; written to a temporary file and renamed, so concurrent callers are safe.
    """
    path = Path(path) if path is not None else default_model_path()
    if path.is_file():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.npz")
    np.savez_compressed(tmp, **build_procedural_model())
    os.replace(tmp, path)
    return path
