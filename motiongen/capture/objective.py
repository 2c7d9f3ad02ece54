"""The multi-view fitting objective of the multi-view capture paper (A1), term by term:

    λ3D·L3D + λ2D·L2D + λz·Lz + λβ·Lβ + λsmooth·Lsmooth       (minimised; the paper's "arg max"
                                                              is a typo for arg min)
    L3D = 1/(TK) Σ_t Σ_k w_tk ‖x_tk − x̂_tk‖                   Euclidean, not squared
    L2D = 1/(TKC) Σ_t Σ_k Σ_c w_tkc φ(‖x_tkc − Π_c(x̂_tk)‖; ρ_tkc),  φ(r; ρ) = r² / (r² + ρ²)
    Lz  = 1/T Σ_t ‖z_t‖²,    Lβ = ‖β‖²
    Lsmooth = 1/((T−2)K) Σ ‖x̂_t − 2x̂_{t+1} + x̂_{t+2}‖²
            + 1/((T−2)J) Σ ‖θ_t − 2θ_{t+1} + θ_{t+2}‖²

Our readings of what the paper leaves open (docs/capture.md gives the reasons, docs/results.md
the figures):
- w are the detections' confidences (0 = missed / not triangulated); K counts the keypoints
  the layout has, so a missing detection costs nothing rather than changing the scale.
- The paper's L3D also sums over cameras c although nothing in it depends on c: a constant
  factor C, which we drop (it would only rescale λ3D).
- Units: lengths in `length_unit` metres (default 0.02). The paper's weights fix the balance
  between terms only once units are chosen: L3D scales as 1/unit, Lsmooth's keypoint part as
  1/unit², Lz not at all, so a large unit hands the fit to the pose prior and a small one to
  the smoothness term. docs/results.md gives the measurements behind 2 cm.
- ρ is given as a length at the subject (`rho`, metres) and turned into pixels per camera
  and keypoint: ρ_tkc = ρ·f_c / depth_tkc (f_c the focal length in pixels). φ is then
  the paper's φ in pixels, and a near camera (a big person in the image) and a far one get the
  same tolerance in space — what EasyMocap gets by dividing residuals by the person's
  bounding-box size.
- ‖·‖ in L3D is smoothed as sqrt(d² + ε²) − ε (ε = `EPS` units) so that gradients exist at 0.
- θ in the smoothness term: the 21 decoded axis-angle body rotations, and for the root
  (J = 22 in all) ½‖R_t − 2R_{t+1} + R_{t+2}‖²_F, which equals the axis-angle form to first
  order and has no wrap-around at π.
- `robust="l2"` replaces φ by r²/ρ² (its small-residual limit: same weight on inliers), the
  plain-L2 baseline the robust term is measured against.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

EPS = 1e-3


@dataclass(frozen=True)
class StageWeights:
    w3d: float
    w2d: float
    smooth: float
    z: float
    betas: float


# The multi-view capture paper, A1. β is frozen after stage 1, so λβ has no effect in stages 2 and 3.
SEED_STAGES = {1: StageWeights(w3d=5.0, w2d=0.0, smooth=0.1, z=0.005, betas=0.04),
               2: StageWeights(w3d=5.0, w2d=0.0, smooth=2.5, z=0.1, betas=0.04),
               3: StageWeights(w3d=1.6, w2d=0.5, smooth=10.0, z=0.01, betas=0.04)}


@dataclass
class Targets:
    """One chunk's observations (torch tensors) and the fixed frames before it."""

    x3d: torch.Tensor              # (T, K, 3) metres
    w3d: torch.Tensor              # (T, K)
    uv: torch.Tensor | None        # (T, K, C, 2) pixels
    w2d: torch.Tensor | None       # (T, K, C)
    keypoints: torch.Tensor | None # (K,) long: the joints the layout observes (None: all 22)
    focal: torch.Tensor | None = None   # (C,) focal lengths, pixels
    context: tuple | None = None   # (J (2, 22, 3), θ (2, 21, 3), R_root (2, 3, 3)) of the previous frames


def geman_mcclure(r2: torch.Tensor, rho: float) -> torch.Tensor:
    """φ(r; ρ) = r² / (r² + ρ²) of squared residuals r2."""
    return r2 / (r2 + rho * rho)


def terms(J: torch.Tensor, theta: torch.Tensor, R_root: torch.Tensor, z: torch.Tensor, betas: torch.Tensor,
          tg: Targets, project, *, length_unit: float, rho: float, robust: str = "gm",
          need_2d: bool = True) -> dict[str, torch.Tensor]:
    """The five terms (unweighted) of one chunk. J (T, 22, 3) fitted joints, theta (T, 21, 3)
    decoded axis-angle, R_root (T, 3, 3), z (T, d), betas (nβ,); project: world points
    (..., 3) -> (pixels (..., C, 2), depth (..., C)); length_unit: metres per unit of L3D and
    Lsmooth; rho: metres at the subject."""
    T = J.shape[0]
    kp = tg.keypoints

    def observed(X):                                                        # (T, 22, 3) -> (T, K, 3)
        return X if kp is None else X[:, kp]

    Jk = observed(J)
    K = max(Jk.shape[1], 1)
    d2 = (Jk - tg.x3d).square().sum(-1) / length_unit ** 2                  # (T, K) units²
    dist = torch.sqrt(d2 + EPS * EPS) - EPS
    out = {"L3D": (tg.w3d * dist).sum() / (T * K)}
    if need_2d and tg.uv is not None:
        uv, depth = project(Jk)                                             # (T, K, C, 2), (T, K, C)
        r2 = (uv - tg.uv).square().sum(-1)                                  # (T, K, C) px²
        # (ρ_px)² = (ρ f / depth)²: dividing r² by (f / depth)² instead leaves φ unchanged.
        r2 = r2 * (depth.detach().clamp(min=1e-3) / tg.focal).square()       # metres² at the subject
        phi = geman_mcclure(r2, rho) if robust == "gm" else r2 / (rho * rho)
        w = tg.w2d * (depth > 0)
        out["L2D"] = (w * phi).sum() / (T * K * uv.shape[-2])
    else:
        out["L2D"] = J.new_zeros(())
    out["Lz"] = z.square().sum(-1).mean()
    out["Lbeta"] = betas.square().sum()
    if tg.context is not None:
        Jc, thc, Rc = tg.context
        Jk, theta, R_root = torch.cat([observed(Jc), Jk]), torch.cat([thc, theta]), torch.cat([Rc, R_root])
    if Jk.shape[0] >= 3:
        n = Jk.shape[0] - 2
        acc = (Jk[2:] - 2 * Jk[1:-1] + Jk[:-2]).square().sum(-1).sum() / length_unit ** 2
        ang = (theta[2:] - 2 * theta[1:-1] + theta[:-2]).square().sum()
        ang = ang + 0.5 * (R_root[2:] - 2 * R_root[1:-1] + R_root[:-2]).square().sum()
        out["Lsmooth"] = acc / (n * K) + ang / (n * (theta.shape[1] + 1))
    else:
        out["Lsmooth"] = J.new_zeros(())
    return out


# Terms whose weights are inside them (LEMO's motion priors, `MultiviewFitter.motion_terms`).
PRIOR_TERMS = ("Lprior", "Linfill")


def total(t: dict[str, torch.Tensor], w: StageWeights) -> torch.Tensor:
    out = w.w3d * t["L3D"] + w.w2d * t["L2D"] + w.z * t["Lz"] + w.betas * t["Lbeta"] + w.smooth * t["Lsmooth"]
    for k in PRIOR_TERMS:
        if k in t:
            out = out + t[k]
    return out
