"""What LEMO's foot-contact velocity term does to fitted real mocap (one run; prints a table).

    python benchmarks/foot_contact_fit.py [--bvh-dir /usr/share/assimp/models/BVH] [--weights 0.01,0.1,1]
        [--steps 30] [--foot-vel-steps 100] [--mlp none|auto|PATH]

1. The CMU / Biovision BVH clips of Debian's assimp-testmodels are imported as the BVH importer
   does (`motiongen.importers.bvh`: 22 joints, y-up, 30 fps, floor at y = 0, foot contact
   labels from height and speed).
2. Each clip is fitted joints -> SMPL-X (`fit_joints`, the body model of `load_body_model()`):
   without the term (one pass, as the CLI does; and two passes, as many iterations as the runs
   with the term: `max_steps`, then `foot_vel_steps` from the first pass's result), and
   with it (`w_foot_vel` = each weight) over the feet within 10 cm of the floor ("height", the
   LEMO's heuristic) or over the importer's contact labels ("contact": where sensor or
   annotated labels would go).
3. Per fit: MPJPE to the mocap joints, the foot skating ratio and grounded slide of the toes
   (`motiongen.metrics`, as evaluate.py reports them), and the median speed of the foot
   joints over the labelled contact frames (what the term holds still).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from motiongen.body.fit import RefineConfig, fit_joints, refine
from motiongen.body.model import load_body_model
from motiongen.body.rotations import axis_angle_to_matrix
from motiongen.data.format import MotionDataset
from motiongen.importers.bvh import parse_args, run
from motiongen.metrics import foot_skating_ratio, grounded_slide
from motiongen.skeleton import FOOT_JOINTS


def contact_speed(joints: np.ndarray, contact: np.ndarray, fps: float) -> float:
    """Median 3-D speed (m/s, forward differences) of the foot joints over frames flagged in
    contact (T, 4) (as the term measures it)."""
    v = np.linalg.norm(np.diff(joints[:, list(FOOT_JOINTS)], axis=0), axis=-1) * fps        # (T-1, 4)
    on = contact[:-1]
    return float(np.median(v[on])) if on.any() else float("nan")


def figures(J: np.ndarray, X: np.ndarray, contact: np.ndarray, fps: float) -> dict:
    return {"mpjpe_cm": float(np.linalg.norm(J - X, axis=-1).mean() * 100), "skating": foot_skating_ratio(J, fps),
            "slide": grounded_slide(J, fps), "contact_speed": contact_speed(J, contact, fps)}


def second_pass_without_term(bm, X, fit, cfg: RefineConfig, fps: float) -> np.ndarray:
    """The baseline with the same iterations as a fit with the term: a second pass of the plain
    refinement from the first pass's result (what `fit_joints` does when w_foot_vel > 0)."""
    R = axis_angle_to_matrix(torch.cat([torch.as_tensor(fit.global_orient)[:, None],
                                        torch.as_tensor(fit.body_pose).reshape(-1, 21, 3)], 1)).to(X.dtype)
    R2, tr, b, _, _ = refine(bm, X, R, torch.as_tensor(fit.betas, dtype=X.dtype),
                             replace(cfg, w_foot_vel=0.0, max_steps=cfg.foot_vel_steps),
                             transl_init=torch.as_tensor(fit.transl, dtype=X.dtype), fps=fps)
    with torch.no_grad():
        return bm.joints_from_rotmats(R2, tr, b).numpy()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bvh-dir", default="/usr/share/assimp/models/BVH")
    ap.add_argument("--weights", default="0.01,0.1,1")
    ap.add_argument("--foot-vel-steps", type=int, default=RefineConfig.foot_vel_steps)
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--mlp", default="none")
    args = ap.parse_args()
    torch.set_num_threads(1)
    files = sorted(str(p) for p in Path(args.bvh_dir).glob("*.bvh"))
    if not files:
        raise SystemExit(f"no .bvh files under {args.bvh_dir} (install assimp-testmodels)")
    bm = load_body_model()
    mlp = None if args.mlp == "none" else args.mlp
    weights = [float(w) for w in args.weights.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        run(parse_args([f"inputs=[{','.join(files)}]", f"out={tmp}/ds"]))
        ds = MotionDataset.open(f"{tmp}/ds")
        clips = [(s.name, np.array(ds.joints[s.start:s.end], np.float32),
                  np.array(ds.contact[s.start:s.end])[:, list(FOOT_JOINTS)]) for s in ds.sequences]
        fps = ds.fps
    rows = []
    for name, X, contact in clips:
        Xt = torch.as_tensor(X)
        base_cfg = RefineConfig(max_steps=args.steps, foot_vel_steps=args.foot_vel_steps)
        t = time.time()
        fit = fit_joints(X, bm, mlp, config=base_cfg, fps=fps)
        one = time.time() - t
        rows.append((name, "mocap (target)", "-", figures(X, X, contact, fps), 0.0))
        rows.append((name, "fit, 1 pass (CLI default)", "-", figures(fit.joints, X, contact, fps), one))
        t = time.time()
        J2 = second_pass_without_term(bm, Xt, fit, base_cfg, fps)
        rows.append((name, "fit, 2 passes, no term", "0", figures(J2, X, contact, fps), one + time.time() - t))
        for mask in ("height", "contact"):
            for w in weights:
                cfg = replace(base_cfg, w_foot_vel=w, foot_vel_mask=mask)
                t = time.time()
                f = fit_joints(X, bm, mlp, config=cfg, contact=contact, fps=fps)
                rows.append((name, f"fit + term, mask {mask}", f"{w:g}", figures(f.joints, X, contact, fps),
                             time.time() - t))
        print(f"{name}: {len(X)} frames at {fps:g} fps, contact labels on {100 * contact.mean():.0f} % of "
              f"foot-joint frames", flush=True)
    print("\n| clip | fit | w_foot_vel | MPJPE cm | foot skating | grounded slide m/s | "
          "foot speed in contact m/s | s |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for name, what, w, m, sec in rows:
        print(f"| {name} | {what} | {w} | {m['mpjpe_cm']:.2f} | {m['skating']:.3f} | {m['slide']:.3f} | "
              f"{m['contact_speed']:.3f} | {sec:.1f} |")


if __name__ == "__main__":
    main()
