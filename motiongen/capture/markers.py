"""Virtual body-surface markers on the SMPL-X mesh, for the LEMO motion priors.

The LEMO supplement represents a body by markers on its mesh surface: 67 body markers
following the SSM2 marker setting of MoSh / AMASS, plus 14 extra markers on the face and the
fingertips that only its smoothness prior uses. SSM2 itself is a capture layout with a few
left/right inconsistencies (e.g. an inner-forearm marker on one arm only); the set here keeps
its names where their meaning is clear and makes it exactly symmetric, which the priors'
left/right mirroring augmentation needs.

Markers are defined geometrically from the model, never by hard-coded vertex ids, so the same
definitions work on the repository's procedural body and on a real SMPL-X file: a left-side or
midline marker is the surface vertex where a ray from an anchor (built from the rest-pose
joints) along a direction leaves the mesh, among the vertices skinned mainly to the intended
joints; a right-side marker is the vertex of the mirrored joints nearest to its left twin's
rest position mirrored (x -> -x). Rest-pose axes (SMPL-X): the body faces +z, y is up, its
left is +x. Fingertips are the vertices farthest from the wrist on each distal finger joint.

Order matters: the priors convolve (3 x 3) over the marker axis, so neighbours in
`MARKER_NAMES` are neighbours on the body (head, torso, left arm, right arm, pelvis, left leg,
right leg; then face and fingertips).
"""

from __future__ import annotations

import weakref
from typing import Callable, NamedTuple

import numpy as np
import torch
from scipy.spatial import cKDTree

from motiongen.body.procedural import SMPLX_JOINT_NAMES
from motiongen.body.rotations import axis_angle_to_matrix
from motiongen.skeleton import NUM_BODY_JOINTS

BODY_MARKER_NAMES: tuple[str, ...] = (
    # head
    "LFHD", "RFHD", "LCHEEK", "RCHEEK", "LBHD", "RBHD",
    # torso: back of the neck down the back, round the side, up the front to the clavicle
    "C7", "T8", "LBSH", "RBSH", "LBAK", "RBAK", "LRIB", "RRIB", "MBLLY", "LNWST", "RNWST",
    "STRN", "LBUST", "RBUST", "CLAV",
    # left arm, shoulder to hand
    "LSHO", "LBCEP", "LELB", "LELBIN", "LFRM", "LOWR", "LIWR", "LFIN", "LTHMB",
    # right arm
    "RSHO", "RBCEP", "RELB", "RELBIN", "RFRM", "ROWR", "RIWR", "RFIN", "RTHMB",
    # pelvis
    "LFWT", "RFWT", "LBWT", "RBWT", "LBUM", "RBUM",
    # left leg, hip to toe
    "LTHI", "LFTHI", "LFTHIIN", "LKNE", "LKNI", "LTIB", "LANK", "LHEE", "LMT5", "LMT1", "LTOE",
    # right leg
    "RTHI", "RFTHI", "RFTHIIN", "RKNE", "RKNI", "RTIB", "RANK", "RHEE", "RMT5", "RMT1", "RTOE",
)
EXTRA_MARKER_NAMES: tuple[str, ...] = (
    "LBROW", "RBROW", "NOSE", "CHIN",
    "LTHUMBT", "LINDEXT", "LMIDDLET", "LRINGT", "LPINKYT",
    "RTHUMBT", "RINDEXT", "RMIDDLET", "RRINGT", "RPINKYT",
)
MARKER_NAMES: tuple[str, ...] = BODY_MARKER_NAMES + EXTRA_MARKER_NAMES
NUM_BODY_MARKERS = len(BODY_MARKER_NAMES)   # 67
NUM_MARKERS = len(MARKER_NAMES)             # 81


def _mirror_name(name: str) -> str:
    twin = {"L": "R", "R": "L"}.get(name[0], "") + name[1:]
    return twin if twin in MARKER_NAMES else name


# (81,) index of each marker's left/right twin (itself on the midline).
MIRROR: np.ndarray = np.array([MARKER_NAMES.index(_mirror_name(n)) for n in MARKER_NAMES], np.int64)

# SMPL-X leg joints: hips, knees, ankles, feet.
LOWER_BODY_JOINTS: tuple[int, ...] = (1, 2, 4, 5, 7, 8, 10, 11)

# ---- definitions -----------------------------------------------------------------------

_J = {n: i for i, n in enumerate(SMPLX_JOINT_NAMES)}
(_PELVIS, _HIP, _SPINE1, _KNEE, _SPINE2, _ANKLE, _SPINE3, _FOOT, _NECK, _COLLAR, _HEAD, _SHOULDER, _ELBOW, _WRIST,
 _JAW, _EYE) = (
    _J[n] for n in ("pelvis", "left_hip", "spine1", "left_knee", "spine2", "left_ankle", "spine3", "left_foot",
                    "neck", "left_collar", "head", "left_shoulder", "left_elbow", "left_wrist", "jaw",
                    "left_eye_smplhf"))
# Each joint's left/right twin in the full 55-joint list (SMPL-X names say which is which).
_JOINT_MIRROR = np.array([_J[n.replace("left_", "@").replace("right_", "left_").replace("@", "right_")]
                          for n in SMPLX_JOINT_NAMES])


class _Spec(NamedTuple):
    anchor: Callable[["_Frame"], np.ndarray]   # rest-pose point (3,) inside the body
    direction: tuple | None                      # ray direction; None: farthest vertex from the anchor
    joints: tuple[int, ...]                      # candidate vertices are skinned mainly to these


class _Frame(NamedTuple):
    J: np.ndarray      # (55, 3) rest joints
    head: np.ndarray   # (3,) centre of the head's bounding box (the joints say little about the skull)


def _mix(a, b, t):
    return (1 - t) * a + t * b


def _at(p, x=None, y=None):
    """p (3,) with x and/or y replaced."""
    p = np.array(p, np.float64)
    if x is not None:
        p[0] = x
    if y is not None:
        p[1] = y
    return p


_HEAD_PART = (_HEAD, _JAW)   # the eyeballs are left out: markers sit on skin
_TORSO = (_PELVIS, _SPINE1, _SPINE2, _SPINE3, _NECK)
# Left-side and midline markers; right ones are their mirrors. Directions: +z front, +y up, +x left.
# In the SMPL-X T-pose the palms face down, so the elbow's lateral epicondyle points up (+y),
# the olecranon back, the biceps front, and the thumb (radial) side of the wrist front.
_SPECS: dict[str, _Spec] = {
    "LFHD": _Spec(lambda f: f.head, (0.4, 0.45, 0.8), _HEAD_PART),
    "LCHEEK": _Spec(lambda f: f.head, (0.55, -0.45, 0.7), _HEAD_PART),
    "LBHD": _Spec(lambda f: f.head, (0.4, 0.3, -0.85), _HEAD_PART),
    "C7": _Spec(lambda f: f.J[_NECK], (0, 0.2, -1), (_SPINE3, _NECK)),
    "T8": _Spec(lambda f: _mix(f.J[_SPINE2], f.J[_SPINE3], 0.3), (0, 0, -1), _TORSO),
    "LBSH": _Spec(lambda f: _at(_mix(f.J[_SPINE3], f.J[_SHOULDER], 0.5), y=f.J[_SHOULDER][1]), (0, 0.2, -1),
                  (_SPINE3, _COLLAR, _SPINE2)),
    "LBAK": _Spec(lambda f: _at(f.J[_SPINE3], x=0.45 * f.J[_SHOULDER][0]), (0, 0, -1), (_SPINE2, _SPINE3)),
    "LRIB": _Spec(lambda f: f.J[_SPINE2], (1, 0, 0), (_SPINE1, _SPINE2)),
    "MBLLY": _Spec(lambda f: f.J[_SPINE1], (0, 0, 1), (_PELVIS, _SPINE1, _SPINE2)),
    "LNWST": _Spec(lambda f: _at(f.J[_SPINE1], x=0.7 * f.J[_HIP][0]), (0.5, 0, 1), (_PELVIS, _SPINE1)),
    "STRN": _Spec(lambda f: _mix(f.J[_SPINE3], f.J[_SPINE2], 0.4), (0, 0, 1), (_SPINE2, _SPINE3)),
    "LBUST": _Spec(lambda f: _at(_mix(f.J[_SPINE3], f.J[_SPINE2], 0.5), x=0.5 * f.J[_SHOULDER][0]), (0, 0, 1),
                   (_SPINE2, _SPINE3)),
    "CLAV": _Spec(lambda f: _mix(f.J[_NECK], f.J[_SPINE3], 0.25), (0, 0, 1), (_SPINE3, _NECK, _COLLAR, _COLLAR + 1)),
    "LSHO": _Spec(lambda f: _mix(f.J[_SHOULDER], f.J[_COLLAR], 0.3), (0, 1, 0), (_COLLAR, _SHOULDER, _SPINE3)),
    "LBCEP": _Spec(lambda f: _mix(f.J[_SHOULDER], f.J[_ELBOW], 0.5), (0, 0.3, 1), (_SHOULDER,)),
    "LELB": _Spec(lambda f: f.J[_ELBOW], (0, 1, 0), (_SHOULDER, _ELBOW)),
    "LELBIN": _Spec(lambda f: f.J[_ELBOW], (0, -1, 0), (_SHOULDER, _ELBOW)),
    "LFRM": _Spec(lambda f: _mix(f.J[_ELBOW], f.J[_WRIST], 0.5), (0, 1, -0.3), (_ELBOW,)),
    "LOWR": _Spec(lambda f: f.J[_WRIST], (0, 0, 1), (_ELBOW, _WRIST)),
    "LIWR": _Spec(lambda f: f.J[_WRIST], (0, 0, -1), (_ELBOW, _WRIST)),
    "LFIN": _Spec(lambda f: _mix(f.J[_WRIST], f.J[_J["left_middle1"]], 0.7), (0, 1, 0), (_WRIST,)),
    "LTHMB": _Spec(lambda f: f.J[_J["left_thumb2"]], (0, 1, 0.3), (_J["left_thumb1"], _J["left_thumb2"])),
    # ASIS in front of and PSIS behind the pelvis, halfway up to spine1
    "LFWT": _Spec(lambda f: _at(_mix(f.J[_PELVIS], f.J[_SPINE1], 0.5), x=1.3 * f.J[_HIP][0]), (0.3, 0, 1),
                  (_PELVIS, _SPINE1)),
    "LBWT": _Spec(lambda f: _at(_mix(f.J[_PELVIS], f.J[_SPINE1], 0.5), x=0.7 * f.J[_HIP][0]), (0.1, 0, -1),
                  (_PELVIS, _SPINE1)),
    "LBUM": _Spec(lambda f: f.J[_HIP], (0, -0.2, -1), (_PELVIS, _HIP)),
    "LTHI": _Spec(lambda f: _mix(f.J[_HIP], f.J[_KNEE], 0.45), (1, 0, 0), (_HIP,)),
    "LFTHI": _Spec(lambda f: _mix(f.J[_HIP], f.J[_KNEE], 0.3), (0, 0, 1), (_HIP,)),
    "LFTHIIN": _Spec(lambda f: _mix(f.J[_HIP], f.J[_KNEE], 0.6), (-0.7, 0, 0.7), (_HIP,)),
    "LKNE": _Spec(lambda f: f.J[_KNEE], (1, 0, 0), (_HIP, _KNEE)),
    "LKNI": _Spec(lambda f: f.J[_KNEE], (-1, 0, 0), (_HIP, _KNEE)),
    "LTIB": _Spec(lambda f: _mix(f.J[_KNEE], f.J[_ANKLE], 0.45), (0, 0, 1), (_KNEE,)),
    "LANK": _Spec(lambda f: f.J[_ANKLE], (1, 0, 0), (_KNEE, _ANKLE)),
    "LHEE": _Spec(lambda f: f.J[_ANKLE], (0, -0.4, -1), (_ANKLE,)),
    "LMT5": _Spec(lambda f: _mix(f.J[_ANKLE], f.J[_FOOT], 0.75), (1, 0, 0), (_ANKLE, _FOOT)),
    "LMT1": _Spec(lambda f: _mix(f.J[_ANKLE], f.J[_FOOT], 0.75), (-1, 0, 0), (_ANKLE, _FOOT)),
    "LTOE": _Spec(lambda f: f.J[_FOOT], (0, 0.7, 1), (_ANKLE, _FOOT)),
    # face: the brow above the eye, the nose below the eyes, the chin in front of the jaw
    "LBROW": _Spec(lambda f: f.J[_EYE], (0, 0.6, 1), _HEAD_PART),
    "NOSE": _Spec(lambda f: _mix(f.J[_EYE], f.J[_EYE + 1], 0.5), (0, -0.4, 1), _HEAD_PART),
    "CHIN": _Spec(lambda f: f.J[_JAW], (0, -0.8, 0.6), _HEAD_PART),
    **{f"L{finger.upper()}T": _Spec(lambda f: f.J[_WRIST], None, (_J[f"left_{finger}3"],))
       for finger in ("thumb", "index", "middle", "ring", "pinky")},
}


def _ray_exit(V: np.ndarray, cand: np.ndarray, anchor: np.ndarray, direction) -> int:
    """The candidate vertex (of V (N, 3)) where the ray anchor + s·direction leaves the surface:
    the farthest along the ray within a thin cylinder around it, widened until one is found."""
    d = np.asarray(direction, np.float64)
    d /= np.linalg.norm(d)
    rel = V[cand] - anchor                                   # (n, 3)
    s = rel @ d                                              # (n,) distance along the ray
    perp = np.linalg.norm(rel - s[:, None] * d, axis=1)      # (n,) distance from it
    for r in (0.01, 0.02, 0.04, 0.08):
        hit = (s > 1e-3) & (perp < r)     # s > 1 mm: not a tube's end-cap centre at the anchor
        if hit.any():
            # the farthest out, with a tie-break towards the ray itself
            return int(cand[hit][np.argmax((s - perp)[hit])])
    raise ValueError(f"no vertex of the intended part lies along the ray from {anchor} towards {d}")


def _symmetric(V: np.ndarray, cand: np.ndarray, twins: np.ndarray, midline: bool, tol: float = 2e-3) -> np.ndarray:
    """The candidates that have a mirror image among `twins` (vertex ids of the mirrored
    part) within `tol`, or on the midline (|x| < tol): so the right-side twin of a marker sits
    at its mirror image. A symmetric mesh (SMPL-X) keeps them all; the procedural one loses
    the vertices its refinement added on one side only. Falls back to all if none qualify."""
    if midline:
        keep = np.abs(V[cand, 0]) < tol
    else:
        dist, _ = cKDTree(V[twins]).query(V[cand] * np.array([-1.0, 1.0, 1.0]))
        keep = dist < tol
    return cand[keep] if keep.any() else cand


def _place(bm) -> np.ndarray:
    """(81,) vertex ids of the markers on bm's rest-pose mesh."""
    V = bm.template_vertices                                              # (N, 3)
    owner = np.asarray(bm.skinning_weights).argmax(1)                     # (N,) main joint of each vertex
    J = bm.rest_joints(None, body_only=False).detach().cpu().numpy().astype(np.float64)
    head_v = V[bm.part_vertices(_HEAD)]
    frame = _Frame(J, 0.5 * (head_v.min(0) + head_v.max(0)))
    ids = np.full(NUM_MARKERS, -1, np.int64)
    for m, name in enumerate(MARKER_NAMES):
        if name in _SPECS:
            spec = _SPECS[name]
            twins = np.flatnonzero(np.isin(owner, _JOINT_MIRROR[list(spec.joints)]))
            cand = _symmetric(V, np.flatnonzero(np.isin(owner, spec.joints)), twins, MIRROR[m] == m)
            anchor = np.asarray(spec.anchor(frame), np.float64)
            if spec.direction is None:
                ids[m] = cand[np.argmax(np.linalg.norm(V[cand] - anchor, axis=1))]
            else:
                ids[m] = _ray_exit(V, cand, anchor, spec.direction)
    for m in np.flatnonzero(ids < 0):   # right side: nearest to the mirrored left twin
        twin = MIRROR[m]
        cand = np.flatnonzero(np.isin(owner, _JOINT_MIRROR[list(_SPECS[MARKER_NAMES[twin]].joints)]))
        target = V[ids[twin]] * np.array([-1.0, 1.0, 1.0])
        ids[m] = cand[np.argmin(np.linalg.norm(V[cand] - target, axis=1))]
    return ids


# Per model object: placement reads the mesh of that very model, so ids are never stale.
_CACHE: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _cached(bm) -> tuple[np.ndarray, np.ndarray]:
    if bm not in _CACHE:
        ids = _place(bm)
        owner = np.asarray(bm.skinning_weights)[ids].argmax(1)           # (81,) joint of the largest weight
        joints = np.array([_body_ancestor(bm.full_parents, int(j)) for j in owner], np.int64)
        _CACHE[bm] = (ids, joints)
    return _CACHE[bm]


def _body_ancestor(parents, j: int) -> int:
    """Walk finger, eye and jaw joints up the kinematic tree to a body joint (< 22)."""
    while j >= NUM_BODY_JOINTS:
        j = parents[j]
    return j


# ---- public API ------------------------------------------------------------------------

def marker_vertices(bm) -> np.ndarray:
    """(81,) int64 vertex ids of the markers on `bm`'s mesh (a `BodyModel`), cached per model
    (a copy: callers may edit it)."""
    return _cached(bm)[0].copy()


def marker_joints(bm) -> np.ndarray:
    """(81,) int64 body joint (0..21) each marker moves with: the joint of the largest skinning
    weight at its vertex, walked up the full kinematic tree for face and finger joints."""
    return _cached(bm)[1].copy()


def markers_of_joints(bm, joints) -> np.ndarray:
    """(81,) bool: markers whose `marker_joints` is in `joints` (e.g. `LOWER_BODY_JOINTS`)."""
    return np.isin(marker_joints(bm), np.asarray(joints))


def posed_markers(bm, rotmats: torch.Tensor, transl: torch.Tensor | None = None,
                  betas: torch.Tensor | None = None, ids=None) -> torch.Tensor:
    """Body rotation matrices (..., 22, 3, 3) (root first) -> marker positions (..., K, 3),
    K = 81 or len(ids) for marker indices `ids`; differentiable w.r.t. rotmats, transl (..., 3)
    and betas (nβ,) or (..., nβ)."""
    vid = marker_vertices(bm) if ids is None else _cached(bm)[0][np.asarray(ids)]
    return bm.vertices_from_rotmats(rotmats, transl, betas, vertex_ids=vid)


def params_markers(bm, params, ids=None, chunk: int = 256) -> np.ndarray:
    """(T, K, 3) markers of a motion's parameters: global_orient (T, 3), body_pose (T, 63),
    transl (T, 3) and betas (nβ,) (a `FitResult`, `BodyParams`, ...), without gradients, in
    chunks of `chunk` frames so long motions stay small in memory."""
    dev, dt = bm.J_template.device, bm.J_template.dtype

    def t(a):
        return torch.as_tensor(np.asarray(a), dtype=dt, device=dev)

    aa = torch.cat([t(params.global_orient)[:, None], t(params.body_pose).reshape(-1, NUM_BODY_JOINTS - 1, 3)], 1)
    transl, betas = t(params.transl), t(params.betas)          # (T, 22, 3) axis-angle, (T, 3), (nβ,)
    out = []
    with torch.no_grad():
        for s in range(0, len(aa), chunk):
            R = axis_angle_to_matrix(aa[s:s + chunk])           # (n, 22, 3, 3)
            out.append(posed_markers(bm, R, transl[s:s + chunk], betas, ids).cpu().numpy())
    k = NUM_MARKERS if ids is None else len(marker_vertices(bm)[np.asarray(ids)])
    return np.concatenate(out) if out else torch.zeros((0, k, 3), dtype=dt).numpy()
