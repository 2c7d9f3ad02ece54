"""Per-vertex contact annotation of a dataset (TRUMANS supp. B.6): for every frame, which
vertices of the posed body mesh touch the floor, the scene or an object, and which.

    motiongen annotate-contact root=DATASET [threshold=0.02] [max_angle=60]
        [floor=true] [floor_y=0] [scene=auto|mesh|grid] [voxel_size=0.02] [object_meshes=DIR]
        [body_model=PATH] [fit_mlp=none|auto|PATH] [batch=32] [overwrite=false] [progress=true]

The body is the dataset's SMPL-X parameters posed with the body model (`body_model=`, else
$MOTIONGEN_SMPLX_MODEL, else the procedural model); joint-only datasets are fitted first
(`motiongen.body.fit.fit_joints`) and the fitted parameters are stored with the labels. The
labels go to ``DATASET/vertex_contact/`` (`motiongen.data.contact_labels`) together with the
penetration statistics of supp. Fig. A3 (``penetration.png``, ``penetration.csv``).
Library: `annotate_dataset(root, ContactConfig(...), ...)`; rules in `motiongen.annotation.vertex_contact`.
"""

from __future__ import annotations

import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from motiongen.body.fit import fit_joints
from motiongen.body.model import BodyModel, load_body_model
from motiongen.cli import parse_key_values, tool_main
from motiongen.annotation.vertex_contact import (TARGET_NAMES, BodySurface, ContactConfig, SceneTargets,
                                    joint_targets, penetration_per_frame, vertex_contacts)
from motiongen.data.contact_labels import VertexContactWriter
from motiongen.annotation.contact_stats import penetration_table, plot_penetration, write_table
from motiongen.scene.distance_field import OBJECT_VOXEL, MeshField, PlaneField, surface_distance
from motiongen.data.format import SMPLX_FIELDS, MotionDataset, Sequence
from motiongen.scene.mesh_files import MESH_SUFFIXES, load_mesh_file
from motiongen.errors import ConfigError, DataError
from motiongen.output_lock import OutputLock
from motiongen.skeleton import NUM_BODY_JOINTS

# The formats scene meshes are read in, .ply (what datasets store objects as) tried first.
OBJECT_SUFFIXES = (".ply",) + tuple(s for s in MESH_SUFFIXES if s != ".ply")


@dataclass
class AnnotationResult:
    path: Path                # the labels folder
    frames: int
    seconds: float            # annotation time (fitting included)
    fit_seconds: float        # of which fitting joint-only sequences
    table: dict               # penetration statistics (contact_stats.penetration_table)
    body: str                 # "dataset" (its SMPL-X) or "fitted"
    skipped_objects: list     # names of objects without a mesh (not annotated)

    @property
    def frames_per_second(self) -> float:
        return self.frames / max(self.seconds, 1e-9)


class SurfaceBank:
    """Fields of a dataset's scenes and objects, built on first use and kept (object fields
    are shared by every scene an object appears in)."""

    def __init__(self, ds: MotionDataset, cfg: ContactConfig, object_meshes: str | Path | None = None):
        self.ds, self.cfg = ds, cfg
        self.mesh_dir = Path(object_meshes) if object_meshes else None
        if self.mesh_dir is not None and not self.mesh_dir.is_dir():
            raise DataError(self.mesh_dir, "object_meshes", "folder does not exist")
        self._objects: dict[int, tuple | None] = {}
        self._meshes: dict[int, object] = {}
        self._scenes: dict[int, object] = {}
        self.skipped: set[str] = set()

    def object_mesh(self, oid: int):
        """The object's mesh (its local frame): the dataset's, else `<object_meshes>/<name>.*`,
        else None."""
        if oid not in self._meshes:
            mesh = self.ds.object_mesh(oid)
            if mesh is None and self.mesh_dir is not None:
                name = self.ds.objects.get(oid, {}).get("name", str(oid))
                for suffix in OBJECT_SUFFIXES:
                    if (self.mesh_dir / f"{name}{suffix}").is_file():
                        mesh = load_mesh_file(self.mesh_dir / f"{name}{suffix}")
                        break
            self._meshes[oid] = mesh
        return self._meshes[oid]

    def scene_field(self, scene: int):
        """The static scene's field (its mesh, else its grid, per `ContactConfig.scene`), or None."""
        if scene not in self._scenes:
            cfg = self.cfg
            mesh = self.ds.scene_mesh(scene) if cfg.scene in ("auto", "mesh") else None
            fld = None
            if mesh is not None:
                fld = MeshField(mesh, voxel_size=cfg.voxel_size)
            elif cfg.scene == "mesh":
                raise DataError(self.ds.root / "scenes.json", str(scene), "scene has no mesh (use scene=auto or grid)")
            elif (self.ds.scenes.get(scene) or {}).get("grid"):
                fld = surface_distance(self.ds.grid(scene))          # the grid keeps it
            self._scenes = {scene: fld}          # sequences come scene by scene: keep one
        return self._scenes[scene]

    def _object(self, oid: int):
        if oid not in self._objects:
            mesh = self.object_mesh(oid)
            if mesh is None:
                self.skipped.add(self.ds.objects.get(oid, {}).get("name", str(oid)))
                self._objects[oid] = None
            else:
                voxel = min(self.cfg.voxel_size, OBJECT_VOXEL)
                self._objects[oid] = (MeshField(mesh, voxel_size=voxel), np.asarray(mesh.vertices, np.float64))
        return self._objects[oid]

    def targets(self, scene: int, object_ids: np.ndarray | None) -> SceneTargets:
        cfg = self.cfg
        if cfg.scene not in ("auto", "mesh", "grid"):
            raise ConfigError(f"scene={cfg.scene!r}: expected auto, mesh or grid")
        t = SceneTargets(floor=PlaneField(cfg.floor_y) if cfg.floor else None, scene=self.scene_field(scene))
        if object_ids is not None:
            for oid in np.unique(np.asarray(object_ids)):
                if oid >= 0 and self._object(int(oid)) is not None:
                    fld, verts = self._object(int(oid))
                    t.add_object(int(oid), fld, verts)
        return t


def check_rigid(poses: np.ndarray, ids: np.ndarray, path: Path, frame0: int, tol: float = 1e-3) -> None:
    """Object poses (T, K, 4, 4) of present objects must be rigid (rotation + translation)."""
    on = ids >= 0
    if not on.any():
        return
    R = poses[..., :3, :3][on].astype(np.float64)                                     # (n, 3, 3)
    err = np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max((-1, -2))
    bad = np.flatnonzero(err > tol) if err.size else []
    if len(bad):
        f = frame0 + int(np.nonzero(on)[0][bad[0]])
        raise DataError(path, "object_poses", f"pose of a present object at frame {f} is not a rigid transform "
                                              f"(|R Rᵀ - I| = {err[bad[0]]:.3g})")


def sequence_body(ds: MotionDataset, seq: Sequence, bm: BodyModel, fit_mlp=None) -> tuple[dict, str]:
    """SMPL-X parameters {field: (T, d)} of a sequence: the dataset's, else fitted to its joints."""
    s, e = seq.start, seq.end
    if ds.smplx is not None:
        return {k: np.asarray(ds.smplx[k][s:e]) for k in SMPLX_FIELDS}, "dataset"
    fit = fit_joints(np.asarray(ds.joints[s:e, :NUM_BODY_JOINTS]), bm, mlp=fit_mlp)
    betas = np.zeros(SMPLX_FIELDS["betas"], np.float32)
    betas[:len(fit.betas)] = fit.betas
    return {"global_orient": fit.global_orient, "body_pose": fit.body_pose, "transl": fit.transl,
            "betas": np.broadcast_to(betas, (e - s, len(betas)))}, "fitted"


def annotate_frames(body: BodySurface, params: dict, targets: SceneTargets, object_ids, object_poses,
                    cfg: ContactConfig, frames: slice):
    """Labels of `frames` of one sequence's parameters: (target (B, V), distance (B, V),
    joints (B, J), penetration (B, 3), penetrating (B,))."""
    V, N = body.pose(params, frames)
    ids = None if object_ids is None else np.asarray(object_ids[frames])
    poses = None if object_poses is None else np.asarray(object_poses[frames])
    c = vertex_contacts(V, N, targets, ids, poses, cfg)
    pen, n = penetration_per_frame(c)
    return c.target, c.distance, joint_targets(c, body.region, body.joint_set.num_joints), pen, n


def annotate_dataset(root: str | Path, cfg: ContactConfig = ContactConfig(), body_model: BodyModel | str | None = None,
                     object_meshes: str | Path | None = None, fit_mlp=None, overwrite: bool = False,
                     progress: bool = True) -> AnnotationResult:
    """Annotate every frame of the dataset at `root`; write ``root/vertex_contact/``."""
    _check_config(cfg)
    ds = MotionDataset.open(root)
    bm = body_model if isinstance(body_model, BodyModel) else load_body_model(body_model)
    body = BodySurface(bm, ds.joint_set)
    bank = SurfaceBank(ds, cfg, object_meshes)
    fitted = ds.smplx is None
    writer = VertexContactWriter(ds.root, body.num_vertices, ds.joint_set.num_joints, overwrite, smplx=fitted)
    log = (lambda m: print(m, file=sys.stderr, flush=True)) if progress else (lambda m: None)
    t0, fit_s = time.perf_counter(), 0.0
    pens, counts = [], []
    try:
        for i, seq in enumerate(ds.sequences):
            ids = poses = None
            if ds.object_ids is not None:
                ids, poses = ds.object_ids[seq.start:seq.end], ds.object_poses[seq.start:seq.end]
            targets = bank.targets(seq.scene, ids)
            if targets.objects:
                on = np.isin(np.asarray(ids), list(targets.objects))
                check_rigid(np.asarray(poses), np.where(on, ids, -1), ds.root / "object_poses.npy", seq.start)
            tf = time.perf_counter()
            params, source = sequence_body(ds, seq, bm, fit_mlp)
            fit_s += time.perf_counter() - tf
            for s in range(0, seq.num_frames, cfg.batch_frames):
                fr = slice(s, min(s + cfg.batch_frames, seq.num_frames))
                tgt, dist, jt, pen, n = annotate_frames(body, params, targets, ids, poses, cfg, fr)
                writer.add(tgt, dist, jt, pen, n, smplx={k: v[fr] for k, v in params.items()} if fitted else None)
                pens.append(pen)
                counts.append(n)
            log(f"annotate_contact: {i + 1}/{len(ds.sequences)} {seq.name}: {seq.num_frames} frames "
                f"({time.perf_counter() - t0:.0f} s)")
        pen = np.concatenate(pens) if pens else np.zeros((0, 3), np.float32)
        table = penetration_table(pen, np.concatenate(counts) if counts else np.zeros(0, np.int32))
        seconds = time.perf_counter() - t0
        info = {"joint_names": list(ds.joint_set.names), "config": asdict(cfg),
                "targets": {str(k): v for k, v in TARGET_NAMES.items()} | {"objects": "object id (objects.json)"},
                "body": {"source": "fitted" if fitted else "dataset", "model": str(bm.path),
                         "procedural": bool(bm.is_procedural), "fit_mlp": str(fit_mlp) if fitted else None},
                "objects_without_mesh": sorted(bank.skipped), "penetration": table,
                "seconds": round(seconds, 2), "fit_seconds": round(fit_s, 2)}
        path = writer.finish(info)
    except BaseException:
        writer.abort()
        raise
    write_table(path / "penetration.csv", table)
    plot_penetration(path / "penetration.png", pen, title=f"{ds.root.name}: penetration per frame")
    if bank.skipped:
        log(f"annotate_contact: {len(bank.skipped)} object(s) have no mesh and were not annotated "
            f"(give object_meshes=DIR): {', '.join(sorted(bank.skipped)[:5])}{' ...' if len(bank.skipped) > 5 else ''}")
    return AnnotationResult(path, ds.num_frames, seconds, fit_s, table, "fitted" if fitted else "dataset",
                            sorted(bank.skipped))


def _check_config(cfg: ContactConfig) -> None:
    if not cfg.threshold >= 0:
        raise ConfigError(f"threshold must be >= 0 m, got {cfg.threshold}")
    if not 0 < cfg.max_angle <= 180:
        raise ConfigError(f"max_angle must be in (0, 180] degrees, got {cfg.max_angle}")
    if not cfg.voxel_size > 0 or cfg.batch_frames < 1:
        raise ConfigError(f"voxel_size must be > 0 and batch >= 1, got {cfg.voxel_size}, {cfg.batch_frames}")
    if cfg.scene not in ("auto", "mesh", "grid"):
        raise ConfigError(f"scene={cfg.scene!r}: expected auto, mesh or grid")


# ---------------------------------------------------------------------------------------
# CLI

SPEC = {"root": (str, None), "threshold": (float, 0.02), "max_angle": (float, 60.0), "floor": (bool, True),
        "floor_y": (float, 0.0), "scene": (str, "auto"), "voxel_size": (float, 0.02), "object_meshes": (str, None),
        "body_model": (str, None), "fit_mlp": (str, "none"), "batch": (int, 32), "overwrite": (bool, False),
        "progress": (bool, True)}
USAGE = "motiongen annotate-contact root=DATASET [threshold=0.02] [max_angle=60] ..."


def run(args: dict) -> AnnotationResult:
    cfg = ContactConfig(threshold=args["threshold"], max_angle=args["max_angle"], floor=args["floor"],
                        floor_y=args["floor_y"], scene=args["scene"], voxel_size=args["voxel_size"],
                        batch_frames=args["batch"])
    mlp = None if args["fit_mlp"] in ("none", "", None) else args["fit_mlp"]
    if not Path(args["root"]).is_dir():
        raise DataError(args["root"], None, "dataset directory does not exist")
    with OutputLock(args["root"], "annotate-contact"):   # the labels go into the dataset: one run at a time
        return annotate_dataset(args["root"], cfg, args.get("body_model"), args.get("object_meshes"), mlp,
                                args["overwrite"], args["progress"])


def _report(r: AnnotationResult) -> None:
    t = r.table
    print(f"wrote {r.path}: {r.frames} frames in {r.seconds:.1f} s ({r.frames_per_second:.1f} frames/s, "
          f"body {r.body}); penetrating frames {t['frames_penetrating']}/{t['frames']}; "
          f"mean/median penetration < 2 cm in {100 * t['share_below']['mean']['<2 cm']:.1f} / "
          f"{100 * t['share_below']['median']['<2 cm']:.1f} % of frames")


main = tool_main(lambda argv: run(parse_key_values(argv, SPEC, required=("root",), usage=USAGE, doc=__doc__)),
                 _report)


if __name__ == "__main__":
    sys.exit(main())
