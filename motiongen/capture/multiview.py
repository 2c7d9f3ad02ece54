"""Multi-view SMPL-X fitting in three stages (the multi-view capture paper, A1), batched over
frames on the fast joint kinematics (`BodyModel.joints`, no mesh per iteration).

0. 3D targets: given, or triangulated from the 2D detections (`triangulate.py`).
   Root init: per frame, the rest template's shoulders and hips rigidly aligned to the
   targets' (weighted Kabsch, `scipy.spatial.transform.Rotation.align_vectors`); frames where
   they are not seen take the root of the nearest frames (Slerp / linear).
1. The first `stage1_frames` (100) frames, where the subject holds a simple pose: β, z, root.
2. All frames, β frozen, in chunks of `chunk` (500) frames: z and root.
3. As 2 with the Geman–McClure 2D term added.
Weights: `objective.SEED_STAGES`. Chunks are optimised one after another; each sees the last
two fitted frames of the chunk before it as fixed context in its smoothness term, so the
acceleration across a border is penalised as inside a chunk (continuity at chunk borders).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation, Slerp

from motiongen.body._threads import torch_threads
from motiongen.body.analytic import analytic_init
from motiongen.body.model import BodyModel, BodyParams
from motiongen.body.rotations import axis_angle_to_matrix, matrix_to_axis_angle, matrix_to_rot6d, rot6d_to_matrix
from motiongen.capture.cameras import Cameras
from motiongen.capture.objective import SEED_STAGES, StageWeights, Targets, terms, total
from motiongen.capture.pose_prior import PosePrior
from motiongen.capture.triangulate import triangulate
from motiongen.errors import ConfigError
from motiongen.skeleton import BODY_JOINT_NAMES, NUM_BODY_JOINTS

ROOT_JOINTS = tuple(BODY_JOINT_NAMES.index(n) for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip"))


@dataclass
class MultiviewConfig:
    length_unit: float = 0.02         # metres per length unit of L3D / Lsmooth (docs/capture.md: why 2 cm)
    rho: float = 0.01                 # Geman–McClure ρ, metres at the subject (pixels: ρ·f/depth)
    robust: str = "gm"                # "gm" | "l2" (the plain-L2 baseline)
    stage1_frames: int = 100
    chunk: int = 500
    steps: tuple[int, int, int] = (60, 40, 60)     # L-BFGS iterations per stage (per chunk)
    stages: dict[int, StageWeights] = field(default_factory=lambda: dict(SEED_STAGES))
    init_pose: str = "analytic"       # "analytic" (IK to the 3D targets) | "mean" (the seed: z = 0)
    init_smooth: float = 2.0          # frames: Gaussian smoothing of the targets the IK starts from
    reject_px: float | None = 30.0    # triangulation: views reprojecting further are outliers
    max_jump: float | None = 0.1      # triangulation: metres from the neighbours' predictions -> dropped
    min_views: int = 2
    threads: int = 1                  # torch intra-op threads (small tensors: 1 is fastest)

    def check(self) -> None:
        if self.init_pose not in ("analytic", "mean"):
            raise ConfigError(f"init_pose={self.init_pose!r}: expected analytic or mean")
        if self.robust not in ("gm", "l2"):
            raise ConfigError(f"robust={self.robust!r}: expected gm (Geman–McClure) or l2")
        if not (self.rho > 0 and self.length_unit > 0):
            raise ConfigError("rho and the length unit must be positive")
        if self.chunk < 3 or self.stage1_frames < 1 or min(self.steps) < 0 or self.init_smooth < 0:
            raise ConfigError("chunk must be >= 3 frames, stage1_frames >= 1, steps >= 0 and init_smooth >= 0")


@dataclass
class MultiviewResult(BodyParams):
    z: np.ndarray                     # (T, d) pose latents
    joints: np.ndarray                # (T, 22, 3) fitted joints, metres
    x3d: np.ndarray                   # (T, 22, 3) 3D targets (given or triangulated)
    conf3d: np.ndarray                # (T, 22)
    err3d: np.ndarray                 # (T, 22) metres to the targets (NaN where no target)
    err2d: np.ndarray                 # (C, T, 22) pixels to the detections (NaN where none)
    err3d_init: float = float("nan")  # metres: mean distance to the targets after initialisation
    stage_losses: dict = field(default_factory=dict)   # stage -> final terms and weighted total (mean over chunks)
    evaluations: dict = field(default_factory=dict)    # stage -> loss evaluations
    seconds: dict = field(default_factory=dict)        # stage -> wall seconds ("triangulate" too)


class _Logger:
    """Per-stage losses to TensorBoard (one point per loss evaluation), and their final values."""

    def __init__(self, writer):
        self.writer, self.step, self.last = writer, {}, {}

    def log(self, stage: int, t: dict, tot: float) -> None:
        s = self.step.get(stage, 0)
        self.step[stage] = s + 1
        vals = {k: float(v.detach()) for k, v in t.items()}
        vals["total"] = tot
        self.last[stage] = vals
        if self.writer is not None:
            for k, v in vals.items():
                self.writer.add_scalar(f"stage{stage}/{k}", v, s)


def root_init(bm: BodyModel, x3d: np.ndarray, w3d: np.ndarray, betas=None) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame root rotation (T, 3, 3) and translation (T, 3) aligning the rest template's
    shoulders and hips to the targets; frames without three of them are interpolated."""
    with torch.no_grad():
        rest = bm.rest_joints(None if betas is None else torch.as_tensor(betas, dtype=bm.J_template.dtype))
    rest = rest.double().cpu().numpy()                                     # (22, 3)
    idx = list(ROOT_JOINTS)
    T = len(x3d)
    Rs, ts, ok = np.tile(np.eye(3), (T, 1, 1)), np.zeros((T, 3)), np.zeros(T, bool)
    for t in range(T):
        w = w3d[t, idx]
        if (w > 0).sum() < 3:
            continue
        a, b = rest[idx][w > 0], x3d[t, idx][w > 0]
        ww = w[w > 0]
        ca, cb = (ww[:, None] * a).sum(0) / ww.sum(), (ww[:, None] * b).sum(0) / ww.sum()
        rot, _ = Rotation.align_vectors(b - cb, a - ca, weights=ww)
        Rs[t], ts[t], ok[t] = rot.as_matrix(), cb - rot.apply(ca), True
    if not ok.any():
        raise ConfigError("keypoints: the shoulders and hips are never seen in two views (or given in 3D): "
                          "no frame to start the fit from")
    good = np.flatnonzero(ok)
    if not ok.all():
        tt = np.clip(np.arange(T), good[0], good[-1])
        Rs = Slerp(good, Rotation.from_matrix(Rs[good]))(tt).as_matrix() if len(good) > 1 else np.repeat(Rs[good], T, 0)
        ts = np.stack([np.interp(np.arange(T), good, ts[good, i]) for i in range(3)], -1)
    J0 = rest[0]
    # posed joint k = R (J_k − J_0) + J_0 + transl  must equal  R J_k + t
    transl = ts - J0 + np.einsum("tij,j->ti", Rs, J0)
    return Rs, transl


def fill_targets(bm: BodyModel, x3d: np.ndarray, w3d: np.ndarray, Rs: np.ndarray, transl: np.ndarray) -> np.ndarray:
    """(T, 22, 3) targets with every gap filled: a joint's missing frames are interpolated in
    time between its seen ones; a joint never seen takes the root-aligned rest template's."""
    with torch.no_grad():
        rest = bm.rest_joints().double().cpu().numpy()                           # (22, 3)
    template = np.einsum("tij,kj->tki", Rs, rest - rest[0]) + (rest[0] + transl)[:, None]
    out = template.copy()
    frames = np.arange(len(x3d))
    for j in range(NUM_BODY_JOINTS):
        seen = np.flatnonzero(w3d[:, j] > 0)
        if len(seen):
            out[:, j] = np.stack([np.interp(frames, seen, x3d[seen, j, i]) for i in range(3)], -1)
    return out


def pose_init(bm: BodyModel, prior: PosePrior, x3d: np.ndarray, w3d: np.ndarray, Rs: np.ndarray,
              transl: np.ndarray, smooth: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Swing-correction IK (`body.fit.analytic_init`) from the root alignment to the (filled,
    then Gaussian-smoothed over `smooth` frames) targets -> root rotations (T, 3, 3),
    translations (T, 3), latents z (T, d) = V⁻¹(θ).

    Smoothing matters: L-BFGS removes jitter slowly (the smoothness term couples all frames),
    so a fit started from the noisy targets stays jittery for hundreds of iterations; one
    started smooth adds the detail the data asks for within tens (docs/results.md: figures)."""
    X = fill_targets(bm, x3d, w3d, Rs, transl)
    if smooth > 0:
        X = gaussian_filter1d(X, smooth, axis=0, mode="nearest")
    with torch.no_grad():
        rest = bm.rest_joints().double()
        start = torch.eye(3, dtype=torch.float64).repeat(len(X), NUM_BODY_JOINTS, 1, 1)
        start[:, 0] = torch.as_tensor(Rs)
        R = analytic_init(torch.as_tensor(X), rest, start)                         # (T, 22, 3, 3)
        theta = matrix_to_axis_angle(R[:, 1:]).reshape(len(X), 63).numpy()
    return R[:, 0].numpy(), X[:, 0] - rest[0].numpy(), prior.encode(theta)


class MultiviewFitter:
    """Runs the stages on one sequence; see `fit_multiview` for the entry point."""

    def __init__(self, bm: BodyModel, cams: Cameras, prior: PosePrior, cfg: MultiviewConfig, writer=None,
                 motion=None):
        cfg.check()
        self.bm, self.cams, self.cfg = bm, cams, cfg
        # LEMO's motion priors (a `prior_fit.PriorTerms`, or None): the smoothness prior in
        # stages 2 and 3, the infilling prior's markers in stage 3 (`infill` set before it).
        self.motion, self.infill = motion, None
        self.dev, self.dt = bm.J_template.device, bm.J_template.dtype
        self.decoder = prior.decoder(self.dt, self.dev)
        self.cam_t = cams.tensors(self.dt, self.dev)
        self.focal = torch.sqrt(self.cam_t["K"][:, 0, 0] * self.cam_t["K"][:, 1, 1])       # (C,) pixels
        self.log = _Logger(writer)

    def _t(self, a) -> torch.Tensor:
        return torch.as_tensor(np.asarray(a), dtype=self.dt, device=self.dev)

    def project(self, X):
        return self.cams.project(X, self.cam_t)

    def pose(self, rot6d, transl, z, betas):
        """-> joints (T, 22, 3), θ (T, 21, 3), R_root (T, 3, 3). transl is in length units:
        every parameter then moves the loss on a similar scale (better L-BFGS steps)."""
        R_root = rot6d_to_matrix(rot6d)
        theta = self.decoder(z).reshape(z.shape[0], 21, 3)
        R = torch.cat([R_root[:, None], axis_angle_to_matrix(theta)], 1)         # (T, 22, 3, 3)
        return self.bm.joints_from_rotmats(R, transl * self.cfg.length_unit, betas), theta, R_root

    def optimise(self, stage: int, state: dict, tg: Targets, fit_betas: bool, steps: int,
                 sl: slice = slice(None)) -> dict:
        """One chunk (frames `sl`) of one stage. state: rot6d (T, 6), transl (T, 3), z (T, d), betas (nβ,)."""
        w = self.cfg.stages[stage]
        p = {k: v.detach().clone().requires_grad_(k != "betas" or fit_betas) for k, v in state.items()}
        params = [v for v in p.values() if v.requires_grad]
        motion = self.motion_terms(stage, sl)

        def loss_terms():
            J, theta, R_root = self.pose(p["rot6d"], p["transl"], p["z"], p["betas"])
            t = terms(J, theta, R_root, p["z"], p["betas"], tg, self.project, length_unit=self.cfg.length_unit,
                      rho=self.cfg.rho, robust=self.cfg.robust, need_2d=w.w2d > 0)
            if motion:
                R = torch.cat([R_root[:, None], axis_angle_to_matrix(theta)], 1)        # (T, 22, 3, 3)
                args = (R, p["transl"] * self.cfg.length_unit, p["betas"])
                # The prior terms are in m² (as the joint fit's); L3D and Lsmooth are in units.
                t.update({k: f(*args) / self.cfg.length_unit ** 2 for k, f in motion.items()})
            return t

        if steps > 0:
            opt = torch.optim.LBFGS(params, lr=1.0, max_iter=steps, history_size=20, tolerance_grad=1e-9,
                                    tolerance_change=1e-10, line_search_fn="strong_wolfe")

            def closure():
                opt.zero_grad(set_to_none=True)
                t = loss_terms()
                loss = total(t, w)
                loss.backward()
                self.log.log(stage, t, loss.item())
                return loss

            opt.step(closure)
        with torch.no_grad():
            t = loss_terms()
            self.log.log(stage, t, total(t, w).item())
        return {k: v.detach() for k, v in p.items()}

    def motion_terms(self, stage: int, sl: slice) -> dict:
        """The motion priors' extra terms for frames `sl` of `stage`: {name: f(R, transl m, betas)}."""
        m = self.motion
        if m is None or stage < 2:
            return {}
        out = {"Lprior": m.smooth_term()} if m.smooth is not None else {}
        if stage == 3 and self.infill is not None:
            target, missing = self.infill
            out["Linfill"] = m.infill_term(target[sl], missing[sl])
        return out

    def set_infill(self, state: dict, observed: np.ndarray) -> None:
        """The infilling prior's markers for the whole sequence posed by `state`, the joints
        observed where `observed` (T, 22) says: stage 3's targets."""
        with torch.no_grad():
            J, theta, R_root = self.pose(state["rot6d"], state["transl"], state["z"], state["betas"])
            R = torch.cat([R_root[:, None], axis_angle_to_matrix(theta)], 1)
            self.infill = self.motion.infill_targets(R, state["transl"] * self.cfg.length_unit, state["betas"],
                                                     torch.as_tensor(observed, device=self.dev))

    def targets(self, x3d, w3d, uv, w2d, keypoints, sl: slice, context) -> Targets:
        """Frames `sl` of the observations, restricted to the observed joints `keypoints`."""
        k = keypoints
        return Targets(self._t(x3d[sl][:, k]), self._t(w3d[sl][:, k]),
                       None if uv is None else self._t(uv[:, sl][:, :, k].transpose(1, 2, 0, 3)),     # (T, K, C, 2)
                       None if w2d is None else self._t(w2d[:, sl][:, :, k].transpose(1, 2, 0)),      # (T, K, C)
                       None if len(k) == NUM_BODY_JOINTS else torch.as_tensor(k, device=self.dev),
                       focal=self.focal, context=context)

    def run_stage(self, stage: int, state: dict, data: tuple, n: int, chunk: int, fit_betas: bool) -> tuple[dict, list]:
        """Stage over frames [0, n) in chunks; returns the new state (all T frames) and the
        final weighted terms of each chunk."""
        out = {k: v.clone() for k, v in state.items()}
        finals = []
        context = None
        for s in range(0, n, chunk):
            sl = slice(s, min(s + chunk, n))
            chunk_state = {k: (v if k == "betas" else v[sl]) for k, v in out.items()}
            tg = self.targets(*data, sl, context)
            res = self.optimise(stage, chunk_state, tg, fit_betas, self.cfg.steps[stage - 1], sl)
            finals.append(self.log.last[stage])
            for k, v in res.items():
                if k == "betas":
                    out[k] = v
                else:
                    out[k][sl] = v
            with torch.no_grad():
                J, theta, R_root = self.pose(res["rot6d"][-2:], res["transl"][-2:], res["z"][-2:], res["betas"])
            context = (J, theta, R_root)
        return out, finals


def fit_multiview(bm: BodyModel, cams: Cameras, uv: np.ndarray, conf: np.ndarray, prior: PosePrior,
                  cfg: MultiviewConfig = MultiviewConfig(), x3d: np.ndarray | None = None,
                  conf3d: np.ndarray | None = None, observed: np.ndarray | None = None,
                  writer=None, motion=None) -> MultiviewResult:
    """Fit SMPL-X to one person seen by calibrated cameras.

    uv (C, T, 22, 2) pixels and conf (C, T, 22) detections on our joints (`keypoints.py`);
    x3d (T, 22, 3) / conf3d (T, 22) optional 3D keypoints (else triangulated); observed (22,)
    bool: the joints the keypoint layout has (default: those ever detected); writer: a
    TensorBoard SummaryWriter or None; motion: LEMO's motion priors (`prior_fit.PriorTerms`):
    the smoothness prior's term in stages 2 and 3, and in stage 3 the infilling prior's markers
    for the joints without a 3D keypoint at a frame (confidence 0).
    """
    if uv.ndim != 4 or uv.shape[0] != len(cams) or uv.shape[2:] != (NUM_BODY_JOINTS, 2) or conf.shape != uv.shape[:3]:
        raise ConfigError(f"detections: expected uv ({len(cams)}, T, {NUM_BODY_JOINTS}, 2) and conf (C, T, "
                          f"{NUM_BODY_JOINTS}), got {uv.shape} and {conf.shape}")
    C, T = conf.shape[:2]
    if x3d is not None and (x3d.shape != (T, NUM_BODY_JOINTS, 3) or conf3d is None
                            or conf3d.shape != (T, NUM_BODY_JOINTS)):
        raise ConfigError(f"3D keypoints: expected ({T}, {NUM_BODY_JOINTS}, 3) with conf3d ({T}, {NUM_BODY_JOINTS})")
    seconds = {}
    t0 = time.time()
    if x3d is None:
        tri = triangulate(cams, uv, conf, cfg.min_views, cfg.reject_px, cfg.max_jump)
        x3d, conf3d = tri.points, tri.conf
    seconds["triangulate"] = time.time() - t0
    if observed is None:
        observed = (conf > 0).any((0, 1)) | (conf3d > 0).any(0)
    keypoints = np.flatnonzero(observed)
    fitter = MultiviewFitter(bm, cams, prior, cfg, writer, motion)
    with torch_threads(cfg.threads):
        t0 = time.time()
        Rs, transl = root_init(bm, x3d, conf3d)
        z = np.zeros((T, prior.dims))
        if cfg.init_pose == "analytic":
            Rs, transl, z = pose_init(bm, prior, x3d, conf3d, Rs, transl, cfg.init_smooth)
        seconds["init"] = time.time() - t0
        state = {"rot6d": matrix_to_rot6d(fitter._t(Rs)), "transl": fitter._t(transl / cfg.length_unit),
                 "z": fitter._t(z), "betas": torch.zeros(bm.num_betas, dtype=fitter.dt, device=fitter.dev)}
        with torch.no_grad():
            J0 = fitter.pose(state["rot6d"], state["transl"], state["z"], state["betas"])[0].double().cpu().numpy()
        init_err = float(np.nanmean(np.where(conf3d > 0, np.linalg.norm(J0 - x3d, axis=-1), np.nan)))
        data = (x3d, conf3d, uv, conf, keypoints)
        finals = {}
        for stage in (1, 2, 3):
            t0 = time.time()
            n = min(cfg.stage1_frames, T) if stage == 1 else T
            chunk = n if stage == 1 else cfg.chunk
            if stage == 3 and motion is not None and motion.infill is not None:
                fitter.set_infill(state, conf3d > 0)
            state, finals[stage] = fitter.run_stage(stage, state, data, n, chunk, fit_betas=stage == 1)
            seconds[f"stage{stage}"] = time.time() - t0
        with torch.no_grad():
            J, theta, R_root = fitter.pose(state["rot6d"], state["transl"], state["z"], state["betas"])
            uv_hat, depth = fitter.project(J)                                  # (T, 22, C, 2)
    J_np = J.double().cpu().numpy()
    err3d = np.where(conf3d > 0, np.linalg.norm(J_np - x3d, axis=-1), np.nan)
    e2 = np.linalg.norm(uv_hat.double().cpu().numpy().transpose(2, 0, 1, 3) - uv, axis=-1)   # (C, T, 22)
    err2d = np.where((conf > 0) & (depth.cpu().numpy().transpose(2, 0, 1) > 0), e2, np.nan)
    losses = {s: {k: float(np.mean([f[k] for f in v])) for k in v[0]} for s, v in finals.items()}
    return MultiviewResult(
        global_orient=matrix_to_axis_angle(R_root).double().cpu().numpy(),
        body_pose=theta.reshape(T, 63).double().cpu().numpy(),
        transl=state["transl"].double().cpu().numpy() * cfg.length_unit,
        betas=state["betas"].double().cpu().numpy(), z=state["z"].double().cpu().numpy(), joints=J_np,
        x3d=x3d, conf3d=conf3d, err3d=err3d, err2d=err2d, err3d_init=init_err, stage_losses=losses,
        evaluations=dict(fitter.log.step), seconds=seconds)

