"""Benchmark multi-view SMPL-X fitting (the multi-view capture paper, A1) on the test rig (one
run; prints figures).

    python benchmarks/fit_multiview.py [--frames 1000] [--cameras 4] [--threads 1]
        [--outliers 0.1] [--noise-px 1.5] [--drop 0.05] [--compare-frames 0]

Speed: the procedural body in known motion (tests/capture_rig.py), `--cameras` virtual
cameras, detections with pixel noise, dropped detections and outliers; the whole pipeline
(triangulation, initialisation, the three stages in 500-frame chunks) with the default
settings, torch limited to `--threads` threads. Prints frames/s overall and per stage, and the
joint error against the truth (MPJPE, metres → cm).

Accuracy (`--compare-frames N`, on an N-frame rig): the default against the alternatives the
docs discuss — the robust 2D term against plain L2, the paper's mean-pose start against the IK
start, unsmoothed IK start, and other length units than the default 2 cm.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))                  # run from a checkout without installing
sys.path.insert(0, str(ROOT / "tests"))        # the rig builder

from capture_rig import make_rig  # noqa: E402

from motiongen.body.model import load_body_model  # noqa: E402
from motiongen.capture.multiview import MultiviewConfig, fit_multiview  # noqa: E402
from motiongen.capture.pose_prior import default_prior  # noqa: E402
from motiongen.capture.triangulate import triangulate  # noqa: E402


def run(bm, rig, cfg: MultiviewConfig) -> dict:
    t0 = time.time()
    res = fit_multiview(bm, rig.cams, rig.uv, rig.conf, default_prior(), cfg)
    seconds = time.time() - t0
    err = np.linalg.norm(res.joints - rig.joints, axis=-1)                      # (T, 22)
    acc = np.linalg.norm(res.joints[2:] - 2 * res.joints[1:-1] + res.joints[:-2], axis=-1).mean()
    return {"seconds": seconds, "mpjpe_cm": err.mean() * 100, "worst_frame_cm": err.mean(1).max() * 100,
            "accel_cm": acc * 100, "err2d_px": float(np.nanmedian(res.err2d)), "stage_seconds": res.seconds,
            "evaluations": res.evaluations}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--cameras", type=int, default=4)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--outliers", type=float, default=0.1)
    ap.add_argument("--noise-px", type=float, default=1.5)
    ap.add_argument("--drop", type=float, default=0.05)
    ap.add_argument("--compare-frames", type=int, default=0)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    bm = load_body_model()
    default_prior()                                                               # built once, not timed
    cfg = MultiviewConfig(threads=a.threads)
    rig = make_rig(bm, T=a.frames, cameras=a.cameras, noise_px=a.noise_px, drop=a.drop, outliers=a.outliers, seed=7)
    print(f"rig: {a.frames} frames x {a.cameras} cameras, noise {a.noise_px} px, {a.drop:.0%} dropped, "
          f"{rig.outlier.mean():.1%} outliers; torch threads {a.threads}", flush=True)
    r = run(bm, rig, cfg)
    per_stage = ", ".join(f"{k} {v:.2f} s" for k, v in r["stage_seconds"].items())
    print(f"speed: {a.frames / r['seconds']:.1f} frames/s ({r['seconds']:.1f} s: {per_stage}; loss evaluations "
          f"{r['evaluations']})")
    print(f"accuracy: MPJPE {r['mpjpe_cm']:.2f} cm (worst frame {r['worst_frame_cm']:.2f} cm), mean joint "
          f"acceleration {r['accel_cm']:.3f} cm/frame^2 (truth "
          f"{np.linalg.norm(rig.joints[2:] - 2 * rig.joints[1:-1] + rig.joints[:-2], axis=-1).mean() * 100:.3f}), "
          f"2D median {r['err2d_px']:.2f} px", flush=True)
    if a.compare_frames:
        small = make_rig(bm, T=a.compare_frames, cameras=a.cameras, noise_px=a.noise_px, drop=a.drop,
                         outliers=a.outliers, seed=8)
        for name, reject in (("consensus + temporal check", (cfg.reject_px, cfg.max_jump)),
                             ("plain weighted DLT", (None, None))):
            tri = triangulate(small.cams, small.uv, small.conf, 2, *reject)
            ok = tri.conf > 0
            e = np.linalg.norm(tri.points - small.joints, axis=-1)[ok]
            print(f"triangulation, {name}: {ok.mean():.1%} of points kept, error mean {e.mean() * 100:.2f} cm, "
                  f"max {e.max() * 100:.1f} cm")
        variants = {"default (unit 2 cm, rho 1 cm, GM, IK start smoothed 2 frames)": cfg,
                    "plain L2 2D term": replace(cfg, robust="l2"),
                    "the paper's start (mean pose, z = 0)": replace(cfg, init_pose="mean"),
                    "IK start unsmoothed": replace(cfg, init_smooth=0.0),
                    "after stage 2 (steps3 = 0)": replace(cfg, steps=cfg.steps[:2] + (0,)),
                    **{f"length unit {u * 100:g} cm": replace(cfg, length_unit=u) for u in (1.0, 0.05, 0.01, 0.001)}}
        print(f"\n{a.compare_frames}-frame rig | MPJPE cm | worst frame cm | accel cm/frame^2 | 2D median px | s")
        for name, c in variants.items():
            r = run(bm, small, c)
            print(f"{name} | {r['mpjpe_cm']:.2f} | {r['worst_frame_cm']:.2f} | {r['accel_cm']:.3f} | "
                  f"{r['err2d_px']:.2f} | {r['seconds']:.1f}", flush=True)


if __name__ == "__main__":
    main()
