"""Contact-preserving augmentation (TRUMANS supp. B.5): new training sequences made by scaling an
object a person touches, swapping it for another mesh of the same type, or moving it, with the
body re-solved so that its contacts follow the object.

    motiongen augment root=DATASET out=DIR [ops=[scale,swap,move]] [copies=1]
        [split=train] [window=30] [scale_min=0.8] [scale_max=1.25] [move=0.15] [seed=0]
        [min_contact_frames=3] [ik_steps=80] [object_meshes=DIR] [body_model=PATH]
        [overwrite=false] [progress=true]

Contacts come from the per-vertex labels (`motiongen annotate-contact`; computed
first when the dataset has none). Per source sequence and copy: pick an object it touches and
an edit (`augment_objects`), move each touching joint's target with its contact point and ease
it in and out over `window` frames (`augment_offsets`, Eq. A1-A6), solve one rigid body to the
targets (`augment_body`), recompute the contact labels. The output is a dataset of the
augmented sequences only (same scenes, the edited objects as new objects, labels in
``vertex_contact/``); train on it together with the source with `data.augmented=[DIR]`.
Library: `augment_dataset(root, out, AugmentConfig(...))`.
"""

from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from motiongen.body.model import BodyModel, load_body_model
from motiongen.cli import parse_key_values, tool_main
from motiongen.annotation import augment_objects as edits
from motiongen.annotation.annotate_contact import SurfaceBank, annotate_dataset, annotate_frames
from motiongen.annotation.augment_body import contact_points, contact_runs, initial_body, retarget, solve_body
from motiongen.annotation.vertex_contact import BodySurface, ContactConfig
from motiongen.data.contact_labels import VertexContact, VertexContactWriter
from motiongen.scene.distance_field import OBJECT_VOXEL, MeshField
from motiongen.data.format import SMPLX_FIELDS, MotionDataset, Sequence
from motiongen.data.dataset_writer import DatasetWriter
from motiongen.errors import ConfigError, DataError
from motiongen.metrics import bone_consistency
from motiongen.output_lock import refuse_output_over_input
from motiongen.data.representation import stance_labels
from motiongen.skeleton import FOOT_JOINTS, NUM_BODY_JOINTS

MOVED = 0.01     # m: a joint moved further than this gets its contact label recomputed


@dataclass
class AugmentConfig:
    ops: tuple[str, ...] = edits.OPS      # edits to choose from per copy
    copies: int = 1                       # augmented versions per source sequence
    split: str | None = "train"           # source sequences (None: all)
    window: int = 30                      # W, frames of easing in and out (Eq. A3)
    scale_min: float = 0.8
    scale_max: float = 1.25
    move: float = 0.15                    # m, largest move of an object
    seed: int = 0
    min_contact_frames: int = 3           # shorter object contacts are ignored
    ik_steps: int = 80                    # L-BFGS iterations of the body solve
    contact: ContactConfig = field(default_factory=ContactConfig)


@dataclass
class AugmentResult:
    path: Path
    sequences: int                 # augmented sequences written
    sources: int                   # source sequences considered
    skipped: dict                  # reason -> count
    seconds: float
    stats: dict                    # mean over sequences: target error, bone CV, contacts kept, ...

    @property
    def per_minute(self) -> float:
        return 60.0 * self.sequences / max(self.seconds, 1e-9)


def _edit(rng, cfg: AugmentConfig, ds: MotionDataset, bank: SurfaceBank, scene_field, oid: int, pose0):
    """A random edit of object `oid` that is possible, or None."""
    mesh = bank.object_mesh(oid)
    for op in rng.permutation(list(cfg.ops)):
        if op == "scale":
            return edits.scale_edit(oid, mesh, pose0, float(rng.uniform(cfg.scale_min, cfg.scale_max)))
        if op == "swap":
            kind = ds.objects.get(oid, {}).get("type")
            others = [o for o, e in sorted(ds.objects.items()) if o != oid and e.get("type") == kind]
            others = [o for o in others if bank.object_mesh(o) is not None]
            if others:
                other = int(rng.choice(others))
                return edits.swap_edit(oid, mesh, bank.object_mesh(other), other, pose0)
        if op == "move":
            for _ in range(20):
                a = rng.uniform(0, 2 * np.pi)
                delta = float(rng.uniform(0.3, 1.0) * cfg.move) * np.array([np.cos(a), 0.0, np.sin(a)])
                moved = np.array(pose0, np.float64)
                moved[:3, 3] += delta
                if edits.placement_ok(mesh, moved, scene_field, cfg.contact.floor_y):
                    return edits.move_edit(oid, mesh, delta)
    return None


@dataclass
class AugmentContext:
    """What augmenting the sequences of one dataset needs (built once by `augment_dataset`)."""

    ds: MotionDataset
    labels: VertexContact
    bm: BodyModel
    body: BodySurface
    bank: SurfaceBank
    cfg: AugmentConfig


@dataclass
class AugmentedSequence:
    joints: np.ndarray           # (T, J, 3) float32
    contact: np.ndarray          # (T, J) bool
    object_ids: np.ndarray       # (T, K) int32, the edited object under its new id
    object_poses: np.ndarray     # (T, K, 4, 4) float32
    smplx: dict | None           # the solved body {field: (T, d) / (10,)}; None when unchanged
    labels: list                 # per frame batch: (target, distance, joints, penetration, penetrating)
    changed: bool                # False: no joint touches the edited object, the motion is the source's
    stats: dict


def object_track(ds: MotionDataset, seq: Sequence, object_id: int) -> tuple[np.ndarray, np.ndarray]:
    """Where an object is in a sequence: (slots (frames, slots) as from np.where, poses (T, 4, 4)
    with the identity in frames without it)."""
    ids = np.asarray(ds.object_ids[seq.start:seq.end])
    slot_of = np.where(ids == object_id)
    poses = np.broadcast_to(np.eye(4), (seq.num_frames, 4, 4)).copy()
    poses[slot_of[0]] = np.asarray(ds.object_poses[seq.start:seq.end])[slot_of]
    return slot_of, poses


def augment_sequence(ctx: AugmentContext, seq: Sequence, edit: edits.ObjectEdit, new_id: int) -> AugmentedSequence:
    """One sequence with one object edited (its new id `new_id`): joints touching it follow
    their contact points (Eq. A1-A6), one body is solved through the new targets, and the
    contact labels are recomputed on that body against the new object. A sequence in which no
    joint touches the object comes back unchanged (joints bitwise; only the object changes)."""
    ds, cfg, s, e = ctx.ds, ctx.cfg, seq.start, seq.end
    oid = edit.object_id
    jt = np.asarray(ctx.labels.joints[s:e])                                             # (T, J)
    ids = np.asarray(ds.object_ids[s:e])
    slot_of, poses = object_track(ds, seq, oid)
    new_ids = np.where(ids == oid, new_id, ids).astype(np.int32)
    new_poses = np.asarray(ds.object_poses[s:e], np.float64).copy()
    new_poses[slot_of] = edit.poses(new_poses[slot_of])
    joints = np.asarray(ds.joints[s:e], np.float64)
    contact = np.asarray(ds.contact[s:e])
    runs = contact_runs(jt, oid, cfg.min_contact_frames)
    if not runs:
        return AugmentedSequence(np.asarray(ds.joints[s:e]).copy(), contact, new_ids, new_poses.astype(np.float32),
                                 None, [], False, {})
    targets = ctx.bank.targets(seq.scene, ids)
    params = {k: np.asarray(v[s:e]) for k, v in (ctx.labels.smplx or ds.smplx).items()}
    pts = {(j, a): contact_points(ctx.labels, ctx.body, params, s, j, (a, b), oid, targets.objects[oid], poses[a:b])
           for j, rs in runs.items() for a, b in rs}
    rt = retarget(joints, runs, pts, edit, poses, cfg.window)
    start = initial_body(ctx.bm, ds.joint_set, joints, params)
    planted = stance_labels(joints, contact, FOOT_JOINTS, ds.fps)
    motion = solve_body(ctx.bm, ds.joint_set, rt, start, planted, cfg.ik_steps)
    # labels of the new sequence: the solved body against the edited object
    targets.add_object(new_id, MeshField(edit.mesh, voxel_size=min(cfg.contact.voxel_size, OBJECT_VOXEL)),
                       np.asarray(edit.mesh.vertices, np.float64))
    new_params = {"global_orient": motion.global_orient, "body_pose": motion.body_pose,
                  "transl": motion.transl, "betas": _betas(motion.betas)}
    labels = []
    for a in range(0, seq.num_frames, cfg.contact.batch_frames):
        fr = slice(a, min(a + cfg.contact.batch_frames, seq.num_frames))
        labels.append(annotate_frames(ctx.body, new_params, targets, new_ids, new_poses, cfg.contact, fr))
    new_jt = np.concatenate([lab[2] for lab in labels])
    # joints the edit moved (not the fit: the body model's skeleton is not the data's) get the
    # new labels' "touches something"; the others keep the source's contact labels
    moved = np.linalg.norm(motion.joints - start.joints, axis=-1) > MOVED               # (T, J)
    new_contact = np.where(moved, new_jt != -1, contact)
    stats = _sequence_stats(rt, motion.joints, joints, start.joints, jt, new_jt, oid, new_id, ds.joint_set.parents)
    return AugmentedSequence(motion.joints.astype(np.float32), new_contact, new_ids, new_poses.astype(np.float32),
                             new_params, labels, rt.changed, stats)


@dataclass
class _Output:
    """The dataset of augmented sequences being written, and what `augment_dataset` records of it."""

    writer: DatasetWriter
    next_id: int                                        # id of the next edited object
    vc_writer: VertexContactWriter | None = None
    skipped: dict[str, int] = field(default_factory=dict)   # reason -> count
    records: list[dict] = field(default_factory=list)       # one per augmented sequence (meta.json)
    stats: list[dict] = field(default_factory=list)         # AugmentedSequence.stats of each
    used_objects: set = field(default_factory=set)          # source objects the sequences hold
    used_scenes: set = field(default_factory=set)


def augment_dataset(root: str | Path, out: str | Path, cfg: AugmentConfig = AugmentConfig(),
                    body_model: BodyModel | str | None = None, object_meshes: str | Path | None = None,
                    overwrite: bool = False, progress: bool = True) -> AugmentResult:
    """Write the augmented sequences of the dataset at `root` as a new dataset at `out`."""
    _check(cfg)
    # Before anything is read or labelled: the new dataset never replaces the source it is made of.
    refuse_output_over_input(out, [root, object_meshes, body_model if not isinstance(body_model, BodyModel) else None],
                             "out")
    log = (lambda m: print(m, file=sys.stderr, flush=True)) if progress else (lambda m: None)
    t0 = time.perf_counter()
    ctx = _context(root, out, cfg, body_model, object_meshes, overwrite, progress, log)
    ds, cfg = ctx.ds, ctx.cfg
    seqs = ds.split_sequences(cfg.split)
    writer = DatasetWriter(out, ds.joint_set, ds.action_names, ds.fps, ds.meta["num_object_slots"],
                           has_smplx=ds.smplx is not None, overwrite=overwrite)
    output = _Output(writer, max(ds.objects, default=-1) + 1)
    try:
        output.vc_writer = VertexContactWriter(writer.tmp, ctx.body.num_vertices, ds.joint_set.num_joints,
                                               smplx=ds.smplx is None)
        for si, seq in enumerate(seqs):
            _augment_copies(ctx, output, si, seq, log, t0)
        if not output.records:
            raise ConfigError(f"{ds.root}: no augmented sequence could be made from split {cfg.split!r} "
                              f"({', '.join(f'{k}: {v}' for k, v in output.skipped.items()) or 'no sequences'})")
        path, summary = _finish(ctx, output, t0)
    except BaseException:
        if output.vc_writer is not None:
            output.vc_writer.abort()
        writer.abort()
        raise
    return AugmentResult(path, len(output.records), len(seqs), output.skipped, time.perf_counter() - t0, summary)


def _context(root, out, cfg: AugmentConfig, body_model, object_meshes, overwrite: bool, progress: bool,
             log) -> AugmentContext:
    """The source dataset, its per-vertex contact labels (annotated first when it has none), the
    body model and surfaces; the contact settings become those the labels were made with."""
    bm = body_model if isinstance(body_model, BodyModel) else load_body_model(body_model)
    ds = MotionDataset.open(root)
    if ds.object_ids is None:
        raise ConfigError(f"{ds.root}: the dataset has no objects to augment (num_object_slots = 0)")
    if Path(out).exists() and not overwrite:
        raise DataError(out, None, "output directory already exists (pass overwrite=true)")
    labels = ds.vertex_contact()
    if labels is None:
        log(f"augment: {ds.root} has no per-vertex contact labels; annotating it first")
        annotate_dataset(ds.root, cfg.contact, bm, object_meshes, progress=progress)
        labels = ds.vertex_contact()
    known = {f.name for f in fields(ContactConfig)}
    if isinstance(labels.info.get("config"), dict) and set(labels.info["config"]) == known:
        cfg = replace(cfg, contact=ContactConfig(**labels.info["config"]))     # relabel as the source was labelled
    return AugmentContext(ds, labels, bm, BodySurface(bm, ds.joint_set), SurfaceBank(ds, cfg.contact, object_meshes), cfg)


def _augment_copies(ctx: AugmentContext, output: _Output, si: int, seq: Sequence, log, t0: float) -> None:
    """The `copies` augmented versions of source sequence number `si`, each editing one object
    the sequence touches (chosen, like the edit, by the seed, `si` and the copy's number)."""
    ds, cfg = ctx.ds, ctx.cfg
    jt = np.asarray(ctx.labels.joints[seq.start:seq.end])                         # (T, J)
    touched = [o for o in np.unique(jt[jt >= 0]).tolist()
               if o in ds.objects and ctx.bank.object_mesh(o) is not None
               and contact_runs(jt, o, cfg.min_contact_frames)]
    if not touched:
        output.skipped["no object contact"] = output.skipped.get("no object contact", 0) + cfg.copies
        return
    for k in range(cfg.copies):
        rng = np.random.default_rng([cfg.seed, si, k])
        oid = int(rng.choice(touched))
        slot_of, poses = object_track(ds, seq, oid)
        edit = _edit(rng, cfg, ds, ctx.bank, ctx.bank.scene_field(seq.scene), oid, poses[slot_of[0][0]])
        if edit is None:
            output.skipped["no possible edit"] = output.skipped.get("no possible edit", 0) + 1
            continue
        new_id, output.next_id = output.next_id, output.next_id + 1
        a = augment_sequence(ctx, seq, edit, new_id)
        name = f"{seq.name}~aug{k}"
        _write_sequence(ctx, output, seq, name, edit, new_id, a)
        log(f"augment: {len(output.records)} {name}: {edit.op} {ds.objects[oid]['name']} {edit.params} "
            f"(target error {100 * a.stats['target_error_m']:.2f} cm, contact kept "
            f"{100 * a.stats['contact_kept']:.0f} %, {time.perf_counter() - t0:.0f} s)")


def _write_sequence(ctx: AugmentContext, output: _Output, seq: Sequence, name: str, edit: edits.ObjectEdit,
                    new_id: int, a: AugmentedSequence) -> None:
    """One augmented sequence, its edited object and its contact labels into the output."""
    ds, oid = ctx.ds, edit.object_id
    o = 0
    for lab in a.labels:                       # the labels' body: the solved one
        n = len(lab[0])
        body = {k2: v if v.ndim == 1 else v[o:o + n] for k2, v in a.smplx.items()}
        output.vc_writer.add(*lab, smplx=body if ds.smplx is None else None)
        o += n
    src_obj = ds.objects[oid]
    output.writer.add_object(new_id, name=f"{src_obj['name']}~{edit.op}{new_id}", type=src_obj.get("type", ""),
                             mesh=edit.mesh)
    output.writer.add_sequence(name, seq.scene, a.joints, np.asarray(ds.actions[seq.start:seq.end]), a.contact,
                               a.object_poses, a.object_ids, smplx=a.smplx if ds.smplx is not None else None)
    output.used_scenes.add(seq.scene)
    output.used_objects.update(int(o) for o in np.unique(a.object_ids) if o >= 0 and o != new_id)
    output.stats.append(a.stats)
    output.records.append({"name": name, "source": seq.name, "object": int(oid), "new_object": new_id,
                           "op": edit.op, **edit.params, **{k2: round(v, 5) for k2, v in a.stats.items()}})


def _finish(ctx: AugmentContext, output: _Output, t0: float) -> tuple[Path, dict]:
    """The scenes and source objects the sequences use, the labels and the metadata written;
    the dataset published. Returns its path and the mean statistics."""
    ds, cfg, writer = ctx.ds, ctx.cfg, output.writer
    for sid in sorted(output.used_scenes):
        entry = ds.scenes[sid]
        writer.add_scene(sid, grid=ds.grid(sid) if entry.get("grid") else None, mesh=ds.scene_mesh(sid),
                         name=entry.get("name"))
    for oid in sorted(output.used_objects):
        entry = ds.objects.get(oid, {"name": f"object_{oid}", "type": ""})
        writer.add_object(oid, name=entry["name"], type=entry.get("type", ""), mesh=ctx.bank.object_mesh(oid))
    seconds = time.perf_counter() - t0
    summary = {k2: float(np.mean([s_[k2] for s_ in output.stats])) for k2 in output.stats[0]}
    output.vc_writer.finish({"joint_names": list(ds.joint_set.names), "config": asdict(cfg.contact),
                             "body": {"source": "augmentation solve", "model": str(ctx.bm.path)}})
    extra = {"augmented": {"from": str(ds.root.resolve()), "source": ds.meta.get("source"),
                           "config": {**asdict(cfg), "ops": list(cfg.ops)}, "sequences": output.records,
                           "skipped": output.skipped, "summary": summary, "seconds": round(seconds, 2)}}
    path = writer.finish(splits=ds.splits, source=f"{ds.meta.get('source', 'unknown')}+augmented", extra=extra)
    return path, summary


def _betas(b) -> np.ndarray:
    """(10,) float32: the body's betas, zero-padded to the format's 10."""
    out = np.zeros(SMPLX_FIELDS["betas"], np.float32)
    b = np.asarray(b, np.float32).ravel()[:len(out)]
    out[:len(b)] = b
    return out


def _sequence_stats(rt, joints_out, joints_src, joints_start, jt_old, jt_new, oid: int, new_id: int, parents) -> dict:
    """target_error_m: mean distance of moved joints to their targets where the offset is in
    full; contact_kept: share of the (frame, joint) contacts with the object that touch the new
    one; offset_m: mean offset there; away_m: mean joint distance to the source where no
    target is moved (the body model's fit of the data: `fit_m`, plus what the solve changed);
    bone_cv: median bone-length CV of the output."""
    full = rt.weights >= 1.0                                                      # (T, J)
    err = np.linalg.norm(joints_out - rt.targets, axis=-1)[full]
    was = jt_old == oid
    kept = (jt_new[was] == new_id).mean() if was.any() else 1.0
    off = np.linalg.norm(rt.offsets, axis=-1)[full]
    away = ~(rt.weights > 0).any(1)                                               # (T,) frames with no target moved
    dist = np.linalg.norm(joints_out - joints_src, axis=-1)
    fit = np.linalg.norm(joints_start - joints_src, axis=-1)
    return {"target_error_m": float(err.mean()) if err.size else 0.0, "contact_kept": float(kept),
            "offset_m": float(off.mean()) if off.size else 0.0,
            "away_m": float(dist[away].mean()) if away.any() else 0.0, "fit_m": float(fit.mean()),
            "bone_cv": float(bone_consistency(joints_out[:, :NUM_BODY_JOINTS], parents[:NUM_BODY_JOINTS]).cv_median)}


def _check(cfg: AugmentConfig) -> None:
    bad = [op for op in cfg.ops if op not in edits.OPS]
    if bad or not cfg.ops:
        raise ConfigError(f"ops: expected a non-empty list of {', '.join(edits.OPS)}, got {list(cfg.ops)}")
    if cfg.copies < 1 or cfg.window < 1 or cfg.ik_steps < 1 or cfg.min_contact_frames < 1:
        raise ConfigError("copies, window, ik_steps and min_contact_frames must be >= 1")
    if not 0 < cfg.scale_min <= cfg.scale_max:
        raise ConfigError(f"scale_min/scale_max: expected 0 < min <= max, got {cfg.scale_min}, {cfg.scale_max}")
    if not cfg.move > 0:
        raise ConfigError(f"move must be > 0 m, got {cfg.move}")


# ---------------------------------------------------------------------------------------
# CLI

SPEC = {"root": (str, None), "out": (str, None), "ops": (list, list(edits.OPS)), "copies": (int, 1),
        "split": (str, "train"), "window": (int, 30), "scale_min": (float, 0.8), "scale_max": (float, 1.25),
        "move": (float, 0.15), "seed": (int, 0), "min_contact_frames": (int, 3), "ik_steps": (int, 80),
        "object_meshes": (str, None), "body_model": (str, None), "overwrite": (bool, False),
        "progress": (bool, True)}
USAGE = "motiongen augment root=DATASET out=DIR [ops=[scale,swap,move]] [copies=1] ..."


def run(args: dict) -> AugmentResult:
    split = None if args["split"] in ("all", "none", "") else args["split"]
    cfg = AugmentConfig(ops=tuple(args["ops"]), copies=args["copies"], split=split, window=args["window"],
                        scale_min=args["scale_min"], scale_max=args["scale_max"], move=args["move"],
                        seed=args["seed"], min_contact_frames=args["min_contact_frames"], ik_steps=args["ik_steps"])
    return augment_dataset(args["root"], args["out"], cfg, args.get("body_model"), args.get("object_meshes"),
                           args["overwrite"], args["progress"])


def _report(r: AugmentResult) -> None:
    s = r.stats
    print(f"wrote {r.path}: {r.sequences} augmented sequences from {r.sources} source sequences in "
          f"{r.seconds:.0f} s ({r.per_minute:.1f} per minute); target error {100 * s['target_error_m']:.2f} cm, "
          f"contacts kept {100 * s['contact_kept']:.0f} %, bone CV {s['bone_cv']:.2e}"
          + (f"; skipped: {r.skipped}" if r.skipped else ""))


main = tool_main(lambda argv: run(parse_key_values(argv, SPEC, required=("root", "out"), usage=USAGE, doc=__doc__)),
                 _report)


if __name__ == "__main__":
    sys.exit(main())
