"""One body per generated motion.

A diffusion model predicts joint positions, which need not belong to any body: bones stretch
from frame to frame. `MotionBody` holds one shape (SMPL-X betas, one per sample) for a whole
motion and turns predicted joints into that body:

* `MotionBody.estimate` fits the shape once, to the first window the model produces;
* `project` maps every sampled window onto the body (swing correction down the kinematic
  tree, `fit.analytic_init`, twist carried over from the previous pose): bone lengths are the
  body's by construction, whatever the network predicted, so the next episode always continues
  from a rigid body;
* `solve` is the final pass over the whole motion at the output rate: the same refinement as
  `motiongen.body.fit` (joint L2, smoothness, rotation prior) with foot locking — every span a
  foot joint is predicted planted, it is held in one place at the height the network predicted
  for it (`fit.lock_loss`), and between
  those spans a foot is not pulled below its predicted height (swing clearance);
  `solve_joint_space` is the same pass in closed form (`loop.solve=joint-space`,
  `joint_solve.py`): about 20 times faster, with the trade-off docs/sampling.md describes.

Joint sets: the 22 SMPL-X body joints, plus the index1 finger joints where the model has them
(posed rigidly from the wrist).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d
from scipy.optimize import least_squares

from motiongen.body.analytic import posed_joints, swing
from motiongen.body.fit import FitResult, RefineConfig, refine
from motiongen.body.joint_solve import follow_locks, held_limbs, into_reach, solve_joints
from motiongen.body.limbs import limb_lengths, place_limbs
from motiongen.body.model import BodyModel, BodyParams, forward_kinematics
from motiongen.body.rotations import matrix_to_axis_angle
from motiongen.metrics import bone_lengths
from motiongen.skeleton import EXTRA_JOINTS, NUM_BODY_JOINTS, JointSet

# Shape coefficients are ~N(0, 1) over real people: beyond 3 sigma is not a body, whatever an
# untrained network's first window says. The prior (metres of bone length per unit beta) only
# decides directions the bone lengths leave open.
BETA_LIMIT = 3.0
SHAPE_PRIOR = 1e-3
# Refinement of the final solve: a planted foot (w_contact) outweighs several cm of disagreement
# with the predicted joints, and joint acceleration (w_smooth_joints) keeps the moments a foot
# is put down or lifted from jerking; joint centres stay 0.3 cm above the floor (y = 0, the
# scenes' convention; a planted toe joint of the data sits 2 cm up). The sampler sets
# w_smooth_joints by the model's frame rate (`sampling.assemble.solve_smoothness_for_rate`).
# Swing clearance (w_clearance) keeps an unplanted foot joint from being pulled below the
# predicted height: strong smoothing flattens a swing into a low, fast foot — foot skating.
# 300 removed most of that skating at equal PSKL; 30 did half as much and 3000 cost PSKL
# (the 4-scene check in docs/results.md).
SOFT_REACH = 0.03       # m: the limbs' soft IK in the joint-space solve (limbs.two_bone)
TRUNK_SHIFT_SMOOTHING = 3.0   # frames: sigma of that trunk shift over time
BEND_SMOOTHING = 2.0    # frames: sigma over which the limbs' bending planes are smoothed
SOLVE_CONFIG = RefineConfig(max_steps=80, w_contact=100.0, w_reach=30.0, w_smooth_joints=5.0, w_floor=1000.0, floor_y=0.003,
                            w_clearance=300.0, optimize_betas=False, w_prior=1e-3, threads=1)


@dataclass
class BodyMotion(BodyParams):
    """A motion of one body: SMPL-X parameters and the joints they pose."""

    joints: np.ndarray          # (T, J, 3) float32, the model's joint set
    rotmats: np.ndarray         # (T, 22, 3, 3) local rotations

    def as_fit(self, joints: np.ndarray):
        """A `FitResult` (for `fit.save_amass_npz`) of this body against `joints` (T, J, 3): the
        output motion is this body's own joints, so the per-frame error is what it is (~0)."""
        err = np.linalg.norm(self.joints[:, :NUM_BODY_JOINTS] - joints[:, :NUM_BODY_JOINTS], axis=-1).mean(-1)
        return FitResult(self.global_orient, self.body_pose, self.transl, self.betas,
                         self.joints[:, :NUM_BODY_JOINTS], err, None, float(err.mean()), float(err.mean()),
                         0, 0.0, "motion body")


class MotionBody:
    """S bodies (one per sample) of a body model, posed by local rotations and translations."""

    def __init__(self, bm: BodyModel, joint_set: JointSet, betas: torch.Tensor):
        self.bm, self.joint_set = bm, joint_set
        self.betas = torch.as_tensor(betas, dtype=bm.J_template.dtype).reshape(-1, bm.num_betas)   # (S, nβ)
        rest_all = bm.rest_joints(self.betas, body_only=False)                                    # (S, 55, 3)
        self.rest = rest_all[:, :NUM_BODY_JOINTS]                                                  # (S, 22, 3)
        # Extra joints ride rigidly on their parent body joint: (name index, parent, offset (S, 3)).
        self.extras = []
        for k, name in enumerate(joint_set.names[NUM_BODY_JOINTS:], NUM_BODY_JOINTS):
            full, parent = EXTRA_JOINTS[name]
            p = joint_set.index(parent)
            self.extras.append((k, p, rest_all[:, full] - rest_all[:, p]))

    @property
    def num_samples(self) -> int:
        return self.betas.shape[0]

    @classmethod
    def estimate(cls, bm: BodyModel, joint_set: JointSet, window: np.ndarray) -> "MotionBody":
        """Shape fitted to a window of predicted joints (S, L, J, 3), per sample: the betas whose
        rest skeleton has the window's bone lengths (median over its frames; least squares with
        a weak pull towards the mean shape). Bone lengths are what a shape fixes; the pose is the
        projection's business, so this is a 10-parameter problem, solved in milliseconds."""
        parents = bm.parents
        kids = np.array([c for c, p in enumerate(parents) if p >= 0])
        par = np.array([parents[c] for c in kids])
        J0 = bm.J_template[:NUM_BODY_JOINTS].double().numpy()                                   # (22, 3)
        Jd = bm.J_dirs[:NUM_BODY_JOINTS].double().numpy()                                       # (22, 3, nβ)
        B0, Bd = J0[kids] - J0[par], Jd[kids] - Jd[par]                                         # (21, 3), (21, 3, nβ)
        betas = []
        for w in np.asarray(window, np.float64):
            target = np.median(bone_lengths(w[:, :NUM_BODY_JOINTS], parents), axis=0)          # (21,)

            def residual(b):
                return np.concatenate([np.linalg.norm(B0 + Bd @ b, axis=-1) - target, SHAPE_PRIOR * b])

            sol = least_squares(residual, np.zeros(bm.num_betas), bounds=(-BETA_LIMIT, BETA_LIMIT))
            betas.append(sol.x)
        return cls(bm, joint_set, torch.as_tensor(np.stack(betas)))

    def pose(self, rotmats: torch.Tensor, transl: torch.Tensor, sample: int | slice = slice(None)) -> torch.Tensor:
        """Joints (S, T, J, 3) of local rotations (S, T, 22, 3, 3) and translations (S, T, 3)
        (`sample` picks the bodies when S is a subset)."""
        rest = self.rest[sample]
        rest = rest[:, None] if rest.dim() == 3 else rest[None, None]
        P, G = forward_kinematics(rotmats, rest, self.bm.parents, self.bm._levels)          # (S, T, 22, 3)
        out = [P]
        for _, p, off in self.extras:
            o = off[sample]
            o = o[:, None] if o.dim() == 2 else o[None, None]
            out.append((P[..., p, :] + (G[..., p, :, :] @ o[..., None])[..., 0])[..., None, :])
        return torch.cat(out, -2) + transl[..., None, :]

    def project(self, joints: np.ndarray, rot_hint: torch.Tensor | None = None):
        """Predicted joints (S, T, J, 3) -> (joints on the body (S, T, J, 3) float64, local
        rotations (S, T, 22, 3, 3), translations (S, T, 3)). Lengths are the body's; the
        pelvis stays where it was predicted, the trunk follows the predicted bone directions and
        the ankles and wrists the predicted positions (two-bone IK, `limbs.place_limbs`).
        rot_hint (S, 22, 3, 3): the last pose, whose twist (invisible in joint positions)
        carries over."""
        S, T = joints.shape[:2]
        J22 = NUM_BODY_JOINTS
        X = torch.as_tensor(np.asarray(joints[..., :J22, :]), dtype=self.rest.dtype).reshape(S * T, J22, 3)
        rest = self.rest[:, None].expand(S, T, J22, 3).reshape(S * T, J22, 3)
        hint = None if rot_hint is None else rot_hint[:, None].expand(S, T, J22, 3, 3).reshape(-1, J22, 3, 3)
        R, P = self._rotations(X, rest, hint)
        R = R.reshape(S, T, J22, 3, 3)
        transl = X.reshape(S, T, J22, 3)[:, :, 0] - self.rest[:, None, 0]                       # (S, T, 3)
        if P is None:
            return self.pose(R, transl).double().numpy(), R, transl
        # The joints as the last swing placed them (float64, as `pose` would give them up to
        # float32 rounding), without running forward kinematics again.
        return P.reshape(S, T, J22, 3) + transl.double().numpy()[:, :, None], R, transl

    def _rotations(self, X: torch.Tensor, rest: torch.Tensor, hint: torch.Tensor | None,
                   bend: torch.Tensor | None = None, soft: float = 0.0):
        """Local rotations (N, 22, 3, 3) putting rest joints (N, 22, 3) on joints X (N, 22, 3)
        (`project`): bone directions, then the limbs' ends by two-bone IK (bending as `bend`
        (N, 22, 3) bends, or X); twist from hint. Also their joints (N, 22, 3) float64 numpy,
        root at rest[0], or None for a joint set with extra joints (those need `pose`). The
        steps between the two swings stay in float64 numpy (`analytic.swing`,
        `analytic.posed_joints`): on a window's few dozen frames the cost is the number of small
        operations, which torch makes several times dearer."""
        rest_np = rest.double().numpy()
        X_np = X.detach().double().numpy()
        R, G = swing(X_np, rest_np, None if hint is None else hint.double().numpy())
        P = torch.from_numpy(posed_joints(G, rest_np) + (X_np[:, :1] - rest_np[:, :1])).to(X.dtype)
        P = place_limbs(P, X, rest, bend, soft)                                                # (N, 22, 3)
        R, G = swing(P.double().numpy(), rest_np, R)                                           # exact: lengths agree
        R = torch.from_numpy(R).to(X.dtype)
        return R, None if self.extras else posed_joints(G, rest_np)

    def solve_joint_space(self, sample: int, joints: np.ndarray, rot_hint: torch.Tensor,
                          planted: np.ndarray | None = None, contact_joints=(), cfg: RefineConfig | None = None,
                          reach=None, planted_heights: np.ndarray | None = None) -> BodyMotion:
        """The final pass for one sample as `solve`, in closed form: the objective's joint
        terms minimised exactly in joint space (`joint_solve.solve_joints`), then put on the
        body (`project`'s analytic fit, frame by frame; twist from rot_hint (T, 22, 3, 3)).
        About 20 times faster than `solve`; the figures of both: docs/results.md."""
        cfg = cfg if cfg is not None else SOLVE_CONFIG
        X = np.asarray(joints[:, :NUM_BODY_JOINTS], np.float64)
        Y = solve_joints(X, cfg, planted, contact_joints, reach, planted_heights)               # (T, 22, 3)
        # the trunk follows the held feet as the rigid legs of `solve` carry it (follow_locks)
        Y = follow_locks(Y, X, planted if cfg.w_contact else None, contact_joints, TRUNK_SHIFT_SMOOTHING)
        T = Y.shape[0]
        lengths = limb_lengths(self.rest[sample].double()).numpy()                              # (4,)
        Y = into_reach(Y, lengths, held_limbs(T, reach), TRUNK_SHIFT_SMOOTHING)
        Yt = torch.as_tensor(Y, dtype=self.rest.dtype)
        bend = torch.as_tensor(gaussian_filter1d(X, BEND_SMOOTHING, axis=0, mode="nearest"), dtype=Yt.dtype)
        R, P = self._rotations(Yt, self.rest[sample].expand(T, NUM_BODY_JOINTS, 3), rot_hint.to(Yt.dtype), bend,
                               SOFT_REACH)
        transl = Yt[:, 0] - self.rest[sample, 0]
        return self._motion(sample, R, transl, None if P is None else P + transl.double().numpy()[:, None])

    def solve(self, sample: int, joints: np.ndarray, rot_init: torch.Tensor, planted: np.ndarray | None = None,
              contact_joints=(), cfg: RefineConfig | None = None, reach=None,
              planted_heights: np.ndarray | None = None) -> BodyMotion:
        """The final pass for one sample: joints (T, J, 3) to follow, local rotations (T, 22, 3, 3)
        to start from, planted (T, C) bool for `contact_joints` (None or cfg.w_contact = 0: no
        locking), reach = (frames (N,), body joints (N,), points (N, 3), weights (N,)) or None: a
        hand to put on an object, planted_heights (T, C) or None: the heights a planted span is
        held at (`fit.refine`; None: those of `joints`). Returns the body's motion."""
        cfg = cfg if cfg is not None else SOLVE_CONFIG
        X = torch.as_tensor(np.asarray(joints[:, :NUM_BODY_JOINTS], np.float64), dtype=self.rest.dtype)
        betas = self.betas[sample]
        if planted is not None and cfg.w_contact and len(contact_joints):
            contact = torch.as_tensor(np.asarray(planted, bool))
        else:
            contact, cfg = None, replace(cfg, w_contact=0.0)
        if reach is not None:
            f, j, p, w = reach
            reach = (torch.as_tensor(f, dtype=torch.long), torch.as_tensor(j, dtype=torch.long),
                     torch.as_tensor(p, dtype=X.dtype), torch.as_tensor(w, dtype=X.dtype))
        heights = None if planted_heights is None or contact is None else torch.as_tensor(planted_heights, dtype=X.dtype)
        R, transl, _, _, _ = refine(self.bm, X, rot_init.to(X.dtype), betas, cfg, contact, fixed_betas=True,
                                    contact_joints=tuple(contact_joints), reach=reach, planted_heights=heights)
        return self._motion(sample, R, transl)

    def _motion(self, sample: int, R: torch.Tensor, transl: torch.Tensor, joints: np.ndarray | None = None) -> BodyMotion:
        """The BodyMotion of sample's body posed by local rotations (T, 22, 3, 3), translations
        (T, 3); joints (T, J, 3): those rotations' joints where the caller has them already."""
        with torch.no_grad():
            if joints is None:
                joints = self.pose(R[None], transl[None], slice(sample, sample + 1))[0]          # (T, J, 3)
            aa = matrix_to_axis_angle(R)                                                       # (T, 22, 3)
        T = R.shape[0]
        return BodyMotion(global_orient=aa[:, 0].numpy(), body_pose=aa[:, 1:].reshape(T, 63).numpy(),
                          transl=transl.numpy(), betas=self.betas[sample].numpy(), joints=np.asarray(joints, np.float32),
                          rotmats=R.numpy())
