"""From model-rate episodes to the output motion: resample to the output rate, then the final
body solve (one body, planted feet locked; `motiongen.body.solve`)."""

from __future__ import annotations

import functools
import math
from dataclasses import replace

import numpy as np
import torch
from scipy.interpolate import CubicSpline

from motiongen.body.analytic import analytic_init
from motiongen.body.rotations import matrix_to_quaternion, quaternion_to_matrix
from motiongen.body.solve import SOLVE_CONFIG
from motiongen.checks import require_choice
from motiongen.forked import forked_map
from motiongen.skeleton import NUM_BODY_JOINTS
from motiongen.spans import clean_plants


def blend_seam(window: np.ndarray, k: int, frames: int) -> np.ndarray:
    """Carry the pinned frames' velocity into the free ones: (S, L, J, 3) -> same, new array.

    window: frames 0..k-1 pinned (the previous episode's last frames), k.. the network's. The
    velocity jump at the seam, δ = (x[k] - x[k-1]) - (x[k-1] - x[k-2]) per joint, is taken out
    of frame k and faded over the next `frames` free frames with a raised cosine (weights 1 ..
    0), so frame k continues the pinned frames at constant velocity and the correction's own
    acceleration stays ~δ π² / (2 frames²) per frame². The network places the first free frame
    a few centimetres off the continuation of the pinned ones, far above the data's own
    acceleration there (docs/quality.md); without this every episode seam is a jolt.
    k < 2 (no velocity to carry) or frames < 1 leaves the window as it is."""
    out = np.array(window, copy=True)
    n = min(int(frames), out.shape[1] - k)
    if k < 2 or n < 1:
        return out
    delta = (out[:, k] - out[:, k - 1]) - (out[:, k - 1] - out[:, k - 2])                # (S, J, 3)
    w = 0.5 * (1.0 + np.cos(np.pi * np.arange(n) / n))                                     # (n,) 1 -> ~0
    out[:, k:k + n] -= w[None, :, None, None] * delta[:, None]
    return out


# Frame rate from which a model's frame-level jitter (at 5-7.5 Hz) sits above the body's steps;
# below it (10 fps: 3-5 Hz) the jitter shares the legs' swing band (docs/quality.md).
SMOOTHABLE_FPS = 15.0


def solve_smoothness_for_rate(model_fps: float) -> float:
    """`loop.solve_smoothness` = None: the final solve's joint-acceleration weight. At
    SMOOTHABLE_FPS or more a strong weight (200) takes the network's jitter out (motion
    spectrum and foot skating both improve with the weight). Below it, 50: a 10 fps model's
    spectrum lacks the data's 8-15 Hz power (its windows stop at 5 Hz), and a weaker weight lets
    the solve's foot lock and swing clearance put some back. The swing clearance keeps the
    skating down at these weights (without it, a strong weight lowers the swinging foot). The
    solve runs a fixed 80 L-BFGS steps and is not converged at any of these weights: it filters
    the high frequencies first, which is what this weight is for, at a cost that does not grow
    with it. The figures behind both values: docs/results.md."""
    return 200.0 if model_fps >= SMOOTHABLE_FPS - 1e-6 else 50.0


def clearance_for_rate(model_fps: float) -> float:
    """The final solve's swing-clearance weight (`loop.swing_clearance` on): how hard an
    unplanted foot joint is held at or above its predicted (lifted) height. At SMOOTHABLE_FPS or
    more, the solve's own 300 (`body.solve.SOLVE_CONFIG`): its strong acceleration weight there
    would flatten each swing into a low, fast foot. Below it, 10: under the weaker weight of a
    10 fps model the swings keep most of their height by themselves, and a hard hold adds a
    kick at every lift-off and landing that the data's feet do not have (its spectrum and jerk
    move away from the data's, docs/results.md "Swing clearance by the model's rate")."""
    return SOLVE_CONFIG.w_clearance if model_fps >= SMOOTHABLE_FPS - 1e-6 else 10.0


def smoothing_sigma(smooth: float | None, model_fps: float) -> float:
    """The Gaussian sigma (output frames) that `loop.smooth` asks for: `smoothing_for_rate` when
    unset, else its own value (0: off)."""
    return smoothing_for_rate(model_fps) if smooth is None else float(smooth)


def smoothing_for_rate(model_fps: float) -> float:
    """`loop.smooth` = None: the Gaussian sigma (output frames) over the non-foot joints before
    the final solve. At SMOOTHABLE_FPS or more, 2: the network's frame-level jitter lies above
    the body's own motion and smoothing it out brings the output's spectrum closer to the
    data's. Below, off: a 10 fps model's jitter shares the legs' band, and on the validation
    scenes the quality recipe's PSKL is lowest without smoothing (docs/results.md, "Smoothing at
    10 fps, again")."""
    return 2.0 if model_fps >= SMOOTHABLE_FPS - 1e-6 else 0.0


# The joint-space solve (`loop.solve=joint-space`) reaches the minimum the L-BFGS solve stops
# short of, so the same weight filters far more: 200 leaves nothing of the body's 2-5 Hz steps.
# Its weights, chosen on the validation scenes (docs/results.md): the body's acceleration 10
# (half power at about 3 Hz), the feet's 400 (what keeps them from skating).
JOINT_SPACE_SMOOTHING = 10.0
JOINT_SPACE_FEET_SMOOTHING = 400.0


# `loop.solve=refined`: L-BFGS steps from the joint-space solve's result. 80 steps from the
# analytic start stop short of the minimum with the pelvis shaking at 4-8 Hz (twice the data's
# acceleration; the walk reads 27° off its travel where its facing is the network's); from the
# joint-space result 40 steps end nearer it (docs/results.md, "The final solve from the
# joint-space result").
REFINED_STEPS = 40


def solve_weights(method: str, model_fps: float, smoothness: float | None) -> dict:
    """The final solve's acceleration weights for `method` (RefineConfig fields): smoothness
    (`loop.solve_smoothness`) the body's, None: by method and model rate. `refined`: those of
    its L-BFGS steps (its joint-space start takes `joint-space`'s by model rate)."""
    if method == "joint-space":
        w = JOINT_SPACE_SMOOTHING if smoothness is None else float(smoothness)
        return {"w_smooth_joints": w, "w_smooth_contact": max(w, JOINT_SPACE_FEET_SMOOTHING)}
    return {"w_smooth_joints": solve_smoothness_for_rate(model_fps) if smoothness is None else float(smoothness)}


def output_times(num_model_frames: int, model_fps: float, out_fps: float) -> tuple[np.ndarray, np.ndarray]:
    """(t_out (T,) seconds, nearest model frame (T,) int) of the output frames."""
    T = int(math.floor((num_model_frames - 1) * out_fps / model_fps + 1e-6)) + 1
    t_out = np.arange(T) / out_fps
    near = np.minimum(np.round(t_out * model_fps).astype(np.int64), num_model_frames - 1)
    return t_out, near


def resample(x: np.ndarray, model_fps: float, out_fps: float) -> np.ndarray:
    """(S, Tm, ...) at model_fps -> (S, T, ...) at out_fps, cubic spline over the whole motion
    (episode seams are continuous already: transition frames are copies)."""
    Tm = x.shape[1]
    t_out, _ = output_times(Tm, model_fps, out_fps)
    if Tm < 2 or abs(out_fps / model_fps - 1) < 1e-9:
        return x[:, : len(t_out)].copy()
    return CubicSpline(np.arange(Tm) / model_fps, x, axis=1)(t_out)


def planted_at_output(stance: np.ndarray, joints: np.ndarray, contact_joints, model_fps: float, out_fps: float,
                      min_frames: int = 5, min_swing: int = 8, same_spot: float = 0.05) -> np.ndarray:
    """Feet to lock, (S, T, C) bool at the output rate, from the predicted stance channels
    (S, Tm, C) at the model rate (nearest model frame) and the motion's own joints (S, T, J, 3),
    by `spans.clean_plants`' rules (flickers dropped, blinks merged, short swings widened)."""
    _, near = output_times(stance.shape[1], model_fps, out_fps)
    flags = np.asarray(stance, bool)[:, near]                                           # (S, T, C)
    feet = np.asarray(joints)[:, :, list(contact_joints)]                               # (S, T, C, 3)
    return np.stack([clean_plants(flags[s], feet[s], min_frames, min_swing, same_spot) for s in range(len(flags))])


def solve_bodies(body, joints: np.ndarray, rot_model: torch.Tensor, planted: np.ndarray | None,
                 contact_joints, model_fps: float, out_fps: float, reach: list | None = None, cfg=None,
                 samples=None, method: str = "refined", planted_heights: np.ndarray | None = None,
                 workers: int = 1) -> list:
    """The final solve, per sample: joints (S, T, J, 3) to follow at the output rate (resampled
    projected frames), rot_model (S, Tm, 22, 3, 3) the episodes' rotations (twist hints),
    planted (S, T, C) or None, reach: per sample a `reach_targets` tuple or None, cfg: the
    solve's RefineConfig (None: body.solve.SOLVE_CONFIG), samples: which to solve (None: all),
    method: "lbfgs" (`MotionBody.solve`: 80 L-BFGS iterations over the rotations),
    "joint-space" (`MotionBody.solve_joint_space`: the objective's minimum in joint space in
    closed form, then the analytic fit) or "refined" (REFINED_STEPS L-BFGS iterations from the
    joint-space result; cfg holds those iterations' weights), planted_heights (S, T, C) or None:
    the heights the foot lock holds the contact joints at (`fit.refine`; None: those of
    `joints`), workers: processes solving samples side by side (`parallel_solves`). Returns
    one `BodyMotion` per sample solved."""
    require_choice("loop.solve", method, SOLVE_METHODS)
    cfg = cfg if cfg is not None else SOLVE_CONFIG
    todo = list(range(joints.shape[0]) if samples is None else samples)
    one = functools.partial(_solve_sample, body, joints, rot_model, planted, contact_joints, model_fps,
                            output_times(rot_model.shape[1], model_fps, out_fps), reach, cfg, method, planted_heights)
    return parallel_solves(one, todo, workers)


def _solve_sample(body, joints, rot_model, planted, contact_joints, model_fps, times, reach, cfg, method,
                  planted_heights, s: int):
    """Sample s's final solve (`solve_bodies`' arguments; times: `output_times` of its output)."""
    t_out, near = times
    p = None if planted is None else planted[s]
    r = None if reach is None else reach[s]
    h = None if planted_heights is None else planted_heights[s]
    if method != "lbfgs":
        hint = interpolate_rotations(rot_model[s], model_fps, t_out)                       # (T, 22, 3, 3)
        exact = cfg if method == "joint-space" else replace(cfg, **solve_weights("joint-space", model_fps, None))
        start = body.solve_joint_space(s, joints[s], hint, p, contact_joints, cfg=exact, reach=r, planted_heights=h)
        if method == "joint-space":
            return start
        R0, cfg_s = torch.as_tensor(start.rotmats, dtype=body.rest.dtype), replace(cfg, max_steps=REFINED_STEPS)
    else:
        X = torch.as_tensor(joints[s, :, :NUM_BODY_JOINTS], dtype=body.rest.dtype)        # (T, 22, 3)
        R0, cfg_s = analytic_init(X, body.rest[s], rot_model[s, near].to(X.dtype)), cfg   # (T, 22, 3, 3)
    return body.solve(s, joints[s], R0, p, contact_joints, cfg=cfg_s, reach=r, planted_heights=h)


# Samples below which the final solves stay in this process: a fork and the results' way back
# cost more than a few solves save.
PARALLEL_MIN_SAMPLES = 8


def parallel_solves(one, todo: list, workers: int) -> list:
    """[one(s) for s in todo], in `workers` forked processes (`forked.forked_map`; 0: as many as
    torch has threads, i.e. one per core unless `threads=` or an `evaluate jobs=N` worker set
    fewer) when there are at least PARALLEL_MIN_SAMPLES. Each solve is single-threaded (the
    body's tensors are small: body/_threads.py) and its Python holds the interpreter lock most
    of the time, so threads gain nothing on a short motion (docs/results.md, "The final solve's
    posing pass"); forked children inherit the inputs and give each sample the bitwise result
    it has here."""
    workers = workers if workers > 0 else torch.get_num_threads()
    return list(forked_map(one, todo, workers if len(todo) >= PARALLEL_MIN_SAMPLES else 1))


SOLVE_METHODS = ("lbfgs", "joint-space", "refined")


def interpolate_rotations(R: torch.Tensor, fps: float, t: np.ndarray) -> torch.Tensor:
    """Rotations (Tm, J, 3, 3) at `fps` -> (T, J, 3, 3) at times t (T,) seconds, by normalised
    linear interpolation of quaternions (the nearest frame would step the twist at the model
    rate: a wrist turning in jumps). Not scipy's `Slerp` (as `importers.amass.resample_params`):
    one joint at a time it took 67 ms on a 25 s motion, more than the joint-space solve itself,
    and scipy's batched rotations 160 ms."""
    q = matrix_to_quaternion(R.double())                                                   # (Tm, J, 4)
    # Neighbouring frames on the same side of the double cover, so the interpolation takes the short way.
    sign = torch.where((q[1:] * q[:-1]).sum(-1) < 0, -1.0, 1.0).to(q.dtype)
    q = q * torch.cat([torch.ones_like(sign[:1]), torch.cumprod(sign, 0)])[..., None]
    x = np.clip(np.asarray(t) * fps, 0, R.shape[0] - 1)
    i0 = np.minimum(np.floor(x).astype(np.int64), R.shape[0] - 1)
    i1 = np.minimum(i0 + 1, R.shape[0] - 1)
    w = torch.as_tensor(x - i0, dtype=q.dtype)[:, None, None]
    qi = (1 - w) * q[i0] + w * q[i1]
    return quaternion_to_matrix(qi / qi.norm(dim=-1, keepdim=True)).to(R.dtype)
