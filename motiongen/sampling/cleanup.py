"""The clean-up after the last episode: the kept model-rate frames resampled to the output rate
(cubic spline), the feet to lock, the non-foot joints smoothed, seated bodies put on their
seats, and the final solve on the body over the whole motion (planted feet held in place at
the network's own heights, a hand on the object it picks up). The network's own joints are resampled beside, so that what
the clean-up did can be measured."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d

from motiongen.body.solve import SOLVE_CONFIG
from motiongen.sampling.assemble import (clearance_for_rate, output_times, planted_at_output, resample,
                                         smoothing_sigma, solve_bodies, solve_weights)
from motiongen.sampling.episode import EpisodeState
from motiongen.sampling.hand_clearance import PUSH_SMOOTHING, settle_hands
from motiongen.sampling.interactions import hand_targets, merge_targets, seat_shift
from motiongen.sampling.progress import GoalPlan
from motiongen.sampling.settings import LoopConfig
from motiongen.sampling.swing import lift_swings


@dataclass
class CleanMotion:
    """The motion at the output rate, and its model-rate frames."""

    joints: np.ndarray             # (S, T, J, 3) float64 world: the output
    joints_raw: np.ndarray         # (S, T, J, 3) float64 the network's joints, resampled the same way
    planted: np.ndarray | None     # (S, T, C) bool feet held planted; None without stance channels
    actions: np.ndarray            # (S, T) int action index per output frame (nearest model frame)
    bodies: list | None            # one BodyMotion per sample; None without a body
    model_joints: np.ndarray       # (S, Tm, J, 3) float64 the kept frames at the model rate


def clean_up(state: EpisodeState, layout, model_fps: float, plan: GoalPlan, loop: LoopConfig,
             objects, scene, swing_rise=None) -> CleanMotion:
    """The output motion from the episodes' kept frames (see the module's docstring);
    swing_rise: the training data's swing table (`LoadedModel.swing_rise`, None: the embedded
    dataset's) for the swing lift."""
    model_joints = np.concatenate(state.frames, 1)                                          # (S, Tm, J, 3)
    model_labels = np.concatenate(state.labels, 1)                                          # (S, Tm)
    _, near = output_times(model_joints.shape[1], model_fps, loop.out_fps)                 # (T,) nearest model frame
    out = resample(model_joints, model_fps, loop.out_fps)                                  # (S, T, J, 3)
    raw_out = resample(np.concatenate(state.raws, 1), model_fps, loop.out_fps)
    planted = planted_at_output(np.concatenate(state.stances, 1), out, layout.contact_joints, model_fps,
                                loop.out_fps) if layout.num_contacts else None
    sigma = smoothing_sigma(loop.smooth, model_fps)
    if sigma > 0:
        out = smooth_non_feet(out, sigma, layout.contact_joints)
    labels = model_labels[:, near]                                                          # (S, T)
    seats = [None] * out.shape[0]
    if loop.project and loop.seat_shift:
        out, seats = seat_bodies(out, labels, plan)
    bodies = None
    if state.body is not None:
        if planted is not None and loop.swing_lift:
            out = lift_swings(out, planted, layout.contact_joints, swing_rise)
        hands = hand_targets(out, labels, plan.names, loop.hand_actions, objects, scene) or [None] * out.shape[0]
        weights = solve_weights(loop.solve, model_fps, loop.solve_smoothness)
        clearance = clearance_for_rate(model_fps) if loop.swing_clearance else 0.0
        reach = [merge_targets(h, p) for h, p in zip(hands, seats)]
        rots = torch.cat(state.rots, 1)
        # By default a planted foot is held where the network put it, not where the projection
        # did: the body's legs may be shorter than the network's, its feet then above the floor.
        network = loop.foot_height == "network" and layout.num_contacts
        heights = raw_out[:, :, list(layout.contact_joints), 1] if network else None          # (S, T, C)

        def solve(samples, targets):
            return solve_bodies(state.body, out, rots, planted if loop.foot_lock else None, layout.contact_joints,
                                model_fps, loop.out_fps, targets, samples=samples, method=loop.solve,
                                cfg=dataclasses.replace(SOLVE_CONFIG, w_clearance=clearance,
                                                        lock_height=loop.foot_height != "free", **weights),
                                planted_heights=heights, workers=loop.solve_workers)

        bodies = solve(None, reach)
        bodies = settle_hands(bodies, reach, objects, state.body.bm,
                              lambda s, r: solve([s], [r if i == s else None for i in range(len(reach))])[0],
                              sigma=PUSH_SMOOTHING[loop.solve] * loop.out_fps)
        out = np.stack([b.joints for b in bodies])
    return CleanMotion(out, raw_out, planted, labels, bodies, model_joints)


def smooth_non_feet(joints: np.ndarray, sigma: float, feet) -> np.ndarray:
    """Gaussian smoothing over time (sigma in frames) of every joint but the `feet` (S, T, J, 3).

    Network jitter sits near the model rate's Nyquist frequency (3-5 Hz at 10 fps), where real
    motion has little power (docs/sampling.md); steps (1-2 Hz) pass. It is on by default since
    the final solve's swing clearance holds the swing up (docs/quality.md). The feet keep their
    own timing: smoothing would flatten each swing into a shuffle (lower, longer, near the
    floor); the final solve's lock and acceleration terms handle their jitter."""
    keep = list(feet)
    kept = joints[:, :, keep].copy()
    out = gaussian_filter1d(joints, sigma, axis=1, mode="nearest")
    out[:, :, keep] = kept
    return out


def seat_bodies(joints: np.ndarray, labels: np.ndarray, plan: GoalPlan) -> tuple[np.ndarray, list]:
    """Seated or lying bodies moved onto their furniture (`interactions.seat_shift`) over the
    frames labelled with a goal's seat action: joints (S, T, J, 3), labels (S, T) ->
    (joints, per sample the pelvis reach targets or None). Goals without a seat height leave
    the motion as it is."""
    seat_goals: dict[int, list[int]] = {}
    for g in range(len(plan.goals)):
        if np.isfinite(plan.seat_y[g]):
            seat_goals.setdefault(plan.goal_labels[g], []).append(g)
    if not seat_goals:
        return joints, [None] * joints.shape[0]
    targets = [[plan.goal_xz[g, 0], plan.seat_y[g], plan.goal_xz[g, 1]] for g in range(len(plan.goals))]
    shifted = [seat_shift(joints[s], labels[s], seat_goals, targets) for s in range(joints.shape[0])]
    return np.stack([x for x, _ in shifted]), [r for _, r in shifted]
