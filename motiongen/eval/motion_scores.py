"""Per-motion scores of the evaluation protocol: body figures, penetration, contact on the
labelled interaction frames, distance to goals and objects; and the reference row (the same
scores on the scene's own motion data)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from motiongen import metrics as M
from motiongen.eval.mesh_scores import BodyMeshes, InteractionObject, mesh_scores
from motiongen.eval.pairs import ProtocolConfig
from motiongen.eval.scene_context import HAND_NAMES, SceneContext
from motiongen.skeleton import LEFT_HIP, PELVIS, RIGHT_HIP, joint_set_for
from motiongen.spans import true_runs


def _hand_idx(names) -> list[int]:
    return [i for i, n in enumerate(names) if n in HAND_NAMES]


def object_contact(ctx: SceneContext, joints, labelled, names, oid_poses, thresh: float) -> tuple[int, int]:
    """(hits, frames) over labelled frames: a hand joint (less its skin offset) within `thresh`
    of the object's surface at that frame's pose, or of the scene/floor. oid_poses: [(oid,
    poses (T, 4, 4))]."""
    frames = np.flatnonzero(labelled)
    idx = _hand_idx(names)
    if not frames.size or not idx:
        return 0, 0
    h = np.asarray(joints, np.float64)[frames][:, idx]                                       # (F, H, 3)
    d = ctx.surface(h.reshape(-1, 3)).reshape(h.shape[:2])
    for oid, poses in oid_poses:
        d = np.minimum(d, ctx.object_distance(h, oid, np.asarray(poses)[frames]))
    d = d - np.array([M.DEFAULT_SKIN_OFFSET.get(names[i], 0.0) for i in idx])
    return int((d < thresh).any(axis=1).sum()), int(frames.size)


@dataclass
class MeshInput:
    """A motion's body mesh for the mesh figures (`eval.mesh_scores`): the meshes of the body
    model, the motion's SMPL-X parameters, and each interaction's frames and object."""
    meshes: BodyMeshes
    params: object                                          # BodyParams
    interactions: list = field(default_factory=list)        # [(frames (F,) int, InteractionObject)]


def motion_metrics(ctx: SceneContext, joints, fps: float, names, labels, action_names, setting: str,
                   cfg: ProtocolConfig, boundaries, objects=(), mesh: MeshInput | None = None) -> dict:
    """Per-trajectory metrics for joints (T, J, 3) with per-frame labels (T, A) bool.
    objects: [(oid, poses (T, 4, 4))] for the dynamic setting's object contact/approach.
    mesh: the motion on a body, for the figures measured on its skin."""
    j = np.asarray(joints, np.float64)
    pen = M.scene_penetration(j, ctx.grid, sdf=ctx.sdf)
    flo = M.floor_penetration(j)
    out = {**M.body_metrics(j, fps, joint_set_for(names).parents), "penetration_frames": pen["frame_ratio"],
           "penetration_max_m": pen["max_depth"], "floor_penetration_frames": flo["frame_ratio"],
           "jerk": M.mean_jerk(j, fps)}
    if mesh is not None:
        out.update(mesh_scores(mesh.meshes, ctx, mesh.params, labels, action_names, setting, cfg,
                               mesh.interactions))
    b = [x for x in boundaries if 1 <= x < len(j)]
    out["seam_ratio"] = M.seam_jump(j, b).ratio if b else float("nan")
    labels = np.asarray(labels, bool)
    hits = total = 0
    if setting == "static":
        parts = {a: p for a, p in M.DEFAULT_CONTACT_PARTS.items() if a in cfg.static_actions}
        if labels.any():
            r = M.contact_rate(j, labels, action_names, ctx.surface, joint_names=names, expected_parts=parts,
                               thresh=cfg.contact_thresh)
            n = [int(labels[:, action_names.index(a)].sum()) for a in r if a != "all"]
            hits, total = int(round(r["all"] * sum(n))) if n else 0, sum(n)
    elif cfg.dynamic_action in action_names:
        lab = labels[:, action_names.index(cfg.dynamic_action)]
        hits, total = object_contact(ctx, j, lab, names, objects, cfg.contact_thresh)
        idx = _hand_idx(names)
        if objects and idx:
            frames = np.flatnonzero(lab) if lab.any() else np.arange(len(j))
            d = np.min([ctx.object_distance(j[frames][:, idx], oid, np.asarray(p)[frames]).min()
                        for oid, p in objects])
            out["object_dist_m"] = float(d)
    # Pooled later (hits / frames over all trajectories), so keep the counts.
    out["_contact_hits"], out["_contact_frames"] = hits, total
    return out


def goal_metrics(joints, arrival: int, goal_xz, subgoals) -> dict:
    """Distance of the pelvis and of the body's own centre (hips midpoint) to the final goal at
    the arrival frame; never arrived: the closest approach stands in, so misses still count
    with their real distance. Plus the waypoint distances for the trajectory fail rate."""
    j = np.asarray(joints, np.float64)
    hip = 0.5 * (j[:, LEFT_HIP] + j[:, RIGHT_HIP])[:, [0, 2]]                                   # (T, 2)
    if 0 <= arrival < len(j):
        pelvis = float(np.linalg.norm(j[arrival, PELVIS, [0, 2]] - goal_xz))
        body = float(np.linalg.norm(hip[arrival] - goal_xz))
    else:
        pelvis = float(M.goal_distances(j, np.asarray(goal_xz)[None])[0])
        body = float(np.linalg.norm(hip - goal_xz, axis=-1).min())
    return {"goal_dist_m": pelvis, "goal_dist_body_m": body,
            "_waypoints": M.goal_distances(j, subgoals).tolist()}


@dataclass
class ReferenceResult:
    per_sequence: list[dict]
    motions: list[np.ndarray]           # (T_i, J, 3) per sequence
    labels: list[np.ndarray] = field(default_factory=list)   # (T_i, A) bool per sequence: its actions


def data_interactions(ctx: SceneContext, seq, labels, cfg: ProtocolConfig) -> list[tuple[np.ndarray, InteractionObject]]:
    """The data's interactions in one sequence: per segment labelled `cfg.dynamic_action`, its
    frames and the object it is done with (nearest the hands at the segment's start: the rule
    the dynamic pairs use), so the data is measured against one object per interaction as
    the model is."""
    names = ctx.ds.action_names
    if cfg.dynamic_action not in names or ctx.ds.object_ids is None:
        return []
    hands = _hand_idx(ctx.ds.joint_set.names)
    out = []
    for s, e in true_runs(np.asarray(labels)[:, names.index(cfg.dynamic_action)]):
        found = ctx.segment_object(seq, s, hands)
        if found is not None:
            out.append((np.arange(s, e), InteractionObject(found[0], found[1])))
    return out


def only_during(frames: np.ndarray, obj: InteractionObject) -> tuple[int, np.ndarray]:
    """(oid, poses (T, 4, 4)) with the object far away outside `frames`: joint contact and
    approach then count this object during its own interaction only."""
    poses = obj.poses.copy()
    away = np.ones(len(poses), bool)
    away[frames] = False
    poses[away, :3, 3] = 1e6
    return obj.oid, poses


def reference_metrics(ctx: SceneContext, setting: str, cfg: ProtocolConfig, episode_frames: int,
                      meshes: BodyMeshes | None = None) -> ReferenceResult:
    """The same metrics on the scene's own motion data. Seams: boundaries every
    `episode_frames` frames (the model's episode length), so the ratio shows what an
    invisible seam looks like on real data. Dynamic: each pick-up segment against its own
    object at the data's per-frame poses. meshes: put the data on a body for the mesh figures."""
    ds = ctx.ds
    names = list(ds.joint_set.names)
    out, motions, labels = [], [], []
    for seq in ctx.sequences:
        j = np.asarray(ds.joints[seq.start:seq.end], np.float64)
        lab = np.asarray(ds.actions[seq.start:seq.end], bool)
        inter = data_interactions(ctx, seq, lab, cfg) if setting == "dynamic" else []
        objs = [only_during(f, o) for f, o in inter]
        bounds = list(range(episode_frames, len(j), episode_frames))
        mesh = MeshInput(meshes, meshes.of_joints(j), inter) if meshes is not None else None
        m = motion_metrics(ctx, j, ds.fps, names, lab, ds.action_names, setting, cfg, bounds, objs, mesh)
        m.pop("object_dist_m", None)
        idx = _hand_idx(names)
        if inter and idx:
            # Closest hand approach per interaction segment, averaged over the segments.
            m["object_dist_m"] = float(np.mean([ctx.object_distance(j[f][:, idx], o.oid, o.poses[f]).min()
                                                for f, o in inter]))
        out.append(m)
        motions.append(j.astype(np.float32))
        labels.append(lab)
    return ReferenceResult(out, motions, labels)
