"""Fitting joints with LEMO's learned motion priors (the LEMO supplement, its fitting stages).

Missing observations are NaN joints. Every fit starts from today's fit (`fit_joints`) of the
joints with the gaps filled by linear interpolation over time: with no prior that is the
result (the baseline the priors are measured against). With priors, from that start:

  stage 2 (smoothness prior):  joint term on the observed joints only
                               + w_smooth · the smoothness prior's latent change over time
                                 on the body's 81 markers, in place of the joint-acceleration
                                 term (the foot velocity term stays when asked for);
  stage 3 (infilling prior):   the infilling prior fills the markers of the joints that were
                               missing from the stage-2 body's observed markers; the fit adds
                               w_infill · mean distance of those markers to the infilled ones.

Stage 2 comes before stage 3, as the supplement's ablation says it must: the infilling prior
was trained on clean motion and needs smooth input. The optimiser is the refinement's
L-BFGS (the paper uses Adam, 900 steps per 100 frames: far beyond two CPU cores); `steps`
iterations per stage.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import numpy as np
import torch

from motiongen.body.fit import FitResult, RefineConfig, fit_joints, refine
from motiongen.body.model import BodyModel
from motiongen.body.rotations import axis_angle_to_matrix, matrix_to_axis_angle
from motiongen.capture import markers as mk
from motiongen.capture.motion_prior import infill, load_prior, smoothness_term
from motiongen.errors import ConfigError
from motiongen.skeleton import BODY_JOINT_NAMES

# Distances of the infilling term are divided by this length (metres) and squared near zero:
# a 1 cm miss then costs about what a 1 cm joint miss costs in the joint term (m²).
INFILL_SCALE = 0.01


@dataclass
class MotionPriorConfig:
    smooth: str | None = None       # a smoothness prior (train-motion-prior kind=smooth), or None
    infill: str | None = None       # an infilling prior (kind=infill), or None
    w_smooth: float = 2.0           # weight of the latent smoothness term (chosen on the synthetic val split)
    w_infill: float = 1.0           # weight of the distance to the infilled markers
    steps: int = 30                 # L-BFGS iterations of stage 2 and of stage 3

    def check(self) -> None:
        if self.w_smooth < 0 or self.w_infill < 0:
            raise ConfigError("motion_prior.w_smooth and motion_prior.w_infill must be >= 0")
        if self.steps < 0:
            raise ConfigError(f"motion_prior.steps={self.steps}: expected >= 0")

    @property
    def any(self) -> bool:
        return bool(self.smooth or self.infill)


def fill_linear(joints: np.ndarray, desc: str = "joints") -> tuple[np.ndarray, np.ndarray]:
    """NaN joints (T, 22, 3) filled by linear interpolation over time (the first and last
    observed frame held at the ends). Returns (filled (T, 22, 3), observed (T, 22) bool).
    A joint never observed has nothing to interpolate: ConfigError naming it."""
    X = np.array(joints, dtype=np.float64)
    observed = np.isfinite(X).all(-1)                                          # (T, 22)
    t = np.arange(X.shape[0])
    for j in range(X.shape[1]):
        seen = observed[:, j]
        if seen.all():
            continue
        if not seen.any():
            raise ConfigError(f"{desc}: joint {BODY_JOINT_NAMES[j]} is missing (NaN) in every frame; "
                              f"nothing to fill it from")
        for c in range(3):
            X[:, j, c] = np.interp(t, t[seen], X[seen, j, c])
    return X.astype(np.float32), observed


class PriorTerms:
    """The loaded priors and the marker ids of one body model; makes stage 2's and stage 3's
    extra loss terms for `refine`."""

    def __init__(self, bm: BodyModel, cfg: MotionPriorConfig):
        cfg.check()
        self.bm, self.cfg = bm, cfg
        dev, dt = bm.J_template.device, bm.J_template.dtype
        self.smooth = None if not cfg.smooth else load_prior(cfg.smooth).to(device=dev, dtype=dt)
        self.infill = None if not cfg.infill else load_prior(cfg.infill).to(device=dev, dtype=dt)
        for name, p, kind in (("smooth", self.smooth, "smooth"), ("infill", self.infill, "infill")):
            if p is not None and p.kind != kind:
                raise ConfigError(f"motion_prior.{name}={getattr(cfg, name)}: a prior of kind {p.kind}, expected kind {kind}")
        self.owner = torch.as_tensor(mk.marker_joints(bm), device=dev)           # (81,) body joint per marker

    def smooth_only(self) -> "PriorTerms":
        """These terms without the infilling prior (stage 2 alone), sharing the loaded network."""
        t = copy.copy(self)
        t.infill, t.cfg = None, replace(self.cfg, infill=None)
        return t

    def markers(self, R: torch.Tensor, transl: torch.Tensor, betas: torch.Tensor, n: int) -> torch.Tensor:
        """The first n markers (T, n, 3) of the body posed by R (T, 22, 3, 3), transl (T, 3)."""
        return mk.posed_markers(self.bm, R, transl, betas, ids=list(range(n)))

    def smooth_term(self):
        """extra(R, transl, betas) -> w_smooth · latent smoothness of the body's markers."""
        n, w = self.smooth.num_markers, self.cfg.w_smooth
        return lambda R, transl, betas: w * smoothness_term(self.smooth, self.markers(R, transl, betas, n))

    def infill_targets(self, R, transl, betas, observed: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The infilling prior's markers (T, M, 3) for the body (R, transl, betas) whose joints
        were observed where `observed` (T, 22) says, and the mask (T, M) of the markers it
        filled (those moving with a joint that was missing)."""
        M = self.infill.num_markers
        with torch.no_grad():
            m = self.markers(R, transl, betas, M)                                # (T, M, 3)
            seen = observed[:, self.owner[:M]]                                   # (T, M)
            return infill(self.infill, m, seen), ~seen

    def infill_term(self, target: torch.Tensor, missing: torch.Tensor):
        """extra(...) -> w_infill · mean smoothed distance (in INFILL_SCALE units, squared at
        0) of the missing markers to the infilled `target` (T, M, 3)."""
        M, w = target.shape[1], self.cfg.w_infill
        count = missing.sum().clamp(min=1)
        eps = 1e-3

        def term(R, transl, betas):
            d2 = (self.markers(R, transl, betas, M) - target).square().sum(-1) / INFILL_SCALE ** 2   # (T, M)
            return w * INFILL_SCALE ** 2 * ((torch.sqrt(d2 + eps) - eps ** 0.5) * missing).sum() / count
        return term


def _rotmats(fit: FitResult, dtype, device) -> torch.Tensor:
    """(T, 22, 3, 3) body rotations of a fit."""
    aa = np.concatenate([fit.global_orient[:, None], fit.body_pose.reshape(-1, 21, 3)], 1)
    return axis_angle_to_matrix(torch.as_tensor(aa, dtype=dtype, device=device))


def fit_observed(joints, bm: BodyModel, mlp=None, *, priors: MotionPriorConfig = MotionPriorConfig(),
                 terms: PriorTerms | None = None, config: RefineConfig = RefineConfig(), contact=None,
                 device="cpu", fps: float = 30.0, desc: str = "joints") -> FitResult:
    """Fit SMPL-X to joints (T, 22, 3) where NaN marks a joint not observed at a frame: the
    gaps filled linearly and fitted (`fit_joints`), then the priors' stages. `per_frame_error`
    and `mpjpe` are measured on the observed joints only. terms: the loaded priors, to reuse
    them over samples (else loaded from `priors`)."""
    X, observed = fill_linear(joints, desc)
    fit = fit_joints(X, bm, mlp, config=config, contact=contact, device=device, fps=fps)
    if priors.any:
        terms = terms or PriorTerms(bm.to(device), priors)
        fit = _prior_stages(bm, X, observed, fit, terms, config, contact, fps)
    return _observed_errors(fit, joints, observed)


def _prior_stages(bm, X, observed, fit: FitResult, terms: PriorTerms, config: RefineConfig, contact, fps) -> FitResult:
    """Stage 2 (smoothness) and stage 3 (infilling) from the first fit."""
    dev, dt = bm.J_template.device, bm.J_template.dtype
    Xt = torch.as_tensor(X, dtype=dt, device=dev)
    obs = torch.as_tensor(observed, device=dev)
    ct = None if contact is None else torch.as_tensor(np.asarray(contact), dtype=torch.bool, device=dev)
    # The prior replaces the joint-acceleration term (LEMO's temporal fit has no other smoothing).
    cfg = replace(config, max_steps=terms.cfg.steps, w_smooth_joints=0.0 if terms.smooth else config.w_smooth_joints)
    R = _rotmats(fit, dt, dev)
    transl = torch.as_tensor(fit.transl, dtype=dt, device=dev)
    betas = torch.as_tensor(fit.betas, dtype=dt, device=dev)
    steps, hist = fit.steps, list(fit.history)
    smooth = terms.smooth_term() if terms.smooth else None
    if smooth is not None:
        R, transl, betas, s, h = refine(bm, Xt, R, betas, cfg, ct, transl_init=transl, fps=fps,
                                        target_weights=obs, extra=smooth, fixed_betas=True)
        steps, hist = steps + s, hist + h
    if terms.infill is not None:
        target, missing = terms.infill_targets(R, transl, betas, obs)
        inf = terms.infill_term(target, missing)
        extra = inf if smooth is None else (lambda *a: smooth(*a) + inf(*a))
        R, transl, betas, s, h = refine(bm, Xt, R, betas, cfg, ct, transl_init=transl, fps=fps,
                                        target_weights=obs, extra=extra, fixed_betas=True)
        steps, hist = steps + s, hist + h
    with torch.no_grad():
        J = bm.joints_from_rotmats(R, transl, betas)
        aa = matrix_to_axis_angle(R)
    T = J.shape[0]
    return replace(fit, global_orient=aa[:, 0].cpu().numpy(), body_pose=aa[:, 1:].reshape(T, 63).cpu().numpy(),
                   transl=transl.cpu().numpy(), betas=betas.cpu().numpy(), joints=J.cpu().numpy(),
                   steps=int(steps), history=hist)


def _observed_errors(fit: FitResult, joints, observed: np.ndarray) -> FitResult:
    """The fit's per-frame error (T,) and MPJPE over the observed joints only (a frame with
    none observed: NaN)."""
    d = np.linalg.norm(fit.joints - np.where(observed[..., None], joints, 0.0), axis=-1)      # (T, 22)
    n = observed.sum(1)
    per_frame = np.where(n > 0, (d * observed).sum(1) / np.maximum(n, 1), np.nan)
    mpjpe = float((d * observed).sum() / max(int(observed.sum()), 1))
    return replace(fit, per_frame_error=per_frame.astype(np.float32), mpjpe=mpjpe)

