"""Benchmark joints → SMPL-X fitting (one run; prints figures).

    python benchmarks/fit.py [--frames 1000] [--mesh-steps 3] [--full] [--mlp PATH|auto|none]

1. Held-out motion: parameters from `sample_motion` (seed 12345, not a training seed), joints
   from the body model (procedural unless $MOTIONGEN_SMPLX_MODEL is set).
2. Ours: MLP (default: the cached `default_mlp`) + L-BFGS refinement on joint kinematics only.
3. Reference-style baseline: the same initialisation, then Adam (lr 0.05) on axis-angle pose,
   translation and β, each step running the full LBS mesh (pose blend shapes, 10475 vertices)
   and regressing joints from it, 100 steps. By default only --mesh-steps steps are timed and
   the per-step cost is extrapolated to 100 (--full runs all 100).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from motiongen.body.fit import default_mlp, fit_joints
from motiongen.body.model import load_body_model
from motiongen.body.random_motion import sample_motion
from motiongen.body.rotations import axis_angle_to_matrix, matrix_to_axis_angle


def held_out(bm, frames: int, gait: bool, seed: int):
    """One continuous sequence: joints (T, 22, 3) and its parameters."""
    p = sample_motion(frames, 30.0, np.random.default_rng(seed), gait=gait, num_betas=bm.num_betas)
    with torch.no_grad():
        X = bm.joints(torch.as_tensor(p["global_orient"]), torch.as_tensor(p["body_pose"]),
                      torch.as_tensor(p["transl"]), torch.as_tensor(p["betas"]))
    return X, p


def angular_accel_deg(fit_aa: np.ndarray, fps: float) -> float:
    """Max over frames/joints of the geodesic second difference of rotations, deg/frame²."""
    R = axis_angle_to_matrix(torch.as_tensor(fit_aa))                     # (T, 22, 3, 3)
    d = R[1:] @ R[:-1].transpose(-1, -2)                                   # per-frame rotation steps
    w = matrix_to_axis_angle(d)                                            # (T-1, 22, 3)
    return float(torch.rad2deg((w[1:] - w[:-1]).norm(dim=-1)).max())


def mesh_baseline(bm, X, R_init, betas_init, steps: int, threads: int):
    torch.set_num_threads(threads)
    aa = matrix_to_axis_angle(R_init).clone().requires_grad_(True)         # (T, 22, 3)
    transl = (X[:, 0] - bm.rest_joints(betas_init)[0]).clone().requires_grad_(True)
    betas = betas_init.clone().requires_grad_(True)
    opt = torch.optim.Adam([aa, transl, betas], lr=0.05)
    times = []
    for _ in range(steps):
        t = time.time()
        V = bm.vertices(aa[:, 0], aa[:, 1:], transl, betas)                 # (T, V, 3)
        J = bm.regress_joints(V)
        loss = (J - X).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        times.append(time.time() - t)
    with torch.no_grad():
        J = bm.regress_joints(bm.vertices(aa[:, 0], aa[:, 1:], transl, betas))
    return times, (J - X).norm(dim=-1).mean().item()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--mesh-steps", type=int, default=3)
    ap.add_argument("--full", action="store_true", help="run all 100 baseline steps")
    ap.add_argument("--mlp", default="auto")
    ap.add_argument("--threads", type=int, default=2, help="torch threads for the mesh baseline")
    args = ap.parse_args()

    bm = load_body_model()
    print(f"body model: {bm.path} (procedural={bm.is_procedural}, {bm.num_vertices} vertices)")
    t = time.time()
    mlp = default_mlp(bm) if args.mlp == "auto" else (None if args.mlp == "none" else args.mlp)
    print(f"MLP ready in {time.time() - t:.1f} s ({'cached or trained' if args.mlp == 'auto' else args.mlp})")
    X, _ = held_out(bm, 10, True, 0)
    fit_joints(X, bm, mlp)                                                 # warm-up (allocations, lazy imports)
    runs = {}
    for name, gait, seed in (("gait", True, 12345), ("free", False, 12346)):
        X, params = held_out(bm, args.frames, gait, seed)
        fit = fit_joints(X, bm, mlp)
        runs[name] = (X, fit)
        acc = angular_accel_deg(np.concatenate([fit.global_orient[:, None], fit.body_pose.reshape(-1, 21, 3)], 1), 30.0)
        acc_gt = angular_accel_deg(np.concatenate([params["global_orient"][:, None],
                                                   params["body_pose"].reshape(-1, 21, 3)], 1), 30.0)
        mlp_txt = f"MLP alone {fit.mpjpe_mlp * 100:.2f} cm, " if fit.mpjpe_mlp is not None else ""
        print(f"ours [{name}]: {args.frames} frames, MPJPE: {mlp_txt}init ({fit.init} + swing correction) "
              f"{fit.mpjpe_init * 100:.2f} cm -> refined {fit.mpjpe * 100:.3f} cm (worst frame "
              f"{fit.per_frame_error.max() * 100:.3f} cm) in {fit.seconds:.2f} s, {fit.steps} L-BFGS iterations / "
              f"{len(fit.history)} evaluations; max angular acceleration {acc:.2f} deg/frame² (truth {acc_gt:.2f})")
    X, fit = runs["gait"]

    # Baseline from the same initialisation.
    init = fit_joints(X, bm, mlp, refine_steps=0)
    R_init = axis_angle_to_matrix(torch.as_tensor(np.concatenate([init.global_orient[:, None],
                                                                  init.body_pose.reshape(-1, 21, 3)], 1)))
    n = 100 if args.full else args.mesh_steps
    times, err = mesh_baseline(bm, X, R_init, torch.as_tensor(init.betas), n, args.threads)
    per_step = float(np.median(times))
    total = per_step * 100 if not args.full else float(np.sum(times))
    what = "measured" if args.full else f"extrapolated from {n} steps (median {per_step:.2f} s/step)"
    print(f"mesh baseline: 100 Adam steps through the LBS mesh: {total:.1f} s ({what})"
          + (f", MPJPE {err * 100:.3f} cm" if args.full else ""))
    print(f"speed-up: {total / fit.seconds:.0f}x")


if __name__ == "__main__":
    main()
