"""BVH export of body motion on the SMPL-X skeleton (importable by Blender).

Two entry points:
- `joints_to_bvh(joints (T, 22, 3), fps)`: rotations are solved from joint positions. Each
  joint gets a frame from its bone direction plus a secondary direction for twist (pelvis
  from both hips, spine3 from the collars, knees from the foot, ...); its world rotation is
  that frame relative to the same frame in a T-pose template (y-up, facing +z, left at +x).
  Rest offsets are the median offsets observed in those frames, so a rigid input is
  reproduced exactly. Where a joint's secondary child is *not* rigid in its frame (CMU's
  spine moves against its hips through LowerBack), a zero-length helper joint
  ``<parent>_to_<child>`` is inserted to carry the extra rotation (`helpers=None`: only where
  needed). Non-rigid input (generated motion whose bone lengths vary) keeps every bone
  direction and takes median lengths.
- `smplx_to_bvh(rest_joints (22, 3), rotations (T, 22, 3), transl (T, 3), fps)`: SMPL-X
  parameters (global_orient + body_pose as axis-angle, transl) written as they are.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from motiongen.bvh.file_format import BVH, write_bvh
from motiongen.skeleton import BODY_JOINT_NAMES, BODY_PARENTS, NUM_BODY_JOINTS

N = {n: i for i, n in enumerate(BODY_JOINT_NAMES)}
CHILDREN = {j: [c for c, p in enumerate(BODY_PARENTS) if p == j] for j in range(NUM_BODY_JOINTS)}

# T-pose template (m, relative to the pelvis): approximately the SMPL-X neutral rest joints,
# y-up, facing +z, arms straight out along +-x. Only its directions are used.
TEMPLATE = np.array([
    [0.000, 0.000, 0.000],     # pelvis
    [0.070, -0.090, -0.005],   # left_hip
    [-0.070, -0.090, -0.005],  # right_hip
    [0.000, 0.110, -0.025],    # spine1
    [0.105, -0.465, -0.010],   # left_knee
    [-0.105, -0.465, -0.010],  # right_knee
    [0.000, 0.245, -0.005],    # spine2
    [0.090, -0.865, -0.055],   # left_ankle
    [-0.090, -0.865, -0.055],  # right_ankle
    [0.000, 0.300, 0.000],     # spine3
    [0.120, -0.920, 0.070],    # left_foot
    [-0.120, -0.920, 0.070],   # right_foot
    [0.000, 0.510, -0.040],    # neck
    [0.077, 0.420, -0.035],    # left_collar
    [-0.077, 0.420, -0.035],   # right_collar
    [0.000, 0.600, 0.010],     # head
    [0.190, 0.460, -0.045],    # left_shoulder
    [-0.190, 0.460, -0.045],   # right_shoulder
    [0.455, 0.445, -0.070],    # left_elbow
    [-0.455, 0.445, -0.070],   # right_elbow
    [0.720, 0.445, -0.070],    # left_wrist
    [-0.720, 0.445, -0.070],   # right_wrist
])
# End Site lengths (m) of the leaves, along their parent bone's template direction.
END_LENGTH = {"head": 0.10, "left_wrist": 0.08, "right_wrist": 0.08, "left_foot": 0.05, "right_foot": 0.05}

_LR = ("left_hip", "right_hip")
_LRC = ("left_collar", "right_collar")
_LRS = ("left_shoulder", "right_shoulder")
_UP = (("head",), ("pelvis",))


def _side_specs(s: str) -> dict:
    lat = (("left_hip",), ("right_hip",))
    return {
        f"{s}_hip": ([((f"{s}_knee",), (f"{s}_hip",))], [((f"{s}_foot",), (f"{s}_ankle",)), lat]),
        f"{s}_knee": ([((f"{s}_ankle",), (f"{s}_knee",))], [((f"{s}_foot",), (f"{s}_ankle",)), lat]),
        f"{s}_ankle": ([((f"{s}_foot",), (f"{s}_ankle",))], [((f"{s}_knee",), (f"{s}_ankle",)), lat]),
        f"{s}_collar": ([((f"{s}_shoulder",), (f"{s}_collar",))], [(("neck",), ("spine3",)), (("head",), ("spine3",))]),
        f"{s}_shoulder": ([((f"{s}_elbow",), (f"{s}_shoulder",))], [((f"{s}_wrist",), (f"{s}_elbow",)), _UP, lat]),
        f"{s}_elbow": ([((f"{s}_wrist",), (f"{s}_elbow",))], [((f"{s}_elbow",), (f"{s}_shoulder",)), _UP, lat]),
    }


# Per non-leaf joint: candidates for the bone axis u and the twist reference v, each a
# vector mean(A) - mean(B). Per frame the first non-degenerate candidate is used.
FRAME_SPECS: dict[str, tuple[list, list]] = {
    # The pelvis frame comes from the hips alone (lateral axis, then down to their midpoint):
    # it is rigid with the hips in every skeleton we import.
    "pelvis": ([((_LR[0],), (_LR[1],))], [(_LR, ("pelvis",)), (("spine1",), ("pelvis",))]),
    "spine1": ([(("spine2",), ("spine1",)), (("spine3",), ("spine1",))], [((_LR[0],), (_LR[1],))]),
    "spine2": ([(("spine3",), ("spine2",)), (("neck",), ("spine2",))], [((_LRC[0],), (_LRC[1],)), ((_LRS[0],), (_LRS[1],))]),
    "spine3": ([(("neck",), ("spine3",)), (("head",), ("spine3",))], [((_LRC[0],), (_LRC[1],)), ((_LRS[0],), (_LRS[1],))]),
    "neck": ([(("head",), ("neck",))], [((_LRC[0],), (_LRC[1],)), ((_LRS[0],), (_LRS[1],))]),
    **_side_specs("left"), **_side_specs("right"),
}
_WORLD_FALLBACK = [np.array([1.0, 0, 0]), np.array([0, 0, 1.0]), np.array([0, 1.0, 0])]


def _vector(x: np.ndarray, spec) -> np.ndarray:
    """mean(x[A]) - mean(x[B]): (..., 22, 3) -> (..., 3)."""
    a, b = spec
    return x[..., [N[n] for n in a], :].mean(-2) - x[..., [N[n] for n in b], :].mean(-2)


def _pick(cands: list[np.ndarray], ok) -> np.ndarray:
    """Per frame, the first candidate (..., 3) for which ok(candidate) holds (the last otherwise)."""
    out = cands[-1]
    for c in reversed(cands[:-1]):
        out = np.where(ok(c)[..., None], c, out)
    return out


def _frame(u_cands: list[np.ndarray], v_cands: list[np.ndarray]) -> np.ndarray:
    """Orthonormal frames (..., 3, 3), columns (e1 along u, e2 from v, e3 = e1 x e2)."""
    shape = u_cands[0].shape
    u = _pick(u_cands + [np.broadcast_to(_WORLD_FALLBACK[2], shape)], lambda c: np.linalg.norm(c, axis=-1) > 1e-8)
    e1 = u / np.linalg.norm(u, axis=-1, keepdims=True)

    def perp(c):
        return c - np.sum(c * e1, -1, keepdims=True) * e1

    def ok(c):   # at least ~3 degrees away from the bone axis
        return np.linalg.norm(perp(c), axis=-1) > 0.05 * np.maximum(np.linalg.norm(c, axis=-1), 1e-12)

    v = _pick(v_cands + [np.broadcast_to(w, shape) for w in _WORLD_FALLBACK], ok)
    e2 = perp(v)
    e2 /= np.linalg.norm(e2, axis=-1, keepdims=True)
    return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)


def _joint_frame(x: np.ndarray, name: str) -> np.ndarray:
    us, vs = FRAME_SPECS[name]
    return _frame([_vector(x, s) for s in us], [_vector(x, s) for s in vs])


def _helper_frame(x: np.ndarray, p: int, c: int) -> np.ndarray:
    name = BODY_JOINT_NAMES[p]
    return _frame([x[..., c, :] - x[..., p, :]], [_vector(x, s) for s in FRAME_SPECS[name][1]])


def _euler(R: np.ndarray, order: str) -> np.ndarray:
    with warnings.catch_warnings():   # gimbal lock still gives a valid (if non-unique) triple
        warnings.simplefilter("ignore", UserWarning)
        return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_euler(order, degrees=True).reshape(R.shape[:-2] + (3,))


def _channels(order: str, root: bool) -> tuple[str, ...]:
    rot = tuple(f"{a}rotation" for a in order)
    return ("Xposition", "Yposition", "Zposition") + rot if root else rot


def _check_order(order: str) -> str:
    order = order.upper()
    if sorted(order) != ["X", "Y", "Z"]:
        raise ValueError(f"order must be a permutation of XYZ, got {order!r}")
    return order


def _assemble(names, parents, offsets, world_R, root_pos, fps: float, order: str, scale: float) -> BVH:
    """Joints (with End Sites appended after leaves) and per-frame world rotations -> BVH.
    names/parents/offsets describe the joints only; world_R: (T, J, 3, 3); root_pos (T, 3)."""
    J = len(names)
    local = np.empty_like(world_R)
    for k, p in enumerate(parents):
        local[:, k] = world_R[:, k] if p < 0 else np.swapaxes(world_R[:, p], -1, -2) @ world_R[:, k]
    eul = _euler(local, order)                                                   # (T, J, 3)
    motion = np.concatenate([root_pos * scale, eul.reshape(len(eul), -1)], axis=1)  # (T, 3 + 3J)
    # End Sites after each leaf, keeping parents-before-children order by inserting in place.
    out_names, out_par, out_off, out_ch, out_end, remap = [], [], [], [], [], {}
    has_child = {p for p in parents if p >= 0}
    for k in range(J):
        remap[k] = len(out_names)
        out_names.append(names[k]), out_par.append(-1 if parents[k] < 0 else remap[parents[k]])
        out_off.append(offsets[k] * scale), out_ch.append(_channels(order, parents[k] < 0)), out_end.append(False)
        if k not in has_child:
            body = N.get(names[k])
            par = BODY_PARENTS[body] if body is not None else -1
            d = TEMPLATE[body] - TEMPLATE[par] if body is not None and par >= 0 else np.array([0, 1.0, 0])
            length = END_LENGTH.get(names[k], 0.05)
            out_names.append(f"{names[k]}_end"), out_par.append(remap[k])
            out_off.append(d / np.linalg.norm(d) * length * scale), out_ch.append(()), out_end.append(True)
    return BVH(out_names, np.array(out_par), np.array(out_off), out_ch, np.array(out_end), motion, 1.0 / fps)


def joints_to_bvh(joints, fps: float, order: str = "ZXY", unit: str = "m", helpers: bool | None = None,
                  helper_tol: float = 5e-4) -> BVH:
    """Solve a BVH (SMPL-X skeleton, root position + per-joint Euler rotations) from joint
    positions (T, 22, 3) (or (T, 24, 3): extra joints are dropped), metres, y-up.

    order: Euler channel order (e.g. "ZXY", "XYZ"); unit: "m" or "cm" for the file.
    helpers: insert a zero-length helper joint before a secondary child whose offset is not
    constant in its parent's frame (None: when its 99th-percentile deviation exceeds
    `helper_tol` metres; True: always for secondary children; False: never).
    """
    order = _check_order(order)
    scale = {"m": 1.0, "cm": 100.0}[unit]
    x = np.asarray(joints, np.float64)[:, :NUM_BODY_JOINTS]                  # (T, 22, 3)
    if x.ndim != 3 or x.shape[1:] != (NUM_BODY_JOINTS, 3) or len(x) == 0:
        raise ValueError(f"joints: expected (T>0, 22, 3), got {np.shape(joints)}")
    F = {j: _joint_frame(x, BODY_JOINT_NAMES[j]) for j in range(NUM_BODY_JOINTS) if CHILDREN[j]}      # (T,3,3)
    Ft = {j: _joint_frame(TEMPLATE, BODY_JOINT_NAMES[j]) for j in F}                                   # (3,3)

    names, parents, offsets, world = [], [], [], []
    index = {}

    def add(name, parent, offset, W):
        index[name] = len(names)
        names.append(name), parents.append(parent), offsets.append(offset), world.append(W)

    for j in range(NUM_BODY_JOINTS):                # SMPL-X order lists parents first
        name, p = BODY_JOINT_NAMES[j], BODY_PARENTS[j]
        W = F[j] @ Ft[j].T if j in F else None      # leaves inherit the parent's rotation below
        if p < 0:
            add(name, -1, np.zeros(3), W)
            continue
        d = x[:, j] - x[:, p]                                                 # (T, 3)
        o = np.einsum("tji,tj->ti", F[p], d)                                   # (T, 3) offset in parent frame
        o_med = np.median(o, axis=0)
        primary = FRAME_SPECS[BODY_JOINT_NAMES[p]][0][0][0] == (name,)
        deviation = np.percentile(np.linalg.norm(o - o_med, axis=-1), 99)
        need = (not primary) and (helpers is True or (helpers is None and deviation > helper_tol))
        parent_idx = index[BODY_JOINT_NAMES[p]]
        if need:
            Fh = _helper_frame(x, p, j)
            Fht = _helper_frame(TEMPLATE, p, j)
            add(f"{BODY_JOINT_NAMES[p]}_to_{name}", parent_idx, np.zeros(3), Fh @ Fht.T)
            length = np.median(np.linalg.norm(d, axis=-1))
            offset = Fht @ np.array([length, 0.0, 0.0])
            parent_idx = len(names) - 1
        else:
            offset = Ft[p] @ o_med
        add(name, parent_idx, offset, W if W is not None else world[parent_idx])
    world_R = np.stack(world, axis=1)                                         # (T, J', 3, 3)
    return _assemble(names, parents, np.array(offsets), world_R, x[:, 0], fps, order, scale)


def smplx_to_bvh(rest_joints, rotations, transl, fps: float, order: str = "ZXY", unit: str = "m") -> BVH:
    """SMPL-X parameters as a BVH: rest_joints (22, 3) (the shaped body's rest joints, e.g.
    J_regressor @ v_shaped), rotations (T, 22, 3) axis-angle (global_orient then the 21
    body_pose joints), transl (T, 3). Offsets are rest_joints[j] - rest_joints[parent]; the
    root position channel is rest_joints[0] + transl (SMPL-X rotates about the pelvis), so
    the file's FK equals SMPL-X's joint positions."""
    order = _check_order(order)
    scale = {"m": 1.0, "cm": 100.0}[unit]
    rest = np.asarray(rest_joints, np.float64)
    rot = np.asarray(rotations, np.float64)
    transl = np.asarray(transl, np.float64)
    if rest.shape != (NUM_BODY_JOINTS, 3) or rot.ndim != 3 or rot.shape[1:] != (NUM_BODY_JOINTS, 3) \
            or transl.shape != (rot.shape[0], 3):
        raise ValueError(f"expected rest_joints (22,3), rotations (T,22,3), transl (T,3); got "
                         f"{rest.shape}, {rot.shape}, {transl.shape}")
    T = rot.shape[0]
    local = Rotation.from_rotvec(rot.reshape(-1, 3)).as_matrix().reshape(T, NUM_BODY_JOINTS, 3, 3)
    world = np.empty_like(local)
    for j, p in enumerate(BODY_PARENTS):
        world[:, j] = local[:, j] if p < 0 else world[:, p] @ local[:, j]
    offsets = np.array([np.zeros(3) if p < 0 else rest[j] - rest[p] for j, p in enumerate(BODY_PARENTS)])
    return _assemble(list(BODY_JOINT_NAMES), list(BODY_PARENTS), offsets, world, rest[0] + transl, fps, order, scale)


def export_bvh(path: str | Path, joints, fps: float, **kw) -> Path:
    """`joints_to_bvh` written to `path`."""
    return write_bvh(path, joints_to_bvh(joints, fps, **kw))


def export_smplx_bvh(path: str | Path, rest_joints, rotations, transl, fps: float, **kw) -> Path:
    """`smplx_to_bvh` written to `path`."""
    return write_bvh(path, smplx_to_bvh(rest_joints, rotations, transl, fps, **kw))


__all__ = ["TEMPLATE", "FRAME_SPECS", "joints_to_bvh", "smplx_to_bvh", "export_bvh", "export_smplx_bvh"]
