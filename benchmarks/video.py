"""Sample-video rendering speed: frames drawn in this process vs by forked workers (one run).

    python benchmarks/video.py [--frames 300] [--workers 0]

A walking body of the procedural model (`sample_motion` with gait, seed 7), rendered as
`sample.py` renders it (skinned body, planted feet marked, 800 x 352 at 30 fps) once with
workers=1 and once with --workers (0: the default, one per core up to 4). Prints frames/s of
each and the ratio; the two videos' frames are compared (they must be identical).
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
from motiongen.body.random_motion import sample_motion  # noqa: E402
from motiongen.body.procedural import ensure_procedural_model  # noqa: E402
from motiongen.metrics import TOE_JOINTS  # noqa: E402
from motiongen.export.video import render_video  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--workers", type=int, default=0, help="0 = render_video's default")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        bm = BodyModel(ensure_procedural_model(Path(tmp) / "SMPLX_NEUTRAL.npz"))
        m = sample_motion(args.frames, 30.0, np.random.default_rng(7), gait=True)
        with torch.no_grad():
            joints = bm.joints(*(torch.as_tensor(m[k]) for k in ("global_orient", "body_pose", "transl", "betas")))
        joints = joints.numpy()[None]                                                 # (1, T, 22, 3)
        toes = joints[0, :, list(TOE_JOINTS), 1]                                      # (2, T) toe heights
        planted = (toes < toes.min(1, keepdims=True) + 0.03).T[None]                  # (1, T, 2)
        kw = dict(bodies=[SimpleNamespace(**m)], body_model=bm, planted=planted, contact_joints=list(TOE_JOINTS))
        rates, paths = [], []
        for w in (1, args.workers or None):
            path = Path(tmp) / f"w{w}.mp4"
            t0 = time.perf_counter()
            paths.append(render_video(path, joints, 30.0, workers=w, **kw))
            rates.append(args.frames / (time.perf_counter() - t0))
        import imageio.v3 as iio

        same = np.array_equal(iio.imread(paths[0]), iio.imread(paths[1]))
    print(f"{args.frames} frames, 800x352, skinned body: workers=1 {rates[0]:.1f} frames/s, "
          f"workers={args.workers or 'default'} {rates[1]:.1f} frames/s, ratio {rates[1] / rates[0]:.2f}x; "
          f"identical frames: {same}")


if __name__ == "__main__":
    main()
