"""Sample-video rendering speed: the camera panel drawn with OpenGL (`gl_render`) vs the old
matplotlib boxes + numpy body rasteriser, in a synthetic room and in a mesh scene (one run).

    python benchmarks/video.py [--frames 300] [--workers 0] [--mesh /tmp/haus.obj --start 5.54 -0.62]
                               [--msaa 0] [--workers-check]

A walking body of the procedural model (`sample_motion` with gait, seed 7), rendered as
`sample.py` renders it (skinned body, planted feet marked, walkable map, 800 x 352 at 30 fps)
with --workers processes (0: render_video's default, one per core up to 4). Scenes: a
synthetic room (`synthetic.scenes.make_scene`, seed 3; OpenGL shows its mesh, the old path its
occupancy as boxes) and, with --mesh, that mesh file (y up, metres), the walk moved to
--start (x z; default: the mesh's centre). Prints frames/s of both paths and their ratio per
scene. --msaa: OpenGL multisampling (0: none, the default). --workers-check: also render
the synthetic scene with OpenGL in one process and compare the videos' frames (identical).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from motiongen.body.model import BodyModel  # noqa: E402
from motiongen.body.procedural import ensure_procedural_model  # noqa: E402
from motiongen.body.random_motion import sample_motion  # noqa: E402
from motiongen.export import gl_render  # noqa: E402
from motiongen.export.video import render_video  # noqa: E402
from motiongen.metrics import TOE_JOINTS  # noqa: E402
from motiongen.routing import walkable_map  # noqa: E402
from motiongen.scene.mesh_files import load_scene_grid, load_scene_mesh  # noqa: E402
from motiongen.synthetic.scenes import make_scene  # noqa: E402


def walk(bm: BodyModel, frames: int, start_xz: np.ndarray) -> tuple[np.ndarray, dict]:
    """Joints (1, T, 22, 3) and body parameters of the procedural walk, moved to start_xz (2,)."""
    m = sample_motion(frames, 30.0, np.random.default_rng(7), gait=True)
    m["transl"] = m["transl"] + np.array([start_xz[0], 0.0, start_xz[1]], m["transl"].dtype)
    with torch.no_grad():
        joints = bm.joints(*(torch.as_tensor(m[k]) for k in ("global_orient", "body_pose", "transl", "betas")))
    return joints.numpy()[None], m


def timed(path: Path, joints: np.ndarray, **kw) -> tuple[float, Path]:
    """frames/s of render_video over the whole video (drawing and encoding) and the path written."""
    t0 = time.perf_counter()
    out = render_video(path, joints, 30.0, **kw)
    return joints.shape[1] / (time.perf_counter() - t0), out


def compare(name: str, tmp: Path, bm, m: dict, joints: np.ndarray, grid, mesh, workers: int | None) -> Path:
    """Prints both paths' frames/s in one scene; returns the OpenGL video."""
    toes = joints[0, :, list(TOE_JOINTS), 1]                                          # (2, T) toe heights
    planted = (toes < toes.min(1, keepdims=True) + 0.03).T[None]                      # (1, T, 2)
    kw = dict(bodies=[SimpleNamespace(**m)], body_model=bm, planted=planted, contact_joints=list(TOE_JOINTS),
              grid=grid, walkable=walkable_map(grid), workers=workers)
    old, _ = timed(tmp / f"{name}_old.mp4", joints, gl=False, **kw)
    new, path = timed(tmp / f"{name}_gl.mp4", joints, gl=True, scene_mesh=mesh, **kw)
    print(f"{name}: {joints.shape[1]} frames, 800x352, skinned body, workers={workers or 'default'}: "
          f"old (matplotlib boxes + numpy body) {old:.1f} frames/s, OpenGL {new:.1f} frames/s, "
          f"ratio {new / old:.2f}x", flush=True)
    return path


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--workers", type=int, default=0, help="0 = render_video's default")
    ap.add_argument("--mesh", type=Path, default=None, help="a y-up mesh scene in metres")
    ap.add_argument("--start", type=float, nargs=2, default=None, help="x z where the walk starts in --mesh")
    ap.add_argument("--msaa", type=int, default=0, help="OpenGL multisampling (0: none)")
    ap.add_argument("--workers-check", action="store_true")
    args = ap.parse_args()
    if not gl_render.available():
        sys.exit("no OpenGL (EGL) context on this machine: nothing to compare")
    gl_render.MSAA_SAMPLES = args.msaa
    workers = args.workers or None
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        bm = BodyModel(ensure_procedural_model(tmp / "SMPLX_NEUTRAL.npz"))
        room = make_scene(3, np.random.default_rng(3))
        joints, m = walk(bm, args.frames, np.zeros(2))
        gl_video = compare("synthetic room", tmp, bm, m, joints, room.grid(), room.mesh(), workers)
        if args.mesh is not None:
            mesh = load_scene_mesh(args.mesh)
            start = np.asarray(args.start) if args.start else mesh.bounds.mean(0)[[0, 2]]
            joints, m = walk(bm, args.frames, start)
            grid = load_scene_grid(args.mesh, voxel_size=0.05)
            compare(args.mesh.name, tmp, bm, m, joints, grid, mesh, workers)
        if args.workers_check:
            workers_check(tmp, bm, room, gl_video, args.frames)


def workers_check(tmp: Path, bm, room, gl_video: Path, frames: int) -> None:
    """The synthetic room's OpenGL video again, drawn in this process only: the same frames?"""
    import imageio.v3 as iio

    joints, m = walk(bm, frames, np.zeros(2))
    toes = joints[0, :, list(TOE_JOINTS), 1]
    planted = (toes < toes.min(1, keepdims=True) + 0.03).T[None]
    rate, one = timed(tmp / "one.mp4", joints, bodies=[SimpleNamespace(**m)], body_model=bm, planted=planted,
                      contact_joints=list(TOE_JOINTS), grid=room.grid(), walkable=walkable_map(room.grid()),
                      scene_mesh=room.mesh(), workers=1, gl=True)
    same = np.array_equal(iio.imread(one), iio.imread(gl_video))
    print(f"OpenGL in one process: {rate:.1f} frames/s; identical frames to the workers' video: {same}")


if __name__ == "__main__":
    main()
