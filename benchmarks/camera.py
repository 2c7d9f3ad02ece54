"""The video's cameras compared (not a timed test): for each motion, the `follow` and the
`adaptive` camera (`video_camera=`), in one run:

* pelvis seen: share of frames whose pelvis is inside the panel and not hidden by the scene
  (the ray from the camera first meets the scene within 10 cm of it, or not at all);
* hand seen: the same for the interacting wrist, over the frames where a wrist is within 20 cm
  of a dynamic object (the adaptive camera's own rule for which hand interacts); wrist seen:
  the active wrist (that one, else the right) over all frames;
* camera turn: the view direction's speed about the vertical, deg/s (mean, 95th percentile);
* camera inside: frames whose camera stands inside the scene's geometry;
* path time: computing the camera path, ms per frame; render: drawing the video with it
  (the scene's mesh, the stick figure: the data has no body parameters; `frames` frames
  spread over the motion, one process), ms per frame.

    python benchmarks/camera.py [split=test] [frames=60] [mesh=PATH motion=motion.npz [scene_up=y] [scene_unit=m]]

Without mesh=: the first sequence of each scene of the embedded synthetic dataset's split, the
data's own motion with its objects moving, rays against each scene's mesh. With mesh= and
motion=: a motion that `motiongen sample` generated in that mesh (its sample 0), rays against
the mesh (e.g. the FZK house of Debian's assimp-testmodels, converted to OBJ by assimp).
"""

from __future__ import annotations

import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from motiongen.cli import parse_key_values, tool_main  # noqa: E402
from motiongen.export.adaptive_camera import ARMS, GridRays, MeshRays, acting_hands, visible  # noqa: E402
from motiongen.export.video import render_video  # noqa: E402
from motiongen.export.video_camera import camera_path  # noqa: E402
from motiongen.importers.sources import DataConfig, open_dataset  # noqa: E402
from motiongen.scene.mesh_files import load_scene_grid, load_scene_mesh  # noqa: E402
from motiongen.skeleton import PELVIS  # noqa: E402

SPEC = {"split": (str, "test"), "frames": (int, 60), "mesh": (str, None), "motion": (str, None),
        "scene_up": (str, "y"), "scene_unit": (str, "m")}
MODES = ("follow", "adaptive")


def object_points(ds, seq, n: int = 128) -> np.ndarray | None:
    """(T, N, 3) points on the sequence's objects, moving with them, or None."""
    if ds.object_ids is None:
        return None
    ids = np.asarray(ds.object_ids[seq.start:seq.end])
    poses = np.asarray(ds.object_poses[seq.start:seq.end])                                  # (T, S, 4, 4)
    pts = []
    for slot in range(ids.shape[1]):
        mesh = ds.object_mesh(int(ids[0, slot])) if ids[0, slot] >= 0 else None
        if mesh is None:
            continue
        v = np.asarray(mesh.vertices)[np.linspace(0, len(mesh.vertices) - 1, min(n, len(mesh.vertices))).astype(int)]
        P = poses[:, slot]
        pts.append(np.einsum("tij,nj->tni", P[:, :3, :3], v) + P[:, None, :3, 3])
    return np.concatenate(pts, 1) if pts else None


def seen(rays, path, joints: np.ndarray, joint: np.ndarray) -> np.ndarray:
    """(T,) whether joint[t] of joints (T, J, 3) is seen from the path's camera at frame t."""
    return np.array([visible(rays, path.position[t][None], joints[t, [joint[t]]][None], [path.at(t)])[0, 0]
                     for t in range(len(joints))])


def figures(mode: str, joints, fps, grid, mesh, objects, frames: int) -> dict:
    t0 = time.perf_counter()
    path = camera_path(mode, joints, fps, grid, mesh, objects)
    t_path = (time.perf_counter() - t0) / len(joints)
    rays = MeshRays(mesh) if mesh is not None else GridRays(grid)
    side, acting = acting_hands(joints, objects)
    wrist = np.array([ARMS[s][-1] for s in side])
    pelvis = seen(rays, path, joints, np.full(len(joints), PELVIS))
    wrist_seen = seen(rays, path, joints, wrist)
    hand = wrist_seen[acting]
    d = path.target - path.position
    speed = np.degrees(np.abs(np.diff(np.unwrap(np.arctan2(d[:, 0], d[:, 2]))))) * fps
    inside = int(grid.occupied(path.position, outside=False).sum()) if grid is not None else 0
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        render_video(Path(tmp) / "v.mp4", joints, fps, grid=grid, max_frames=frames, style="skeleton", camera=path,
                     workers=1, scene_mesh=mesh)
        t_render = (time.perf_counter() - t0) / min(frames, len(joints))
    return {"pelvis": pelvis.mean(), "hand": hand.mean() if len(hand) else float("nan"), "n_hand": len(hand), "wrist": wrist_seen.mean(),
            "turn": speed.mean(), "turn95": np.percentile(speed, 95), "inside": inside, "path_ms": 1e3 * t_path,
            "render_ms": 1e3 * t_render}


def row(label: str, mode: str, f: dict) -> str:
    return (f"{label:24s} {mode:9s} {100 * f['pelvis']:8.1f} {100 * f['hand']:8.1f} {f['n_hand']:7d} {100 * f['wrist']:8.1f} "
            f"{f['turn']:8.1f} {f['turn95']:8.1f} {f['inside']:7d} {f['path_ms']:8.2f} {f['render_ms']:9.1f}")


def motions(opts):
    """(label, joints (T, J, 3), fps, grid, mesh, objects) per motion."""
    if opts["mesh"]:
        z = np.load(opts["motion"])
        grid = load_scene_grid(opts["mesh"], up=opts["scene_up"], unit=opts["scene_unit"])
        mesh = load_scene_mesh(opts["mesh"], up=opts["scene_up"], unit=opts["scene_unit"])
        yield Path(opts["mesh"]).name, z["joints"][0].astype(np.float64), float(z["fps"]), grid, mesh, None
        return
    ds = open_dataset(DataConfig(), verbose=False)
    for scene in ds.splits[opts["split"]]:
        seq = next((s for s in ds.sequences if s.scene == scene), None)
        if seq is not None:
            joints = np.asarray(ds.joints[seq.start:seq.end], np.float64)
            yield seq.name, joints, ds.fps, ds.grid(scene), ds.scene_mesh(scene), object_points(ds, seq)


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, usage=__doc__.splitlines()[11].strip())
    warnings.simplefilter("ignore")
    print(f"{'motion':24s} {'camera':9s} {'pelvis %':>8s} {'hand %':>8s} {'hand fr':>7s} {'wrist %':>8s} {'turn °/s':>8s} "
          f"{'p95 °/s':>8s} {'inside':>7s} {'path ms':>8s} {'render ms':>9s}")
    totals = {m: [] for m in MODES}
    for label, joints, fps, grid, mesh, objects in motions(opts):
        for mode in MODES:
            f = figures(mode, joints, fps, grid, mesh, objects, opts["frames"])
            totals[mode].append(f)
            print(row(label, mode, f), flush=True)
    for mode in MODES:
        fs = totals[mode]
        n_hand = sum(f["n_hand"] for f in fs)
        mean = {k: float(np.mean([f[k] for f in fs])) for k in ("pelvis", "wrist", "turn", "turn95", "path_ms",
                                                                 "render_ms")}
        mean["hand"] = sum(f["hand"] * f["n_hand"] for f in fs if f["n_hand"]) / max(n_hand, 1)
        print(row("mean (hand: per frame)", mode, {**mean, "n_hand": n_hand, "inside": sum(f["inside"] for f in fs)}))


if __name__ == "__main__":
    sys.exit(tool_main(run)())
