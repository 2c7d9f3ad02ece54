"""The body side of contact-preserving augmentation (TRUMANS supp. B.5): where each joint
touched the edited object (from the per-vertex contact labels), how its target moves
(`augment_offsets`), and the body solved to the new targets by the project's refinement
(`motiongen.body.solve.MotionBody.solve`: L-BFGS over one body's rotations, so bones stay rigid,
with the moved joints as weighted reach targets, planted feet locked and the rest of the body
held near its original joints) instead of per-chain CCD IK.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from motiongen.body.fit import fit_joints
from motiongen.body.model import BodyModel
from motiongen.body.rotations import axis_angle_to_matrix
from motiongen.body.solve import SOLVE_CONFIG, BodyMotion, MotionBody
from motiongen.annotation.augment_objects import ObjectEdit
from motiongen.annotation.augment_offsets import ContactEvent, blended_offsets, ramp_weights_span
from motiongen.annotation.vertex_contact import BodySurface
from motiongen.data.contact_labels import VertexContact
from motiongen.scene.distance_field import SurfaceField
from motiongen.skeleton import FOOT_JOINTS, NUM_BODY_JOINTS, JointSet
from motiongen.spans import true_runs

FIT_TOLERANCE = 0.01       # m: stored SMPL-X parameters are used as the start when they pose the joints this well


@dataclass
class Retarget:
    """Targets of one sequence after an object edit."""

    targets: np.ndarray        # (T, J, 3) joints moved by their contact offsets
    offsets: np.ndarray        # (T, J, 3) the offsets (zero for joints that never touch the object)
    weights: np.ndarray        # (T, J) how much each joint's target counts (1 in contact, ramps, 0)
    events: dict               # joint index -> [ContactEvent]

    @property
    def changed(self) -> bool:
        return bool(np.abs(self.offsets).max() > 1e-9) if self.offsets.size else False


def contact_runs(joint_targets: np.ndarray, object_id: int, min_frames: int = 1) -> dict[int, list[tuple[int, int]]]:
    """joint index -> [(start, end)) runs of frames in which the joint's part touches the
    object, from the per-joint labels (T, J)."""
    out = {}
    for j in range(joint_targets.shape[1]):
        runs = [r for r in true_runs(joint_targets[:, j] == object_id) if r[1] - r[0] >= min_frames]
        if runs:
            out[j] = runs
    return out


def contact_points(labels: VertexContact, body: BodySurface, params: dict, seq_start: int, joint: int,
                   frames: tuple[int, int], object_id: int, field: SurfaceField, poses: np.ndarray) -> np.ndarray:
    """(n, 3) contact point v_m of a joint on an object at each frame of a run, in the object's
    local frame: the mean of the nearest object-surface points of the joint's part's vertices
    that touch it (Eq. A1's v_m). params: the labels' body (sequence frames); poses (n, 4, 4)."""
    a, b = frames
    region = np.flatnonzero(body.region == joint)                              # (Vj,)
    dt, dev = body.bm.J_template.dtype, body.bm.J_template.device

    def t(k):
        x = np.asarray(params[k])
        x = x[a:b] if x.ndim == 2 else x
        return torch.as_tensor(np.array(x), dtype=dt, device=dev)

    with torch.no_grad():
        verts = body.bm.vertices(t("global_orient"), t("body_pose"), t("transl"), t("betas"),
                                 vertex_ids=region).cpu().numpy().astype(np.float64)   # (n, Vj, 3)
    out = np.zeros((b - a, 3))
    for i in range(b - a):
        ids, tgt, _ = labels.frame(seq_start + a + i)
        on = ids[(tgt == object_id) & (body.region[ids] == joint)]
        pts = verts[i][np.searchsorted(region, on)] if len(on) else verts[i]
        M = poses[i]
        q = field.query(pts, pose=M)
        near = q.nearest
        out[i] = ((near - M[:3, 3]) @ M[:3, :3]).mean(0)                        # world -> local
    return out


def retarget(joints: np.ndarray, runs: dict[int, list[tuple[int, int]]], points: dict, edit: ObjectEdit,
             poses: np.ndarray, window: int) -> Retarget:
    """New joint targets (Eq. A2, A3, A5-A6). joints (T, J, 3); runs: joint -> [(a, b)];
    points: (joint, a) -> (b-a, 3) local contact points; poses (T, 4, 4) the object's old poses."""
    T, J = joints.shape[:2]
    offsets = np.zeros((T, J, 3))
    weights = np.zeros((T, J))
    events: dict[int, list[ContactEvent]] = {}
    for j, rs in runs.items():
        evs = [ContactEvent(a, b, edit.offsets(points[(j, a)], poses[a:b])) for a, b in rs]
        events[j] = evs
        offsets[:, j] = blended_offsets(T, evs, window)
        weights[:, j] = np.max([ramp_weights_span(T, a, b, window) for a, b in rs], axis=0)
    return Retarget(np.asarray(joints, np.float64) + offsets, offsets, weights, events)


@dataclass
class StartBody:
    """The body the solve starts from: one shape, its pose per frame, the joints it poses."""

    rotmats: torch.Tensor      # (T, 22, 3, 3) local rotations
    transl: torch.Tensor       # (T, 3)
    betas: np.ndarray          # (nβ,)
    joints: np.ndarray         # (T, J, 3) posed joints in the dataset's joint set
    source: str                # "params" (the given SMPL-X) or "fit"


def initial_body(bm: BodyModel, joint_set: JointSet, joints: np.ndarray, params: dict | None,
                 fit_mlp=None) -> StartBody:
    """Start of the solve: the given SMPL-X parameters when they pose these joints within
    FIT_TOLERANCE (mean), else a fit to the joints (`fit_joints`)."""
    X = np.asarray(joints[:, :NUM_BODY_JOINTS], np.float64)
    dt = bm.J_template.dtype
    if params is not None:
        betas = np.asarray(params["betas"], np.float64)
        betas = (betas[0] if betas.ndim == 2 else betas)[:bm.num_betas]
        go = torch.as_tensor(np.array(params["global_orient"]), dtype=dt)
        bp = torch.as_tensor(np.array(params["body_pose"]), dtype=dt)
        tr = torch.as_tensor(np.array(params["transl"]), dtype=dt)
        with torch.no_grad():
            J = bm.joints(go, bp, tr, torch.as_tensor(betas, dtype=dt))
        if float(np.linalg.norm(J.double().numpy() - X, axis=-1).mean()) < FIT_TOLERANCE:
            R = torch.cat([axis_angle_to_matrix(go)[:, None], axis_angle_to_matrix(bp.reshape(-1, 21, 3))], 1)
            return _start(bm, joint_set, R, tr, betas, "params")
    fit = fit_joints(X, bm, mlp=fit_mlp)
    R = torch.cat([axis_angle_to_matrix(torch.as_tensor(fit.global_orient, dtype=dt))[:, None],
                   axis_angle_to_matrix(torch.as_tensor(fit.body_pose, dtype=dt).reshape(-1, 21, 3))], 1)
    return _start(bm, joint_set, R, torch.as_tensor(fit.transl, dtype=dt), np.asarray(fit.betas, np.float64), "fit")


def _start(bm, joint_set, R, transl, betas, source) -> StartBody:
    body = MotionBody(bm, joint_set, torch.as_tensor(betas[None]))
    with torch.no_grad():
        J = body.pose(R[None], transl[None], slice(0, 1))[0].double().numpy()
    return StartBody(R, transl, betas, J, source)


# The sampler's final solve (body.solve.SOLVE_CONFIG) with the light smoothing of a fit: the
# source is clean mocap, not a network's jittery joints, and should come back as it was away
# from the edited contacts.
AUGMENT_SOLVE = replace(SOLVE_CONFIG, w_smooth_joints=0.1, w_smooth_rot=0.03, w_floor=0.0)


def solve_body(bm: BodyModel, joint_set: JointSet, rt: Retarget, start: StartBody,
               planted: np.ndarray | None, steps: int = 80) -> BodyMotion:
    """One body (betas fixed) through the new targets: reach targets for the moved body joints
    (weights = their ramps), joint L2 to the targets, planted feet locked (planted (T, 4) for
    `FOOT_JOINTS`: contact label and still, `representation.stance_labels`)."""
    body = MotionBody(bm, joint_set, torch.as_tensor(start.betas[None]))
    f, j = np.nonzero(rt.weights[:, :NUM_BODY_JOINTS] > 0)
    reach = (f, j, rt.targets[f, j], rt.weights[f, j]) if len(f) else None
    cfg = replace(AUGMENT_SOLVE, max_steps=int(steps))
    return body.solve(0, rt.targets, start.rotmats, planted, FOOT_JOINTS, cfg, reach)
