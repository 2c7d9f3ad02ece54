"""Per-vertex contact annotation speed: a 10,475-vertex SMPL-X-layout body against a furnished
room, and how the cost scales with vertices, frames and scene-mesh size.

    python benchmarks/contact_annotation.py [--frames 128] [--threads 2] [--full] [--out FILE.json]

Uses the embedded synthetic dataset (`small`, generated into the cache on first use): the
sequence with the most scene contact, its body fitted once (`fit_joints`, timed apart). Measures
frames/s of
  pose        posing the mesh and its vertex normals (BodyModel.vertices, batches of 32)
  exact       the default: pose + floor + exact scene-mesh distances on the culled vertices +
              objects (`annotate_frames`, MeshField)
  grid        the same with the scene as its occupancy grid (GridField; the TRUMANS case)
  naive       trimesh proximity (closest point + face side) on every vertex of every frame
and the scaling of the scene query with the number of vertices queried, the number of frames
(batch size) and the number of scene faces (the room subdivided; large meshes take the r-tree
path). --full also annotates the whole small dataset end to end (fitting included).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _rate(fn, frames: int, repeat: int = 2) -> float:
    """frames / the best of `repeat` timed runs (the machine may be shared)."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return frames / best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=128)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--full", action="store_true", help="also annotate the whole small dataset")
    ap.add_argument("--out", type=str, default=None)
    args = ap.parse_args()

    import numpy as np
    import torch
    import trimesh

    torch.set_num_threads(args.threads)
    from motiongen.body.fit import fit_joints
    from motiongen.body.model import load_body_model
    from motiongen.annotation.annotate_contact import SurfaceBank, annotate_frames
    from motiongen.annotation.vertex_contact import BodySurface, ContactConfig
    from motiongen.scene.distance_field import GridField, MeshField
    from motiongen.importers.sources import DataConfig, open_dataset

    ds = open_dataset(DataConfig(source="synthetic", size="small"))
    bm = load_body_model()
    body = BodySurface(bm, ds.joint_set)
    cfg = ContactConfig()
    # the sequence whose joints are most often labelled in contact with something other than the floor
    seq = max(ds.sequences, key=lambda s: int(np.asarray(ds.contact[s.start:s.end])[:, [0, 20, 21]].sum()))
    T = min(args.frames, seq.num_frames)
    s = seq.start
    t0 = time.perf_counter()
    fit = fit_joints(np.asarray(ds.joints[s:s + T]), bm)
    fit_s = time.perf_counter() - t0
    params = {"global_orient": fit.global_orient, "body_pose": fit.body_pose, "transl": fit.transl,
              "betas": np.asarray(fit.betas)}
    ids, poses = np.asarray(ds.object_ids[s:s + T]), np.asarray(ds.object_poses[s:s + T])
    mesh = ds.scene_mesh(seq.scene)
    out: dict = {"sequence": seq.name, "frames": T, "threads": args.threads, "vertices": body.num_vertices,
                 "scene_faces": int(len(mesh.faces)), "fit_s": round(fit_s, 2)}

    t0 = time.perf_counter()
    bank = SurfaceBank(ds, cfg)
    targets = bank.targets(seq.scene, ids)
    out["build_scene_field_s"] = round(time.perf_counter() - t0, 2)

    def run(tg, batch=32):
        for a in range(0, T, batch):
            annotate_frames(body, params, tg, ids, poses, cfg, slice(a, min(a + batch, T)))

    run(targets)                                                       # warm-up: culling masks, caches
    out["pose_fps"] = _rate(lambda: [body.pose(params, slice(a, min(a + 32, T))) for a in range(0, T, 32)], T)
    out["exact_fps"] = _rate(lambda: run(targets), T)
    t0 = time.perf_counter()
    grid_targets = bank.targets(seq.scene, ids)
    grid_targets.scene = GridField(ds.grid(seq.scene))
    out["build_grid_field_s"] = round(time.perf_counter() - t0, 2)
    run(grid_targets)                                                  # warm-up: culling mask
    out["grid_fps"] = _rate(lambda: run(grid_targets), T)

    # naive: trimesh proximity on every vertex (a few frames: it is slow)
    V, N = body.pose(params, slice(0, 4))
    normals = mesh.face_normals

    def naive():
        for v in V:
            c, d, tri = trimesh.proximity.closest_point(mesh, v)
            np.einsum("nc,nc->n", v - c, normals[tri])
    out["naive_fps"] = _rate(naive, len(V))

    # how much of the body gets an exact query, and the query's cost per vertex count / batch
    V, N = body.pose(params, slice(0, 32))
    fld = targets.scene
    flat = V.reshape(-1, 3)
    near = fld._near_grid(cfg.threshold).occupied(flat, outside=False)
    out["near_share"] = float(near.mean())
    rng = np.random.default_rng(0)
    scaling = []
    for k in (1000, 3000, body.num_vertices):
        sub = V[:, rng.choice(body.num_vertices, k, replace=False)].reshape(-1, 3)
        ms = 1000 / _rate(lambda: fld.query(sub, cfg.threshold), 32)
        scaling.append({"vertices": k, "scene_query_ms_per_frame": round(ms, 2)})
    out["scaling_vertices"] = scaling
    out["scaling_frames"] = [{"batch": b, "exact_fps": round(_rate(lambda: run(targets, b), T), 1)} for b in (8, 32, T)]
    faces = []
    for edge in (None, 0.25, 0.1):
        m = mesh if edge is None else trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, edge))
        t0 = time.perf_counter()
        f = MeshField(m, voxel_size=cfg.voxel_size)
        f.query(flat[:10], cfg.threshold)
        build = time.perf_counter() - t0
        ms = 1000 / _rate(lambda: f.query(flat, cfg.threshold), 32)
        faces.append({"faces": int(len(m.faces)), "build_s": round(build, 2), "scene_query_ms_per_frame": round(ms, 2)})
    out["scaling_faces"] = faces

    if args.full:
        import shutil
        import tempfile

        from motiongen.annotation.annotate_contact import annotate_dataset

        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp) / "ds"
            shutil.copytree(ds.root, root)
            r = annotate_dataset(root, cfg, bm, progress=False)
            out["full"] = {"frames": r.frames, "seconds": round(r.seconds, 1), "fit_seconds": round(r.fit_seconds, 1),
                           "frames_per_s": round(r.frames_per_second, 1),
                           "frames_per_s_without_fit": round(r.frames / max(r.seconds - r.fit_seconds, 1e-9), 1),
                           "penetration": r.table}
    for k in ("pose_fps", "exact_fps", "grid_fps", "naive_fps"):
        out[k] = round(out[k], 1)
    print(json.dumps(out, indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
