"""Adapter for the public TRUMANS release (``Data_release/``) into the motiongen format.

The release is one set of frame-concatenated arrays (N frames over all sequences) plus a
``Scene/`` folder of dense occupancy grids. We read every array with ``mmap_mode="r"`` and
stream sequence by sequence through `DatasetWriter`, so RAM holds one sequence and one scene
grid at a time, never the release. Everything is validated at open (presence, shapes, dtypes,
cross-file N, index ranges) or while streaming (values), and any failure aborts the writer,
so ``out`` is either a complete dataset or untouched.

Interpretations of the release (see docs/data_format.md, "TRUMANS release mapping"):
- sequences: a new sequence starts wherever ``seg_name`` changes (``idx_start`` holds
  *window* starts and ``frame_id`` is what the reference loader iterates; neither is used to
  cut sequences). Output sequences are grouped by scene, release order within a scene.
- scene ids: `scene_ids_from_names`; objects: `interpret_object_flags` (reading the release:
  `motiongen.importers.trumans_release`); contacts (not in the release): `scene_contact`.

CLI:  motiongen import-trumans release=DIR out=DIR [joints=body] [overwrite=true]
      [progress=false] [allow_pickle=true]
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

from motiongen.cli import parse_key_values, tool_main
from motiongen.data.format import DEFAULT_SPLITS
from motiongen.data.dataset_writer import DatasetWriter
from motiongen.scene.occupancy import OccupancyGrid, near_occupied
from motiongen.importers.trumans_release import (_NUM_BETAS, CONTACT_RADIUS, NUM_OBJECT_SLOTS, TRUMANS_ACTIONS,
                                            TRUMANS_FPS, TRUMANS_GRID, GridSpec, TrumansRelease, TrumansSequence,
                                            interpret_object_flags, open_release)
from motiongen.errors import DataError
from motiongen.output_lock import refuse_output_over_input
from motiongen.skeleton import get_joint_set


def scene_contact(joints: np.ndarray, near: OccupancyGrid, floor_y: float, radius: float) -> np.ndarray:
    """Per-joint contact (T,J) bool for joints (T,J,3): the joint's voxel is within `radius`
    of an occupied scene voxel (`near` = the grid dilated by `radius`, see `near_occupied`), or
    the joint is less than `radius` above the floor plane y = `floor_y`.

    The release has no contact labels, and its object meshes are not part of the layout we
    read, so this is scene + floor contact only: a hand holding a bottle is not in contact.
    Joints outside the grid touch nothing but the floor.
    """
    return near.occupied(joints, outside=False) | (joints[..., 1] - floor_y < radius)


# ---------------------------------------------------------------------------------------
# Conversion


def _finite_rows(a: np.ndarray, path: Path, name: str, frame0: int) -> None:
    ok = np.isfinite(a.reshape(a.shape[0], -1)).all(axis=1)
    if not ok.all():
        raise DataError(path, name, f"non-finite value (NaN or inf) at frame {frame0 + int(np.argmin(ok))}")


def _sequence_arrays(rel: TrumansRelease, seq: TrumansSequence, joint_idx: list[int], near: OccupancyGrid,
                     radius: float) -> dict:
    """Everything `DatasetWriter.add_sequence` needs for one release sequence."""
    s, e = seq.start, seq.end
    A = rel.arrays
    joints = np.asarray(A["human_joints"][s:e], np.float32)[:, joint_idx]      # (T,J,3)
    _finite_rows(joints, rel.path("human_joints"), "human_joints", s)
    labels = np.asarray(A["action_label"][s:e])                                 # (T,10)
    if labels.dtype.kind == "f":
        _finite_rows(labels, rel.path("action_label"), "action_label", s)
    actions = labels >= 0.5 if labels.dtype.kind != "b" else labels             # (T,10) bool
    contact = scene_contact(joints, near, rel.grid.origin[1], radius)           # (T,J) bool
    ids, poses = interpret_object_flags(np.asarray(A["object_flag"][s:e]), np.asarray(A["object_mat"][s:e]),
                                        rel.path("object_flag"), s)
    smplx = None
    if rel.smplx is not None:
        smplx = {"global_orient": np.asarray(A["human_orient"][s:e], np.float32),     # (T,3) axis-angle
                 "body_pose": np.asarray(rel.smplx["human_pose"][s:e], np.float32),   # (T,63)
                 "transl": np.asarray(rel.smplx["human_transl"][s:e], np.float32)}    # (T,3)
        for k, src in (("global_orient", "human_orient"), ("body_pose", "human_pose"), ("transl", "human_transl")):
            _finite_rows(smplx[k], rel.path(src), src, s)
        if rel.betas is None:
            smplx["betas"] = np.zeros(_NUM_BETAS, np.float32)                 # mean shape
        elif rel.betas.ndim == 1:
            smplx["betas"] = np.asarray(rel.betas[:_NUM_BETAS], np.float32)
        else:
            smplx["betas"] = np.asarray(rel.betas[s:e, :_NUM_BETAS], np.float32)      # (T,10)
            _finite_rows(smplx["betas"], rel.path("human_betas"), "human_betas", s)
    return dict(joints=joints, actions=actions, contact=contact, object_ids=ids, object_poses=poses, smplx=smplx)


def convert_trumans(release_dir: str | Path, out_dir: str | Path, joints: str = "body+index1",
                    overwrite: bool = False, progress: bool = True, *, allow_pickle: bool = False,
                    grid: GridSpec = TRUMANS_GRID, contact_radius: float = CONTACT_RADIUS) -> Path:
    """Convert a TRUMANS ``Data_release/`` directory into a motiongen dataset at `out_dir`.

    joints: "body+index1" keeps all 24 release joints, "body" the first 22.
    allow_pickle: trust pickled files: load norm.npy (recorded in meta.json as
    ``trumans.norm``) and accept a seg_name.npy stored as an object array. Off by default.
    grid: geometry of Scene/*.npy (the release's; smaller only for tests).
    Returns the dataset path. On any error nothing is left at `out_dir` (an existing dataset
    there is only replaced, atomically, when the conversion succeeds and `overwrite` is set).
    """
    js = get_joint_set(joints)
    out = Path(out_dir)
    refuse_output_over_input(out, [release_dir], "out")   # overwrite= replaces a dataset, never the release
    if out.exists() and not overwrite:
        raise DataError(out, None, "output directory already exists (pass overwrite=true)")
    rel = open_release(release_dir, grid=grid, allow_pickle=allow_pickle)
    joint_idx = list(range(js.num_joints))  # release order is body 0..21 then index1 L/R, as ours
    log = (lambda msg: print(msg, file=sys.stderr, flush=True)) if progress else (lambda msg: None)

    by_scene: dict[int, list[TrumansSequence]] = {}
    for seq in rel.sequences:
        by_scene.setdefault(seq.scene_index, []).append(seq)
    writer = DatasetWriter(out, js, list(TRUMANS_ACTIONS), fps=TRUMANS_FPS, num_object_slots=NUM_OBJECT_SLOTS,
                           has_smplx=rel.smplx is not None, overwrite=overwrite)
    try:
        for oid, name in enumerate(rel.object_names):
            writer.add_object(oid, name=name, type=re.sub(r"[_\-\s]*\d+$", "", name) or name)
        for si, (path, sid) in enumerate(zip(rel.scene_files, rel.scene_ids)):
            occ = np.asarray(np.load(path, mmap_mode="r"))                # (X,Y,Z) bool, ~12 MB
            writer.add_scene(sid, grid=OccupancyGrid.from_dense(occ, grid.origin, grid.voxel_size), name=path.stem)
            seqs = by_scene.get(si, [])
            if seqs:
                near = OccupancyGrid.from_dense(near_occupied(occ, contact_radius / grid.voxel_size),
                                                grid.origin, grid.voxel_size)
                for seq in seqs:
                    writer.add_sequence(seq.name, scene=sid, **_sequence_arrays(rel, seq, joint_idx, near,
                                                                                contact_radius))
            del occ
            log(f"trumans: scene {si + 1}/{len(rel.scene_files)} {path.name} (id {sid}): {len(seqs)} sequences, "
                f"{sum(s.end - s.start for s in seqs)} frames")
        extra = {"trumans": {
            "release": str(rel.root.resolve()),
            "scene_files": {str(sid): p.name for sid, p in zip(rel.scene_ids, rel.scene_files)},
            "scene_id_rule": rel.scene_id_rule,
            "contact": f"scene voxel within {contact_radius} m (voxel centres) or joint < {contact_radius} m "
                       f"above the floor y={grid.origin[1]}",
            "object_flag": "object_flag[n, type] = slot in object_mat[n] (-1 absent); object id = type",
            "norm": rel.norm,
        }}
        return writer.finish(splits=DEFAULT_SPLITS, source="trumans", extra=extra)
    except BaseException:
        writer.abort()
        raise


# ---------------------------------------------------------------------------------------
# CLI

_CLI_SPEC = {"release": (str, None), "out": (str, None), "joints": (str, "body+index1"), "overwrite": (bool, False),
             "progress": (bool, True), "allow_pickle": (bool, False)}


def parse_cli(argv: list[str]) -> dict:
    """key=value arguments -> convert_trumans kwargs; ConfigError on anything else."""
    return parse_key_values(argv, _CLI_SPEC, required=("release", "out"),
                            usage="motiongen import-trumans release=DIR out=DIR", doc=__doc__.split("CLI:")[1])


def run(argv: list[str]) -> Path:
    kw = parse_cli(argv)
    return convert_trumans(kw.pop("release"), kw.pop("out"), **kw)


main = tool_main(run, lambda path: print(f"wrote {path}"))


if __name__ == "__main__":
    sys.exit(main())
