"""Training throughput of the denoiser (forward + backward + Adam) vs the CPU's matmul peak.

    python benchmarks/train_step.py [--preset paper] [--batch 64] [--iters 5] [--no-dropout] [--compile]

Prints samples/s, achieved FLOP/s (FLOPs counted by torch.utils.flop_counter over one
forward + backward: matmuls and attention only, so elementwise work, LayerNorm and Adam
count as overhead), and the ratio to the fp32 peak of a large torch.mm measured in the same
run with the same threads. `--compile` also times the same step through torch.compile
(inductor), interleaved with the eager steps, and prints the compiled / eager ratio and the
one-off compile time. Figures are printed, nothing is asserted.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch
from torch.utils.flop_counter import FlopCounterMode

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout without installing

from motiongen.diffusion import DiffusionConfig, GaussianDiffusion, sample_known_mask
from motiongen.models import Condition, build_model, count_parameters, drop_conditions, model_config


def matmul_peak(a: torch.Tensor, b: torch.Tensor, reps: int = 3) -> float:
    """Best FLOP/s of ``reps`` square fp32 matmuls (a @ b, n x n)."""
    n, best = a.shape[0], 0.0
    for _ in range(reps):
        t0 = time.perf_counter()
        a @ b
        best = max(best, 2 * n**3 / (time.perf_counter() - t0))
    return best


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", default="paper")
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--window", type=int, default=16)
    ap.add_argument("--joints", type=int, default=22)
    ap.add_argument("--actions", type=int, default=6)
    ap.add_argument("--iters", type=int, default=5)
    ap.add_argument("--threads", type=int, default=0, help="0 = torch default")
    ap.add_argument("--unfused-adam", action="store_true")
    ap.add_argument("--no-dropout", action="store_true", help="dropout 0 everywhere (isolates its cost)")
    ap.add_argument("--compile", action="store_true", help="also time torch.compile(model), interleaved")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)

    overrides = {}
    if args.no_dropout:
        overrides = dict(dropout=0.0, scene_dropout=0.0, action_dropout=0.0)
    cfg = model_config(args.preset, **overrides)
    B, L, J, A = args.batch, args.window, args.joints, args.actions
    model = build_model(cfg, J, A, L).train()
    diffusion = GaussianDiffusion(DiffusionConfig())
    # fused=True: one kernel per step instead of ~6 elementwise passes per parameter tensor.
    opt = torch.optim.Adam(model.parameters(), lr=1e-4, fused=not args.unfused_adam)
    g = torch.Generator().manual_seed(0)

    x0 = torch.rand(B, L, J * 3) * 2 - 1
    cond = Condition(scene=(torch.rand(B, 32, 32, 32) < 0.2).float(),
                     actions=(torch.rand(B, L, A) < 0.3).float())
    mask = sample_known_mask(B, L, J, generator=g)

    def step(net=model) -> None:
        c = drop_conditions(cond, 0.1, 0.1, g)
        t = diffusion.sample_timesteps(B, g)
        loss = diffusion.training_losses(net, x0, t, c, known_mask=mask, generator=g)["loss"]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    # FLOPs of forward + backward, with no condition dropped (all three networks run).
    counter = FlopCounterMode(display=False)
    with counter:
        t = diffusion.sample_timesteps(B, g)
        diffusion.training_losses(model, x0, t, cond, known_mask=mask, generator=g)["loss"].backward()
    flops = counter.get_total_flops()
    opt.zero_grad(set_to_none=True)

    # The CPU may be shared (VMs, other jobs): measure the peak right before every timed step
    # and compare each step with its own neighbour, so both see the same contention.
    a, b = torch.randn(2048, 2048), torch.randn(2048, 2048)
    matmul_peak(a, b)
    step()
    step()  # warm-up (allocator, Adam state)
    times, peaks = [], []
    for _ in range(args.iters):
        peaks.append(matmul_peak(a, b))
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    ratios = sorted(flops / t / p for t, p in zip(times, peaks))
    best, med = min(times), sorted(times)[len(times) // 2]
    peak = max(peaks)
    achieved = flops / best
    print(f"preset {args.preset}: {count_parameters(model) / 1e6:.2f} M parameters, batch {B}, "
          f"window {L}, J {J}, A {A}, threads {torch.get_num_threads()}, dropout {'off' if args.no_dropout else 'on'}")
    print(f"FLOPs per step (fwd+bwd, matmul + attention): {flops / 1e9:.1f} GFLOP")
    print(f"step time: best {best * 1e3:.0f} ms, median {med * 1e3:.0f} ms "
          f"-> {B / best:.1f} samples/s (best), {B / med:.1f} samples/s (median)")
    print(f"fp32 matmul peak (2048^2 torch.mm): best {peak / 1e9:.1f} GFLOP/s, median {sorted(peaks)[len(peaks) // 2] / 1e9:.1f}")
    print(f"achieved (best step): {achieved / 1e9:.1f} GFLOP/s = {100 * achieved / peak:.0f}% of the best peak")
    print(f"per-step ratio to the peak measured just before it: median {100 * ratios[len(ratios) // 2]:.0f}%, "
          f"range {100 * ratios[0]:.0f}-{100 * ratios[-1]:.0f}%")
    if args.compile:
        compiled = torch.compile(model)
        t0 = time.perf_counter()
        for _ in range(3):          # conditions dropped or not compile separate graphs
            step(compiled)
        compile_s = time.perf_counter() - t0
        eager, comp = [], []
        for _ in range(args.iters):  # interleaved, so both see the same contention
            t0 = time.perf_counter()
            step()
            eager.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            step(compiled)
            comp.append(time.perf_counter() - t0)
        e, c = sorted(eager)[len(eager) // 2], sorted(comp)[len(comp) // 2]
        print(f"torch.compile (inductor): compile + 3 warm-up steps {compile_s:.0f} s; median step eager "
              f"{e * 1e3:.0f} ms, compiled {c * 1e3:.0f} ms -> {B / c:.1f} vs {B / e:.1f} samples/s, "
              f"compiled/eager speed {e / c:.2f}x")


if __name__ == "__main__":
    main()
