"""Joints (T, 22, 3) → SMPL-X parameters: initialise, then refine by gradient descent.

Initialisation: the 3-frame MLP's rotations (`mlp.py`; smoothed over time), or identity
without a network, then *swing correction* (`analytic_init`): down the tree, each joint is
rotated by the smallest rotation (Kabsch at the pelvis and spine3) that points its bones at the
target joints, keeping the MLP's twist. Refinement then optimises all frames at once (6D
rotations, translations, one β per sequence) with L-BFGS on

    w_joints  · mean ‖J(θ) − X‖²                 joint positions
  + w_smooth_joints · mean ‖J_{t-1} − 2J_t + J_{t+1}‖²   joint acceleration
  + w_smooth_rot    · mean ‖R_{t-1} − 2R_t + R_{t+1}‖²_F rotation acceleration (no flips/jitter)
  + w_prior  · mean ‖R − R_init‖²_F              stay near the initialisation (twist is
                                                 barely observable from joints)
  + w_betas  · ‖β‖² / nβ                         shape prior
  + w_contact · mean over contact spans of ‖J_t − c_span‖²   (optional foot locking: c_span
                 is the span's own mean across the floor, and upwards the height it is held
                 at, by default the target's mean height over the span)
  + w_clearance · mean over unplanted contact-joint frames of max(0, y_target − y)²
                                                 (swing clearance: smoothing may not lower a
                                                 swinging foot)
  + w_foot_vel · Σ max(0, ‖v_foot‖ − a) over feet near the floor or flagged in contact,
                 / ((T−1)·K)                       (LEMO, Eq. 14; `foot_velocity.py`)

(the multi-view capture paper: 3D keypoint L2, second-difference smoothness of keypoints and
joint angles, ℓ2 shape prior). Only joint kinematics run per iteration
(`BodyModel.joints_from_rotmats`), never the mesh. Small tensors make torch's intra-op threads
pure overhead here, so refinement runs single-threaded by default (`threads`).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from motiongen.body import train_mlp
from motiongen.body._threads import torch_threads
from motiongen.body.analytic import analytic_init, smooth_rotations
from motiongen.body.foot_velocity import check_mask, foot_velocity_loss, foot_velocity_mask
from motiongen.body.mlp import JointsToBodyMLP
from motiongen.body.model import BodyModel, BodyParams, load_body_model
from motiongen.body.posing import FixedBodyPose
from motiongen.body.rotations import matrix_to_axis_angle, matrix_to_rot6d, rot6d_to_matrix
from motiongen.errors import ConfigError
from motiongen.paths import cache_dir
from motiongen.rates import DATA_FPS
from motiongen.skeleton import FOOT_JOINTS, NUM_BODY_JOINTS

@dataclass
class RefineConfig:
    max_steps: int = 30             # L-BFGS iterations (Adam: steps)
    optimizer: str = "lbfgs"        # "lbfgs" | "adam"
    lr: float = 1.0                 # L-BFGS step scale; Adam uses adam_lr
    adam_lr: float = 0.01
    tol: float = 1e-6               # stop when the loss changes less than this (1e4 × m²)
    w_joints: float = 1.0
    w_smooth_joints: float = 0.1
    w_smooth_rot: float = 0.03
    w_prior: float = 1e-4
    w_betas: float = 1e-5
    w_contact: float = 0.0
    # The foot lock holds each planted span at a height: `refine`'s planted_heights, or the
    # target's, averaged over the span. False: at whatever height the rest of the objective
    # likes, which lifts the feet of a body that travels further than its stride (`lock_loss`).
    lock_height: bool = True
    w_reach: float = 0.0            # weight of `reach` targets (a hand on an object)
    w_floor: float = 0.0            # joint centres below floor_y (squared depth, summed over joints)
    floor_y: float = 0.0
    # Swing clearance: a contact joint that is not flagged planted is not pulled below the
    # target's height (squared shortfall, mean over swing entries). Needs `contact`.
    w_clearance: float = 0.0
    # LEMO's foot velocity term (foot_velocity.py): foot joints faster than foot_vel_a m/s
    # while within foot_z_thres m of floor_y ("height", in the target) or flagged by the
    # contact labels ("contact").
    w_foot_vel: float = 0.0
    # The joint acceleration weight of the contact joints (the feet) in the joint-space solve
    # (`joint_solve`; None: w_smooth_joints): what keeps a foot from skating there is smoothing
    # it, which the rest of the body, whose steps are 2-5 Hz, does not want.
    w_smooth_contact: float | None = None
    foot_vel_a: float = 0.10
    foot_z_thres: float = 0.10
    foot_vel_mask: str = "height"
    foot_vel_steps: int = 100       # L-BFGS iterations of fit_joints' second pass, which adds the term
    optimize_betas: bool = True
    mlp_smooth_sigma: float = 2.0   # frames; Gaussian smoothing of the per-frame MLP rotations
    threads: int = 1                # torch intra-op threads during refinement; 0: unchanged


@dataclass
class FitResult(BodyParams):
    joints: np.ndarray              # (T, 22, 3) fitted body-model joints
    per_frame_error: np.ndarray     # (T,) mean joint distance to the target, metres
    mpjpe_mlp: float | None         # metres, the MLP's raw prediction (None without MLP)
    mpjpe_init: float               # metres, after initialisation (MLP + swing correction, or analytic)
    mpjpe: float                    # metres, after refinement
    steps: int
    seconds: float
    init: str                       # "mlp" | "analytic"
    history: list = field(default_factory=list)


# ---- refinement ------------------------------------------------------------------------

def contact_spans(contact: torch.Tensor) -> tuple[torch.Tensor, int]:
    """Span ids (T, C) long for contact flags (T, C) bool: every run of True frames of a column
    gets its own id (0..n-1, numbered column by column), -1 outside contact. Returns (ids, n)."""
    c = contact.to(torch.long)
    start = c.clone()
    start[1:] = c[1:] * (1 - c[:-1])                                            # 1 where a run begins
    order = start.T.reshape(-1).cumsum(0).reshape(start.shape[1], -1).T - 1     # (T, C) running count
    ids = torch.where(contact, order, torch.full_like(order, -1))
    return ids, int(start.sum())


def lock_loss(J: torch.Tensor, ids: torch.Tensor, n: int, joints, heights: torch.Tensor | None = None) -> torch.Tensor:
    """Mean squared distance of each locked joint from its span's centre: zero when a planted
    foot stays put. Across the floor (x, z) the centre is the span's own mean (no spot to
    choose); its height is `heights` (n,), the height each span is held at, or, None, the span's
    own mean too. A free height lets a solve that must also follow a body moving faster than its
    feet lift the planted feet off the floor: a diagonal leg reaches further with the foot
    higher (docs/results.md, "The output's feet float"). J (T, J, 3), ids (T, C) from
    `contact_spans`, joints (C,) joint index per column."""
    P = J[:, list(joints)]                                                     # (T, C, 3)
    on = ids >= 0
    sel, idx = P[on], ids[on]                                                  # (N, 3), (N,)
    mean = span_means(sel, idx, n)                                             # (n, 3)
    if heights is not None:
        mean = torch.stack([mean[:, 0], heights.to(J.dtype), mean[:, 2]], -1)
    return (sel - mean[idx]).square().sum(-1).mean()


def span_means(values: torch.Tensor, idx: torch.Tensor, n: int) -> torch.Tensor:
    """(n, ...) the mean of values (N, ...) over the entries of each of n spans, idx (N,) the
    span id of each entry (the planted entries of `contact_spans`' ids)."""
    sums = torch.zeros((n, *values.shape[1:]), dtype=values.dtype, device=values.device).index_add_(0, idx, values)
    counts = torch.zeros(n, dtype=values.dtype, device=values.device).index_add_(0, idx, torch.ones_like(idx, dtype=values.dtype))
    return sums / counts.reshape(n, *[1] * (values.dim() - 1))


def refine(bm: BodyModel, target: torch.Tensor, rot_init: torch.Tensor, betas_init: torch.Tensor,
           cfg: RefineConfig = RefineConfig(), contact: torch.Tensor | None = None,
           fixed_betas: bool = False, contact_joints=FOOT_JOINTS, transl_init: torch.Tensor | None = None,
           reach: tuple | None = None, fps: float = DATA_FPS, target_weights: torch.Tensor | None = None,
           extra=None, planted_heights: torch.Tensor | None = None):
    """Refine (T, 22, 3, 3) rotations, (T, 3) translations and (nβ,) betas to fit target
    joints (T, 22, 3) at `fps`. contact (T, C) bool flags `contact_joints` as planted (foot
    locking, weight `cfg.w_contact`; and the frames of the foot velocity term, weight
    `cfg.w_foot_vel`, when `cfg.foot_vel_mask` is "contact"; with "height" that term takes the
    `contact_joints` near the floor). reach = (frames (N,), joints (N,), points (N, 3), weights (N,)):
    joint positions to reach at those frames (weight `cfg.w_reach`; a weighted mean, so
    weights ramp a reach in and out). target_weights (T, 22): the joint term's weight per
    target entry (0 where a joint was not observed; None: all 1). extra: a callable
    (rotmats (T, 22, 3, 3), transl (T, 3), betas) -> scalar added to the loss in the joint
    term's units (m²; the learned motion priors' terms, `motiongen.capture.prior_fit`).
    planted_heights (T, C): the heights the foot lock holds `contact_joints` at, each span at its
    mean (None: the target's own heights; `lock_loss`). Returns (rotmats, transl, betas, steps,
    history)."""
    T = target.shape[0]
    R0 = rot_init.detach()
    rot6d = matrix_to_rot6d(R0).clone().requires_grad_(True)                   # (T, 22, 6)
    betas = betas_init.detach().clone().requires_grad_(cfg.optimize_betas and not fixed_betas)
    with torch.no_grad():
        transl0 = target[:, 0] - bm.rest_joints(betas)[0] if transl_init is None else transl_init
    transl = transl0.detach().clone().requires_grad_(True)                     # (T, 3)
    params = [rot6d, transl] + ([betas] if betas.requires_grad else [])
    nb = max(betas.numel(), 1)
    # Scaled so that a 1 cm mean error is a loss of about 1: keeps L-BFGS tolerances meaningful.
    scale = 1e4
    ct = _contact_terms(cfg, target, contact, contact_joints, planted_heights)
    if target_weights is not None:
        tw = target_weights.to(target.dtype)
        tw_sum = tw.sum().clamp(min=1e-9)
        target = torch.where(tw[..., None] > 0, target, torch.zeros_like(target))   # no NaN reaches a gradient

    # A fixed body is posed with a hand-written backward pass (body.posing): the same values without
    # autograd's per-operation cost, which on these small tensors was most of each L-BFGS step.
    pose = None if betas.requires_grad else FixedBodyPose(bm.rest_joints(betas), bm.parents)

    def loss_fn():
        if pose is not None:
            J, R = pose(rot6d, transl)                                         # (T, 22, 3), (T, 22, 3, 3)
        else:
            R = rot6d_to_matrix(rot6d)
            J = bm.joints_from_rotmats(R, transl, betas)
        d2 = (J - target).square().sum(-1)                                     # (T, 22)
        loss = cfg.w_joints * (d2.mean() if target_weights is None else (tw * d2).sum() / tw_sum)
        if T >= 3:
            if cfg.w_smooth_joints:
                acc = J[2:] - 2 * J[1:-1] + J[:-2]
                loss = loss + cfg.w_smooth_joints * acc.square().sum(-1).mean()
            if cfg.w_smooth_rot:
                racc = R[2:] - 2 * R[1:-1] + R[:-2]
                loss = loss + cfg.w_smooth_rot * racc.square().sum((-1, -2)).mean()
        if cfg.w_prior:
            loss = loss + cfg.w_prior * (R - R0).square().sum((-1, -2)).mean()
        if betas.requires_grad and cfg.w_betas:
            loss = loss + cfg.w_betas * betas.square().sum() / nb
        if ct.lock is not None:
            ids, n, held = ct.lock
            loss = loss + cfg.w_contact * lock_loss(J, ids, n, contact_joints, held)
        if ct.foot_mask is not None:
            loss = loss + cfg.w_foot_vel * foot_velocity_loss(J, ct.foot_mask, contact_joints, fps, cfg.foot_vel_a)
        if cfg.w_floor:
            loss = loss + cfg.w_floor * (cfg.floor_y - J[..., 1]).clamp(min=0).square().sum(-1).mean()
        if ct.swing is not None:
            short = (ct.swing_y - J[:, ct.swing_j, 1]).clamp(min=0) * ct.swing
            loss = loss + cfg.w_clearance * short.square().sum() / ct.n_swing
        if reach is not None and cfg.w_reach:
            f, j, p, w = reach
            loss = loss + cfg.w_reach * (w * (J[f, j] - p).square().sum(-1)).sum() / w.sum().clamp(min=1e-9)
        if extra is not None:
            loss = loss + extra(R, transl, betas)
        return loss * scale

    with torch_threads(cfg.threads):
        steps, history = _optimise(cfg, params, loss_fn)
    with torch.no_grad():
        R = rot6d_to_matrix(rot6d)
    return R, transl.detach(), betas.detach(), steps, history


@dataclass
class _ContactTerms:
    """What the contact-driven terms of `refine`'s loss need, built once per solve (not at every
    loss evaluation, the L-BFGS hot path). None: the term is off."""
    lock: tuple | None = None                 # (span ids (T, C), number of spans, height per span (n,))
    swing: torch.Tensor | None = None         # (T, C) 1.0 where a contact joint is not planted
    swing_j: torch.Tensor | None = None       # (C,) the contact joints
    swing_y: torch.Tensor | None = None       # (T, C) their target heights
    n_swing: torch.Tensor | None = None       # () swing entries, at least 1
    foot_mask: torch.Tensor | None = None     # (T, C) frames of the foot velocity term


def _contact_terms(cfg: RefineConfig, target: torch.Tensor, contact: torch.Tensor | None, contact_joints,
                   planted_heights: torch.Tensor | None = None) -> _ContactTerms:
    """The foot-locking spans and heights, swing-clearance targets and foot-velocity frames for
    target joints (T, 22, 3) and contact flags (T, C) of `contact_joints`, as far as cfg's
    weights ask; planted_heights (T, C) or None: see `refine`."""
    ct = _ContactTerms()
    if contact is not None and cfg.w_contact and bool(contact.any()):
        ids, n = contact_spans(contact)
        held = None
        if cfg.lock_height:
            heights = target[:, list(contact_joints), 1] if planted_heights is None else planted_heights.to(target.dtype)
            on = ids >= 0
            held = span_means(heights[on], ids[on], n)                                 # (n,)
        ct.lock = (ids, n, held)
    if contact is not None and cfg.w_clearance:
        ct.swing = (~contact.to(torch.bool)).to(target.dtype)                        # (T, C)
        ct.swing_j = torch.as_tensor(list(contact_joints), device=target.device)     # (C,)
        ct.swing_y = target[:, ct.swing_j, 1]                                        # (T, C)
        ct.n_swing = ct.swing.sum().clamp(min=1)
    if cfg.w_foot_vel:
        check_mask(cfg.foot_vel_mask, contact, target.shape[0], len(contact_joints))
        ct.foot_mask = (contact.to(torch.bool) if cfg.foot_vel_mask == "contact"
                        else foot_velocity_mask(target, contact_joints, cfg.floor_y, cfg.foot_z_thres))
    return ct


@contextlib.contextmanager
def _without_compiler_import():
    """Construct a torch optimizer without importing torch's compiler. Optimizer.add_param_group
    is wrapped to keep torch.compile out of it, and the wrapper imports torch._dynamo on its first
    call (1.4 s once per process: a quarter of a short `motiongen sample` run, in which nothing
    is compiled). The wrapper calls the function it finds cached on the raw one, so the raw
    function is cached as itself for the construction. Where torch has no such wrapper, or the
    compiler is loaded already, nothing changes; tests/test_body_fit.py checks that a refine
    imports no compiler."""
    raw = getattr(torch.optim.Optimizer.add_param_group, "__wrapped__", None)
    if raw is None or "torch._dynamo" in sys.modules or hasattr(raw, "__dynamo_disable"):
        yield
        return
    setattr(raw, "__dynamo_disable", raw)
    try:
        yield
    finally:
        delattr(raw, "__dynamo_disable")


def _optimise(cfg: RefineConfig, params: list, loss_fn) -> tuple[int, list[float]]:
    history: list[float] = []
    steps = 0
    if cfg.optimizer == "lbfgs":
        with _without_compiler_import():
            opt = torch.optim.LBFGS(params, lr=cfg.lr, max_iter=cfg.max_steps, history_size=20,
                                    tolerance_grad=1e-7, tolerance_change=cfg.tol, line_search_fn="strong_wolfe")

        def closure():
            for p in params:          # opt.zero_grad(set_to_none=True), whose wrapper imports the compiler
                p.grad = None
            loss = loss_fn()
            loss.backward()
            history.append(loss.item())
            return loss

        opt.step(closure)
        steps = opt.state[opt._params[0]]["n_iter"]
    elif cfg.optimizer == "adam":
        opt = torch.optim.Adam(params, lr=cfg.adam_lr)
        prev = None
        for steps in range(1, cfg.max_steps + 1):
            opt.zero_grad(set_to_none=True)
            loss = loss_fn()
            loss.backward()
            opt.step()
            history.append(loss.item())
            if prev is not None and steps % 10 == 0:
                if abs(prev - history[-1]) < cfg.tol * 10:
                    break
            if steps % 10 == 0:
                prev = history[-1]
    else:
        raise ConfigError(f"refine.optimizer: expected 'lbfgs' or 'adam', got {cfg.optimizer!r}")
    return steps, history


# ---- the default MLP -------------------------------------------------------------------

def _model_key(bm: BodyModel) -> str:
    h = hashlib.sha1()
    h.update(bm.J_template.cpu().numpy().tobytes())
    h.update(bm.J_dirs.cpu().numpy().tobytes())
    return h.hexdigest()[:12]


def default_mlp(bm: BodyModel, cache: bool = True, verbose: bool = False) -> JointsToBodyMLP:
    """A small MLP trained briefly on synthetic motion of `bm` (a short CPU job), cached per
    body model under the motiongen cache. Good enough as an initialiser (a few cm); refinement
    does the rest."""
    cfg = train_mlp.TrainMLPConfig(steps=1500, batch_size=256, lr=2e-3, log_every=250, threads=1,
                                   mlp=train_mlp.MLPConfig(width=256, layers=4, num_betas=min(10, bm.num_betas)),
                                   data=train_mlp.DataConfig(num_sequences=128, seq_frames=240))
    # Keyed by body model and training recipe, so a changed recipe never loads a stale network.
    recipe = hashlib.sha1(repr(cfg).encode()).hexdigest()[:8]
    path = cache_dir() / "body" / f"default_mlp_{_model_key(bm)}_{recipe}.pt"
    if cache and path.is_file():
        return train_mlp.load_mlp(path)
    model = train_mlp.train(cfg, bm=bm, verbose=verbose)
    if cache:
        train_mlp.save_checkpoint(model, cfg, path)
    return model


# ---- public entry point ------------------------------------------------------------------

def fit_joints(joints, body_model: BodyModel | None = None, mlp: JointsToBodyMLP | str | Path | None = None, *,
               betas=None, contact=None, config: RefineConfig = RefineConfig(), refine_steps: int | None = None,
               device: str | torch.device = "cpu", fps: float = DATA_FPS) -> FitResult:
    """Fit SMPL-X parameters to body joints.

    joints: (T, 22, 3) array/tensor, metres, y-up (SMPL-X body joint order).
    body_model: default `load_body_model()` (user file or procedural).
    mlp: a `JointsToBodyMLP`, a checkpoint path, "auto" (`default_mlp`), or None (analytic init).
    betas: (nβ,) known shape (kept fixed) or None (estimated).
    contact: (T, 4) bool planted flags for `skeleton.FOOT_JOINTS`: with config.w_contact > 0 each
    planted span of a foot joint is held in one place (foot locking, `lock_loss`); with
    config.w_foot_vel > 0 and foot_vel_mask "contact" they pick the frames of the foot velocity
    term (LEMO). fps: the joints' frame rate (velocities of that term are in m/s).
    refine_steps: overrides config.max_steps; 0 returns the initialisation.
    """
    X = _checked_joints(joints)
    bm = body_model if body_model is not None else load_body_model()
    dev = torch.device(device)
    bm = bm.to(dev)
    X = X.to(device=dev, dtype=bm.J_template.dtype)
    t0 = time.time()
    with torch_threads(config.threads):
        if isinstance(mlp, str) and mlp == "auto":
            mlp = default_mlp(bm)
        elif isinstance(mlp, (str, Path)):
            mlp = train_mlp.load_mlp(mlp)
        b_known = None if betas is None else torch.as_tensor(np.asarray(betas), dtype=X.dtype, device=dev)
        R_init, b_init, mpjpe_mlp, mpjpe_init = _initialise(bm, X, mlp, b_known, config.mlp_smooth_sigma, dev)
        init = "mlp" if mlp is not None else "analytic"
        cfg = config if refine_steps is None else RefineConfig(**{**config.__dict__, "max_steps": refine_steps})
        ct = None if contact is None else torch.as_tensor(np.asarray(contact), dtype=torch.bool, device=dev)
        if cfg.w_foot_vel:
            check_mask(cfg.foot_vel_mask, ct, X.shape[0], len(FOOT_JOINTS))
        if cfg.max_steps > 0:
            R, transl, b, steps, hist = _refine_passes(bm, X, R_init, b_init, cfg, ct, b_known is not None, fps)
        else:
            R, transl, b, steps, hist = R_init, X[:, 0] - bm.rest_joints(b_init)[0], b_init, 0, []
        with torch.no_grad():
            J = bm.joints_from_rotmats(R, transl, b)
            err = (J - X).norm(dim=-1).mean(-1)                                  # (T,)
            aa = matrix_to_axis_angle(R)                                          # (T, 22, 3)
    T = X.shape[0]
    return FitResult(
        global_orient=aa[:, 0].cpu().numpy(), body_pose=aa[:, 1:].reshape(T, 63).cpu().numpy(),
        transl=transl.cpu().numpy(), betas=b.cpu().numpy(), joints=J.cpu().numpy(),
        per_frame_error=err.cpu().numpy(), mpjpe_mlp=mpjpe_mlp, mpjpe_init=mpjpe_init, mpjpe=err.mean().item(),
        steps=int(steps), seconds=time.time() - t0, init=init, history=hist)


def _checked_joints(joints) -> torch.Tensor:
    """The target joints (T, 22, 3) as a tensor, their shape and values checked."""
    X = joints if isinstance(joints, torch.Tensor) else torch.as_tensor(np.array(joints))  # copy: inputs may be read-only memmaps
    if X.ndim != 3 or X.shape[1:] != (NUM_BODY_JOINTS, 3) or X.shape[0] < 1:
        raise ConfigError(f"joints: expected shape (T, {NUM_BODY_JOINTS}, 3), got {tuple(X.shape)}")
    if not torch.isfinite(X).all():
        raise ConfigError("joints contain NaN or inf")
    return X


def _initialise(bm: BodyModel, X: torch.Tensor, mlp: JointsToBodyMLP | None, b_known: torch.Tensor | None,
                smooth_sigma: float, dev: torch.device):
    """The start of refinement for target joints X (T, 22, 3): rotations (T, 22, 3, 3), the MLP's
    (smoothed over `smooth_sigma` frames) or none, swing-corrected (`analytic_init`), and betas
    (nβ,), known or the MLP's. Returns (rotations, betas, MLP's mean joint error or None, the
    start's mean joint error), errors in metres."""
    mpjpe_mlp, R_mlp = None, None
    b_init = torch.zeros(bm.num_betas, dtype=X.dtype, device=dev)
    if mlp is not None:
        mlp = mlp.to(dev)
        pred = mlp.predict(X)
        R_mlp = pred["rotmats"].to(X.dtype)                               # (T, 22, 3, 3)
        if pred["betas"] is not None:
            b_init[: pred["betas"].numel()] = pred["betas"][: bm.num_betas]
        with torch.no_grad():
            b_m = b_init if b_known is None else b_known
            J_mlp = bm.joints_from_rotmats(R_mlp, X[:, 0] - bm.rest_joints(b_m)[0], b_m)
            mpjpe_mlp = (J_mlp - X).norm(dim=-1).mean().item()
    if b_known is not None:
        b_init = b_known
    if R_mlp is not None:
        R_mlp = smooth_rotations(R_mlp, smooth_sigma)
    R_init = analytic_init(X, bm.rest_joints(b_init), R_mlp)
    with torch.no_grad():
        J0 = bm.joints_from_rotmats(R_init, X[:, 0] - bm.rest_joints(b_init)[0], b_init)
        mpjpe_init = (J0 - X).norm(dim=-1).mean().item()
    return R_init, b_init, mpjpe_mlp, mpjpe_init


def _refine_passes(bm: BodyModel, X: torch.Tensor, R_init: torch.Tensor, b_init: torch.Tensor, cfg: RefineConfig,
                   ct: torch.Tensor | None, fixed: bool, fps: float):
    """`refine` without the foot velocity term, then (cfg.w_foot_vel) a second pass with it from
    the first one's result. Returns (rotmats, transl, betas, steps, history) of both together."""
    R, transl, b, steps, hist = refine(bm, X, R_init, b_init, replace(cfg, w_foot_vel=0.0), ct,
                                       fixed_betas=fixed, fps=fps)
    if cfg.w_foot_vel:
        # The term's hinge is a poor start for L-BFGS: from the initialisation it ends far above
        # the loss reached from the joint fit, so it is added in a second pass from the first
        # pass's result, which needs more iterations than the first (`foot_vel_steps`; the
        # measurements: docs/results.md).
        R, transl, b, s2, h2 = refine(bm, X, R, b, replace(cfg, max_steps=cfg.foot_vel_steps), ct,
                                      fixed_betas=fixed, transl_init=transl, fps=fps)
        steps, hist = steps + s2, hist + h2
    return R, transl, b, steps, hist


def save_amass_npz(path: str | Path, fit: FitResult, fps: float, gender: str = "neutral") -> Path:
    """AMASS SMPL-X layout: poses (T, 165) = root 3 + body 63 + jaw 3 + eyes 6 + hands 90
    (zeros beyond the body), trans, betas, mocap_framerate, gender; plus root_orient,
    pose_body, joints and per-frame joint error, and `up` = "y": unlike AMASS (z-up) our world
    is y-up, and `motiongen.importers.amass` reads this key. Written to a temp file, then
    renamed."""
    path = Path(path)
    T = fit.transl.shape[0]
    poses = np.zeros((T, 165), np.float32)
    poses[:, :3] = fit.global_orient
    poses[:, 3:66] = fit.body_pose
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, poses=poses, trans=fit.transl.astype(np.float32), betas=fit.betas.astype(np.float32),
             mocap_framerate=np.array(float(fps)), gender=np.array(gender), surface_model_type=np.array("smplx"),
             root_orient=fit.global_orient.astype(np.float32), pose_body=fit.body_pose.astype(np.float32),
             joints=fit.joints.astype(np.float32), joint_error=fit.per_frame_error.astype(np.float32),
             up=np.array("y"))
    os.replace(tmp, path)
    return path
