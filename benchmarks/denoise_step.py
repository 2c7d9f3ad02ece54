"""Latency of one denoising step (one model call + scheduler step), condition encoded once.

    python benchmarks/denoise_step.py [--presets paper tiny] [--batches 1 32] [--threads 0]

Also prints the one-off cost of encoding the condition (scene ViT + action transformer),
which the sampler pays once per call instead of once per step.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from motiongen.diffusion import DDIMScheduler, GaussianDiffusion  # noqa: E402
from motiongen.models import Condition, build_model, count_parameters, model_config  # noqa: E402


def timed(fn, reps: int) -> tuple[float, float]:
    fn()
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    ts.sort()
    return ts[0], ts[len(ts) // 2]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--presets", nargs="+", default=["paper", "tiny"])
    ap.add_argument("--batches", nargs="+", type=int, default=[1, 32])
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--threads", type=int, default=0, help="0 = torch default")
    ap.add_argument("--guidance", type=float, default=1.0, help="!= 1 runs the batched 2B CFG pass")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    L, J, A = 16, 22, 6
    diffusion = GaussianDiffusion()
    sched = DDIMScheduler(diffusion)
    sched.set_timesteps(25)
    t_step = int(sched.timesteps[5])
    print(f"threads {torch.get_num_threads()}, window {L}, J {J}, A {A}, guidance {args.guidance}")
    for name in args.presets:
        torch.manual_seed(0)
        model = build_model(model_config(name), J, A, L).eval()
        for B in args.batches:
            cond = Condition(scene=(torch.rand(B, 32, 32, 32) < 0.2).float(),
                             actions=(torch.rand(B, L, A) < 0.3).float())
            x = torch.randn(B, L, J * 3)
            with torch.inference_mode():
                enc_best, _ = timed(lambda: model.encode_condition(cond), max(3, args.reps // 3))
                enc = model.encode_condition(cond)
                if args.guidance != 1.0:
                    enc = enc.concat(model.encode_condition(cond.drop_all()))
                n = 2 * B if args.guidance != 1.0 else B
                t = torch.full((n,), t_step, dtype=torch.long)

                def step():
                    xin = torch.cat([x, x]) if n != B else x
                    out = model(xin, t, enc)
                    if n != B:
                        c, u = out.chunk(2)
                        out = u + args.guidance * (c - u)
                    return sched.step(out, t_step, x)

                best, med = timed(step, args.reps)
            print(f"{name:9s} ({count_parameters(model) / 1e6:6.2f} M) batch {B:3d}: step best {best * 1e3:8.2f} ms, "
                  f"median {med * 1e3:8.2f} ms; condition encode (once) {enc_best * 1e3:8.2f} ms")


if __name__ == "__main__":
    main()
