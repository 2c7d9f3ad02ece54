"""Fit SMPL-X to multi-view 2D keypoints (and optional 3D keypoints): the multi-view capture paper, A1.

    motiongen fit-multiview cameras=cams.json keypoints2d=kp2d.npz out=DIR
        [keypoints3d=kp3d.npz] [layout=smplx22|coco17|body25] [fps=30] [prior=builtin|PATH]
        [body.model_path=...] [length_unit=0.02] [rho=0.01] [robust=gm|l2] [stage1_frames=100]
        [chunk=500] [steps1=60] [steps2=40] [steps3=60] [init_pose=analytic|mean] [init_smooth=2]
        [reject_px=30] [max_jump=0.1] [min_views=2] [tensorboard=true] [threads=1] [device=cpu]
        [motion_prior.smooth=PATH] [motion_prior.infill=PATH] [motion_prior.w_smooth=...] [motion_prior.w_infill=1]

Inputs: `motiongen.capture.cameras` (camera file), `motiongen.capture.keypoints` (keypoint
files). Writes into DIR: `params.npz` (AMASS-style SMPL-X, `motiongen.body.fit.save_amass_npz`),
`errors.npz` (per-frame 3D and 2D errors), `report.json` (per-stage losses, timings,
error summaries) and, with tensorboard=true, per-stage losses under `tb/`. Files are written
under temporary names and renamed together at the end. User mistakes print one `error: ...`
line and exit 2.

`motion_prior.smooth` / `motion_prior.infill` add LEMO's learned motion priors
(`motiongen train-motion-prior`, `motiongen.capture.prior_fit`): the smoothness prior's latent
term in stages 2 and 3, and in stage 3 the infilling prior's markers for the joints that have no
3D keypoint at a frame (confidence 0, or not triangulated).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from motiongen.body.fit import FitResult, save_amass_npz
from motiongen.body.model import load_body_model
from motiongen.capture.cameras import load_cameras
from motiongen.capture.keypoints import load_keypoints2d, load_keypoints3d
from motiongen.capture.multiview import MultiviewConfig, fit_multiview
from motiongen.capture.pose_prior import load_prior
from motiongen.capture.prior_fit import MotionPriorConfig, PriorTerms
from motiongen.checks import require_fps
from motiongen.cli import parse_key_values, tool_main
from motiongen.errors import ConfigError
from motiongen.skeleton import BODY_JOINT_NAMES
from motiongen.staging import StagedOutputs

_D = MultiviewConfig()        # the defaults live there, once
_MP = MotionPriorConfig()
SPEC = {"cameras": (str, None), "keypoints2d": (str, None), "keypoints3d": (str, None), "out": (str, None),
        "layout": (str, None), "fps": (float, None), "prior": (str, "builtin"), "body.model_path": (str, None),
        "length_unit": (float, _D.length_unit), "rho": (float, _D.rho), "robust": (str, _D.robust),
        "stage1_frames": (int, _D.stage1_frames), "chunk": (int, _D.chunk), "steps1": (int, _D.steps[0]),
        "steps2": (int, _D.steps[1]), "steps3": (int, _D.steps[2]), "init_pose": (str, _D.init_pose),
        "init_smooth": (float, _D.init_smooth),
        "reject_px": (float, _D.reject_px), "max_jump": (float, _D.max_jump), "min_views": (int, _D.min_views),
        "tensorboard": (bool, True), "threads": (int, _D.threads), "device": (str, "cpu"),
        "motion_prior.smooth": (str, None), "motion_prior.infill": (str, None),
        "motion_prior.w_smooth": (float, _MP.w_smooth), "motion_prior.w_infill": (float, _MP.w_infill)}
USAGE = "motiongen fit-multiview cameras=cams.json keypoints2d=kp2d.npz out=DIR [keypoints3d=...]"


def config_from(opts: dict) -> MultiviewConfig:
    # fps= checked as a key, before the keypoints file (whose own fps it replaces) is read
    require_fps("fps", opts["fps"], allow_none=True)
    if opts["length_unit"] <= 0 or opts["rho"] <= 0:
        raise ConfigError("length_unit and rho must be positive")
    if opts["min_views"] < 2:
        raise ConfigError(f"min_views={opts['min_views']}: a point needs at least 2 views")
    cfg = MultiviewConfig(length_unit=opts["length_unit"], rho=opts["rho"], robust=opts["robust"],
                          stage1_frames=opts["stage1_frames"], chunk=opts["chunk"],
                          steps=(opts["steps1"], opts["steps2"], opts["steps3"]), init_pose=opts["init_pose"],
                          init_smooth=opts["init_smooth"], reject_px=opts["reject_px"] or None,
                          max_jump=opts["max_jump"] or None,
                          min_views=opts["min_views"], threads=opts["threads"])
    cfg.check()
    return cfg


def nanmean(a: np.ndarray, axis) -> np.ndarray:
    """Mean of the finite entries along axis; NaN where there are none (no warning)."""
    ok = np.isfinite(a)
    n = ok.sum(axis)
    return np.where(n > 0, np.where(ok, a, 0).sum(axis) / np.maximum(n, 1), np.nan)


def _summary(a: np.ndarray, scale: float) -> dict:
    v = a[np.isfinite(a)] * scale
    if v.size == 0:
        return {"mean": None, "median": None, "p95": None, "max": None}
    return {"mean": round(float(v.mean()), 4), "median": round(float(np.median(v)), 4),
            "p95": round(float(np.percentile(v, 95)), 4), "max": round(float(v.max()), 4)}


def run(argv: list[str]) -> dict:
    opts = parse_key_values(argv, SPEC, required=("cameras", "keypoints2d", "out"), usage=USAGE, doc=__doc__)
    cfg = config_from(opts)
    cams = load_cameras(opts["cameras"])
    obs = load_keypoints2d(opts["keypoints2d"], cams.names, opts["layout"], opts["fps"])
    x3d = conf3d = None
    if opts["keypoints3d"]:
        x3d, conf3d = load_keypoints3d(opts["keypoints3d"], obs.num_frames, cams.file_points_to_world, opts["layout"])
    prior = load_prior(opts["prior"])
    bm = load_body_model(opts["body.model_path"], device=opts["device"])
    mp = MotionPriorConfig(smooth=opts["motion_prior.smooth"], infill=opts["motion_prior.infill"],
                           w_smooth=opts["motion_prior.w_smooth"], w_infill=opts["motion_prior.w_infill"])
    motion = PriorTerms(bm, mp) if mp.any else None
    out = Path(opts["out"])
    out.mkdir(parents=True, exist_ok=True)
    res, seconds = _fit(bm, cams, obs, prior, cfg, x3d, conf3d, out / "tb" if opts["tensorboard"] else None, motion)
    frame_err = nanmean(res.err3d, 1)                                                # (T,)
    fit = FitResult(global_orient=res.global_orient, body_pose=res.body_pose, transl=res.transl, betas=res.betas,
                    joints=res.joints, per_frame_error=frame_err, mpjpe_mlp=None, mpjpe_init=res.err3d_init,
                    mpjpe=float(nanmean(res.err3d.reshape(-1), 0)), steps=sum(res.evaluations.values()),
                    seconds=seconds,
                    init=f"multiview/{cfg.init_pose}")
    staged = StagedOutputs(out)
    try:
        save_amass_npz(staged.tmp("params.npz"), fit, obs.fps)
        with open(staged.tmp("errors.npz"), "wb") as f:
            np.savez(f, err3d=res.err3d.astype(np.float32), err2d=res.err2d.astype(np.float32),
                     frame_err3d=frame_err.astype(np.float32),
                     frame_err2d=nanmean(res.err2d, 2).astype(np.float32),
                     x3d=res.x3d.astype(np.float32), conf3d=res.conf3d.astype(np.float32),
                     camera_names=np.array(cams.names), joint_names=np.array(BODY_JOINT_NAMES))
        report = _report(opts, cams, obs, x3d is not None, prior, bm, res, seconds)
        staged.tmp("report.json").write_text(json.dumps(report, indent=2))
        staged.commit()
    except BaseException:
        staged.abort()
        raise
    e3, e2 = report["err3d_cm"], _summary(res.err2d, 1.0)
    print(f"{obs.num_frames} frames x {len(cams)} cameras ({obs.layout}, 3D {report['keypoints3d']}): 3D error to "
          f"targets {e3['mean']} cm mean (after the start {report['err3d_init_cm']} cm), 2D median {e2['median']} px; "
          f"{seconds:.1f} s ({report['frames_per_second']} frames/s) -> {out}", flush=True)
    return report


def _fit(bm, cams, obs, prior, cfg: MultiviewConfig, x3d, conf3d, tb_dir: Path | None, motion=None):
    """`fit_multiview` on the loaded inputs, its per-stage losses to tensorboard in `tb_dir`
    (None: none). Returns the result and the seconds the fit took."""
    writer = None
    if tb_dir is not None:
        from torch.utils.tensorboard import SummaryWriter  # heavy to import; only with tensorboard=true

        writer = SummaryWriter(str(tb_dir))
    t0 = time.time()
    try:
        observed = obs.observed | ((conf3d > 0).any(0) if conf3d is not None else False)
        res = fit_multiview(bm, cams, obs.uv, obs.conf, prior, cfg, x3d, conf3d, observed=observed, writer=writer,
                            motion=motion)
    finally:
        if writer is not None:
            writer.close()
    return res, time.time() - t0


def _report(opts: dict, cams, obs, given3d: bool, prior, bm, res, seconds: float) -> dict:
    """report.json: inputs, settings, per-stage losses, timings and error summaries."""
    T = obs.num_frames
    return {
        "frames": T, "fps": obs.fps, "cameras": cams.names, "layout": obs.layout,
        "keypoints3d": "given" if given3d else "triangulated",
        "triangulated_fraction": round(float((res.conf3d[:, obs.observed] > 0).mean()), 4),
        "prior": prior.source, "body_model": str(bm.path), "procedural_body": bm.is_procedural,
        "config": {k: opts[k] for k in SPEC if k not in ("cameras", "keypoints2d", "keypoints3d", "out")},
        "err3d_init_cm": round(res.err3d_init * 100, 4), "err3d_cm": _summary(res.err3d, 100.0),
        "err2d_px": {n: _summary(res.err2d[c], 1.0) for c, n in enumerate(cams.names)},
        "stage_losses": {f"stage{s}": v for s, v in res.stage_losses.items()},
        "evaluations": {f"stage{s}": n for s, n in res.evaluations.items()},
        "seconds": {k: round(v, 3) for k, v in res.seconds.items()} | {"total": round(seconds, 3)},
        "frames_per_second": round(T / seconds, 2)}


main = tool_main(run)


if __name__ == "__main__":
    main()
