"""Training-time geometry on the denoiser's own prediction, so that the network's joints are a
body before any clean-up makes them one (issue: the network's bone lengths vary by 6 % and its
planted feet slide at 0.47 m/s; the sampler's solve then creates the body rather than correct one).

The terms are measured on the window as sampling assembles it (x̂0 on the free entries, the
pinned values elsewhere), in metres, over the frames with any free entry:

* bone length: |‖ĵ_a − ĵ_parent(a)‖ − ‖j_a − j_parent(a)‖|, mean over bones and frames, against
  the clean window's own lengths (the data's body, whichever body that is);
* planted feet: the speed (m/s) of each stance joint between consecutive frames in which the
  clean window flags it planted (`Layout` stance channels), mean over such pairs. Needs stance
  channels (`window.contact_joints`). A network unsure of the step's phase meets it by moving
  its feet little everywhere: with it the demo network's toes travel half as far as its pelvis
  on the data's windows, without it they glide fast and low (docs/results.md, "The demo
  network does not step"), with or without the signal weighting below.
* facing: |â − a| (m) between the prediction's and the clean window's across vectors (left −
  right hip, left − right shoulder, `across_vectors`), mean over frames: which way the hips and
  the shoulders face, and how far apart they are. In the diffusion loss a turn of the body is
  a few centimetres of a few joints among ranges of metres: the demo network walked 14-21
  degrees off its direction of travel on the data's own windows, its hips folded in to 7-10 cm
  apart (the data's: 12). A unit-vector facing term turned the body but let the hips drift
  apart (15-20 cm); the vectors themselves hold both.
* foot height: |ŷ − y| (m) of the height of each foot joint (ankles and toes, `FOOT_JOINTS`),
  mean over them and the frames. The quality-size network trained with the facing or a
  heavier bone term shuffled: its toes moved 2.5-5 cm above the floor where the data's clear
  7-14 cm, and the skating metric counts such a swing as a foot sliding on the floor. The
  planted-feet term does not see a swing, and in the diffusion loss a few centimetres of foot
  height are little among ranges of metres. (Measured, with what it costs: docs/results.md.)
* foot offset: |(f̂ − p̂) − (f − p)| (m) along the floor, each foot joint f taken from its own
  pelvis p, mean over the foot joints and frames. With the planted-feet term a walking
  network's feet trail its pelvis further each frame (the demo's toes 0.5 m behind it at the
  window's last frame, the data's 0.1 m), and the next window, given those frames, puts them
  back under it in one step: the loop's seam. This term holds them under the pelvis, but the
  network then moves its whole body little within a window and jumps at the seam instead
  (docs/results.md), so no recipe uses it.
* facing goal: the facing term on the windows given a facing goal (`mask.p_facing`), over their
  last quarter of frames only: what the goal asks for. In the diffusion loss alone the
  quality-size network turned by 7 degrees (median) on validation windows where the data turns by
  89, and given the goal it turned little more (docs/results.md, "A facing goal as an angle").
  `squared` (`train.facing_goal_norm`) takes |â − a|² instead: the across vectors are linear in
  the joints, so its best prediction is the mean the diffusion loss asks of x̂0, where the
  l1 term's is a median. Measured, it makes the quality-size network shuffle as much as the l1
  term of the same pull (docs/results.md, "The facing goal's term, lighter and squared").
* pace: |Δp̂ − Δp| (m/s) between the prediction's and the clean window's pelvis steps along the
  floor, over consecutive frame pairs with a free frame (the step from the last pinned frame
  into the first drawn one included), mean over them. The demo-size network leapt 5-7 cm into
  the first frame it drew and ended each window at a third of the data's pace, on the data's
  windows as in the loop, whose walk then surged once per episode (docs/results.md, "The demo
  walks in surges"). In the diffusion loss the pelvis's step is two channels of many.

Weighting over noise levels (`train.geometry_weighting`): `uniform`, or `signal`: each window
weighted by ᾱ_t, the share of signal in its input. At high noise the best prediction is the
mean of many motions, whose bones are shorter and whose feet move less than any one motion's;
asking it for one body's geometry there pulls it away from the mean the diffusion loss wants.

Over training (`train.geometry_start`, `train.geometry_ramp`): every weight is 0 before step
`start` and grows linearly to full over the next `ramp` steps, so that the diffusion loss has
learnt the task (the goals) before the geometry asks for one body.
"""

from __future__ import annotations

import torch

from motiongen.data.representation import Layout
from motiongen.data.windows import NormStats
from motiongen.errors import ConfigError
from motiongen.skeleton import FOOT_JOINTS, LEFT_HIP, LEFT_SHOULDER, PELVIS, RIGHT_HIP, RIGHT_SHOULDER


class BodyLosses:
    """`terms(window, x0, free, t) -> {name: (weight, term)}` for `GaussianDiffusion.training_losses`:
    window, x0 (B, L, D) normalised, free (B, L, D) the entries the model predicts, t (B,) steps.
    noise_weights (T,): each window's weight by its diffusion step (None: all 1)."""

    def __init__(self, layout: Layout, stats: NormStats, parents, fps: float, w_bone: float, w_foot: float,
                 noise_weights: torch.Tensor | None = None, start: int = 0, ramp: int = 0, w_facing: float = 0.0,
                 w_foot_height: float = 0.0, w_foot_offset: float = 0.0, w_pace: float = 0.0,
                 w_facing_goal: float = 0.0, facing_goal_norm: str = "l1"):
        if w_foot > 0 and not layout.num_contacts:
            raise ConfigError("train.w_planted_feet needs stance channels (window.contact_joints)")
        self.layout, self.stats, self.fps = layout, stats, float(fps)
        self.child = [j for j, p in enumerate(parents) if p >= 0]
        self.parent = [parents[j] for j in self.child]
        self.w_bone, self.w_foot, self.w_facing = float(w_bone), float(w_foot), float(w_facing)
        self.w_foot_height = float(w_foot_height)
        self.w_foot_offset = float(w_foot_offset)
        self.w_pace = float(w_pace)
        self.w_facing_goal = float(w_facing_goal)
        self.facing_goal_squared = facing_goal_norm == "squared"
        self.facing_given: torch.Tensor | None = None   # (B,) bool: the batch's facing goals, set by the loop
        self.noise_weights = noise_weights        # (T,) per diffusion step, or None: uniform
        self.start, self.ramp = int(start), int(ramp)
        self.step = 0                             # the training step, set by the loop before each step

    def scale(self) -> float:
        """The share of the full weights at `self.step`: 0 before `start`, then linear over `ramp` steps."""
        if self.step < self.start:
            return 0.0
        return min(1.0, (self.step - self.start + 1) / self.ramp) if self.ramp > 0 else 1.0

    def __call__(self, window: torch.Tensor, x0: torch.Tensor, free: torch.Tensor, t: torch.Tensor) -> dict:
        if self.scale() == 0:
            # Weight 0 (before `start`): the terms are only logged, so no graph is kept for a
            # backward pass that would add nothing (it was a third of a tiny model's step).
            with torch.no_grad():
                return self._terms(window, x0, free, t)
        return self._terms(window, x0, free, t)

    def _terms(self, window: torch.Tensor, x0: torch.Tensor, free: torch.Tensor, t: torch.Tensor) -> dict:
        j_hat, _ = self.layout.decode(self.stats.denormalize(window))                    # (B, L, J, 3)
        j, planted = self.layout.decode(self.stats.denormalize(x0))                      # (B, L, J, 3), (B, L, C)
        frames = free.amax(-1)                                                            # (B, L) any free entry
        if self.noise_weights is not None:
            frames = frames * self.noise_weights.to(frames)[t][:, None]                   # (B, L)
        out, scale = {}, self.scale()
        if self.w_bone > 0:
            out["bone_length"] = (scale * self.w_bone, self._bones(j_hat, j, frames))
        if self.w_foot > 0:
            out["planted_feet"] = (scale * self.w_foot, self._feet(j_hat, planted, frames))
        if self.w_facing > 0 or self.w_facing_goal > 0:
            facing_diff = across_vectors(j_hat) - across_vectors(j)                        # (B, L, 6)
            facing_err = facing_diff.norm(dim=-1)                                           # (B, L)
        if self.w_facing > 0:
            out["facing"] = (scale * self.w_facing, frame_mean(facing_err, frames))
        if self.w_facing_goal > 0 and self.facing_given is not None:
            L = frames.shape[1]
            last = (torch.arange(L, device=frames.device) >= L - max(1, L // 4)).to(frames)   # (L,)
            w = frames * last[None] * self.facing_given.to(frames)[:, None]                   # (B, L)
            err = facing_diff.square().sum(-1) if self.facing_goal_squared else facing_err    # (B, L) m² or m
            out["facing_goal"] = (scale * self.w_facing_goal, frame_mean(err, w))
        if self.w_foot_height > 0:
            feet = list(FOOT_JOINTS)
            err = (j_hat[..., feet, 1] - j[..., feet, 1]).abs().mean(-1)                   # (B, L)
            out["foot_height"] = (scale * self.w_foot_height, frame_mean(err, frames))
        if self.w_foot_offset > 0:
            out["foot_offset"] = (scale * self.w_foot_offset, frame_mean(foot_offsets(j_hat, j), frames))
        if self.w_pace > 0:
            err = (pelvis_steps(j_hat) - pelvis_steps(j)).norm(dim=-1) * self.fps               # (B, L-1)
            w = pair_weights(frames)                                                         # (B, L-1)
            out["pace"] = (scale * self.w_pace, (err * w).sum() / w.sum().clamp(min=1e-8))
        return out

    def _bones(self, j_hat, j, frames):
        length = lambda x: (x[..., self.child, :] - x[..., self.parent, :]).norm(dim=-1)  # noqa: E731  (B, L, nb)
        err = (length(j_hat) - length(j)).abs().mean(-1)                                  # (B, L)
        return frame_mean(err, frames)

    def _feet(self, j_hat, planted, frames):
        feet = j_hat[..., list(self.layout.contact_joints), :]                            # (B, L, C, 3)
        speed = torch.diff(feet, dim=1).norm(dim=-1) * self.fps                           # (B, L-1, C)
        both = (planted[:, 1:] & planted[:, :-1]).to(speed.dtype)                          # (B, L-1, C)
        w = both * pair_weights(frames)[..., None]
        return (speed * w).sum() / w.sum().clamp(min=1e-8)


def across_vectors(joints: torch.Tensor) -> torch.Tensor:
    """(..., 6) left − right hip and left − right shoulder of bodies joints (..., J, 3): which way
    the pelvis and the shoulders face (`geometry.facing_yaw` reads the hips' one), and how wide."""
    return torch.cat([joints[..., LEFT_HIP, :] - joints[..., RIGHT_HIP, :],
                      joints[..., LEFT_SHOULDER, :] - joints[..., RIGHT_SHOULDER, :]], -1)


def foot_offsets(j_hat: torch.Tensor, j: torch.Tensor) -> torch.Tensor:
    """(B, L) mean over the foot joints of how far (m) the prediction's foot is from the clean
    window's along the floor, each taken from its own pelvis: bodies j_hat, j (B, L, J, 3)."""
    feet = list(FOOT_JOINTS)
    off_hat, off = ((x[..., feet, :] - x[..., PELVIS:PELVIS + 1, :])[..., [0, 2]] for x in (j_hat, j))   # (B, L, F, 2)
    return (off_hat - off).norm(dim=-1).mean(-1)


def pelvis_steps(joints: torch.Tensor) -> torch.Tensor:
    """(B, L-1, 2) the pelvis's steps along the floor (x, z) between consecutive frames of bodies (B, L, J, 3)."""
    return torch.diff(joints[..., PELVIS, :][..., [0, 2]], dim=1)


def pair_weights(frames: torch.Tensor) -> torch.Tensor:
    """(B, L-1) the weight of each pair of consecutive frames: the larger of its two frames'
    weights frames (B, L), so a step counts when either end is a free frame."""
    return torch.maximum(frames[:, 1:], frames[:, :-1])


def frame_mean(err: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
    """Mean of per-frame errors err (B, L) weighted by frames (B, L); 0 when no frame counts."""
    return (err * frames).sum() / frames.sum().clamp(min=1e-8)
