"""LEMO's motion priors in the fit, on real mocap (one run; prints two tables).

    python benchmarks/motion_prior_fit.py --smooth runs/prior_smooth/prior.pt --infill runs/prior_infill/prior.pt
        [--source cmu|val] [--bvh-dir /usr/share/assimp/models/BVH] [--frames 0] [--clips 3]
        [--noise 0.02] [--seed 0] [--w-smooth W] [--w-infill W] [--steps N] [--mlp auto|none|PATH]
        [--cases noise,occlusion]

1. Clips: `cmu`, the BVH clips of Debian's assimp-testmodels (CMU 01_01, 01_03 and the
   Biovision boxing clip), imported as `motiongen import-bvh` does (22 joints, y-up, 30 fps);
   `val`, the embedded synthetic dataset's validation sequences (what the priors' weights are
   chosen on: the CMU clips are the test). `--frames` cuts each clip (0: whole).
2. Noisy joints: every joint of every frame moved by Gaussian noise (`--noise` metres per
   axis). Fitted with no temporal term, with today's joint-acceleration term (the default fit),
   and with the smoothness prior (stage 2 of `motiongen.capture.prior_fit`).
3. Occluded lower body: the leg joints (hips, knees, ankles, feet) NaN over blocks of 0.5-2 s
   until 30 % of the frames have them missing (no noise, to see the infilling alone). Fitted
   with the gaps filled by linear interpolation (the fit without priors), and with the priors
   (smoothness then infilling, stages 2 and 3).
4. Figures against the clean clip: MPJPE over all joints and over the missing ones, PSKL on the
   joints both directions (`motiongen.metrics.pskl` over 64-frame chunks; nats), foot skating
   (`motiongen.metrics.foot_skating_ratio`; the clean clip's own in the first row) and seconds.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from motiongen.body.fit import RefineConfig
from motiongen.body.model import load_body_model
from motiongen.capture.markers import LOWER_BODY_JOINTS
from motiongen.capture.prior_fit import MotionPriorConfig, PriorTerms, fit_observed
from motiongen.data.format import MotionDataset
from motiongen.importers.bvh import parse_args, run
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.metrics import foot_skating_ratio, pskl

CHUNK = 64


def cmu_clips(bvh_dir: str) -> tuple[list, float]:
    files = sorted(str(p) for p in Path(bvh_dir).glob("*.bvh"))
    if not files:
        raise SystemExit(f"no .bvh files under {bvh_dir} (install assimp-testmodels)")
    with tempfile.TemporaryDirectory() as tmp:
        run(parse_args([f"inputs=[{','.join(files)}]", f"out={tmp}/ds"]))
        ds = MotionDataset.open(f"{tmp}/ds")
        return [(s.name, np.array(ds.joints[s.start:s.end, :22], np.float32)) for s in ds.sequences], ds.fps


def val_clips(n: int) -> tuple[list, float]:
    ds = open_dataset(DataConfig(), verbose=False)
    seqs = ds.split_sequences("val")[:n]
    return [(s.name, np.array(ds.joints[s.start:s.end, :22], np.float32)) for s in seqs], ds.fps


def occlusion_mask(T: int, fps: float, rng: np.random.Generator, share: float = 0.3) -> np.ndarray:
    """(T,) bool: frames whose lower body is missing, blocks of 0.5-2 s until `share` of them."""
    miss = np.zeros(T, bool)
    while miss.mean() < share:
        n = int(rng.uniform(0.5, 2.0) * fps)
        s = int(rng.integers(0, max(T - n, 1)))
        miss[s:s + n] = True
    return miss


def chunks(J: np.ndarray) -> list[np.ndarray]:
    return [J[s:s + CHUNK] for s in range(0, len(J) - CHUNK + 1, CHUNK)]


def figures(J: np.ndarray, clean: np.ndarray, fps: float, missing: np.ndarray | None = None) -> dict:
    d = np.linalg.norm(J - clean, axis=-1)                                            # (T, 22)
    a, b = pskl(chunks(J), chunks(clean), fps, CHUNK)
    return {"mpjpe": d.mean() * 100, "missing": np.nan if missing is None else d[missing].mean() * 100,
            "pskl": (a, b), "skating": foot_skating_ratio(J, fps)}


def row(clip: str, case: str, fit: str, f: dict, sec: float) -> str:
    miss = "–" if np.isnan(f["missing"]) else f"{f['missing']:.2f}"
    return (f"| {clip} | {case} | {fit} | {f['mpjpe']:.2f} | {miss} | {f['pskl'][0]:.4f} | {f['pskl'][1]:.4f} | "
            f"{f['skating']:.3f} | {sec:.1f} |")


def timed(fn):
    t = time.time()
    out = fn()
    return out, time.time() - t


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--smooth", required=True)
    ap.add_argument("--infill", required=True)
    ap.add_argument("--source", default="cmu", choices=("cmu", "val"))
    ap.add_argument("--bvh-dir", default="/usr/share/assimp/models/BVH")
    ap.add_argument("--frames", type=int, default=0)
    ap.add_argument("--clips", type=int, default=3)
    ap.add_argument("--noise", type=float, default=0.02)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--w-smooth", type=float, default=MotionPriorConfig.w_smooth)
    ap.add_argument("--w-infill", type=float, default=MotionPriorConfig.w_infill)
    ap.add_argument("--steps", type=int, default=MotionPriorConfig.steps)
    ap.add_argument("--cases", default="noise,occlusion", help="which inputs: noise, occlusion or both")
    ap.add_argument("--mlp", default="auto", help="the fit's initialiser: auto (as motiongen fit), none or a path")
    args = ap.parse_args()
    torch.set_num_threads(2)
    clips, fps = cmu_clips(args.bvh_dir) if args.source == "cmu" else val_clips(args.clips)
    bm = load_body_model()
    both = MotionPriorConfig(smooth=args.smooth, infill=args.infill, w_smooth=args.w_smooth,
                             w_infill=args.w_infill, steps=args.steps)
    terms = PriorTerms(bm, both)
    smooth_terms = terms.smooth_only()
    mlp = None if args.mlp == "none" else args.mlp
    rng = np.random.default_rng(args.seed)
    cfg = RefineConfig()
    rows = []
    for name, clean in clips[: args.clips]:
        clean = clean[: args.frames or None]
        noisy = clean + rng.normal(0, args.noise, clean.shape).astype(np.float32)
        gone = occlusion_mask(len(clean), fps, rng)
        occluded = clean.copy()
        occluded[np.ix_(gone, list(LOWER_BODY_JOINTS))] = np.nan
        missing = ~np.isfinite(occluded).all(-1)
        rows.append(row(name, "clean", "mocap", figures(clean, clean, fps), 0.0))
        plain = replace(cfg, w_smooth_joints=0.0, w_smooth_rot=0.0)
        noise_fits = (("no temporal term", dict(config=plain)), ("acceleration term", dict(config=cfg)),
                      ("smoothness prior", dict(config=cfg, priors=smooth_terms.cfg, terms=smooth_terms)))
        if "noise" in args.cases:
            rows.append(row(name, f"noise {args.noise * 100:g} cm", "input", figures(noisy, clean, fps), 0.0))
        for label, kw in noise_fits if "noise" in args.cases else ():
            fit, sec = timed(lambda: fit_observed(noisy, bm, mlp, fps=fps, **kw))
            rows.append(row(name, f"noise {args.noise * 100:g} cm", label, figures(fit.joints, clean, fps), sec))
        occlusion_fits = (("linear interpolation", {}), ("smoothness prior", dict(priors=smooth_terms.cfg, terms=smooth_terms)),
                          ("smoothness + infilling priors", dict(priors=both, terms=terms)))
        for label, kw in occlusion_fits if "occlusion" in args.cases else ():
            fit, sec = timed(lambda: fit_observed(occluded, bm, mlp, config=cfg, fps=fps, **kw))
            rows.append(row(name, "lower body 30 % missing", label, figures(fit.joints, clean, fps, missing), sec))
        print(f"{name}: {len(clean)} frames at {fps:g} fps, {missing.any(1).mean() * 100:.0f} % of frames "
              f"with the lower body missing", flush=True)
    print(f"\nw_smooth {args.w_smooth:g}, w_infill {args.w_infill:g}, {args.steps} L-BFGS iterations per prior stage; "
          f"source {args.source}, seed {args.seed}\n")
    print("| clip | input | fit | MPJPE cm | MPJPE missing cm | PSKL-J (fit, clean) | PSKL-J (clean, fit) | "
          "foot skating | s |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
