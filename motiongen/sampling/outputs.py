"""What `sample.py` writes and prints about a generated motion: the motion.npz payload, the body
figures (bone lengths, foot slide), the summary lines and the lines naming the goals not reached."""

from __future__ import annotations

import numpy as np

from motiongen import metrics as M
from motiongen.sampling.settings import EPISODE_LIMIT, NOT_ATTEMPTED, STALLED, Motion, SamplerSettings
from motiongen.skeleton import joint_set_for


def motion_arrays(motion: Motion, extra: dict | None = None) -> dict:
    """The motion.npz payload (no pickled objects: strings as unicode arrays)."""
    r = motion.route
    goals = np.stack([g.xz for g in r.goals]) if r.goals else np.zeros((0, 2))
    d = {
        "joints": motion.joints.astype(np.float32),                                      # (S, T, J, 3)
        "fps": np.float64(motion.fps),
        "joint_names": np.array(motion.joint_names),
        "model_joints": motion.model_joints.astype(np.float32),                          # (S, Tm, J, 3)
        "model_fps": np.float64(motion.model_fps),
        "start": np.asarray(r.start, np.float64),
        "goals": goals.astype(np.float64),                                                # (G, 2) x, z
        "goal_actions": np.array([g.action or "" for g in r.goals]),
        "goal_durations": np.array([g.duration for g in r.goals], np.float64),
        "path": r.path.astype(np.float64),                                                # (N, 2)
        "path_mode": np.array(r.mode),
        "subgoals": r.subgoals.astype(np.float64),                                        # (K, 2)
        "subgoal_goal": r.subgoal_leg.astype(np.int64),
        "actions": motion.actions.astype(np.int16),                                       # (S, T), -1 = none
        "action_names": np.array(motion.action_names),
        "episode_starts": motion.episode_starts.astype(np.int64),                        # (E,) output frames
        "episode_kinds": np.array(motion.episode_kinds),
        "arrival_frames": motion.arrival_frame.astype(np.int64),                         # (S, G)
        "arrival_error": motion.arrival_error.astype(np.float64),
        "arrival_error_body": motion.arrival_error_body.astype(np.float64),
        "finish_frame": motion.finish_frame.astype(np.int64),
        "completed": np.bool_(motion.completed),
        "wall_time": np.float64(motion.wall_time),
    }
    if motion.goal_outcome is not None:
        d["goal_outcome"] = np.asarray(motion.goal_outcome, str)                         # (S, G) reached | ...
    if motion.joints_raw is not None:
        d["joints_raw"] = motion.joints_raw.astype(np.float32)                           # (S, T, J, 3) network's own
    if motion.planted is not None:
        d["planted"] = motion.planted                                                     # (S, T, C) bool
        d["contact_joints"] = np.array(motion.contact_joints)
    if motion.bodies is not None:
        d["betas"] = np.stack([b.betas for b in motion.bodies]).astype(np.float32)       # (S, nβ) one body each
    for k, v in (extra or {}).items():
        d[k] = np.array(v)
    return d


def body_figures(motion: Motion) -> dict:
    """Per sample, what the motion is as a body (docs/metrics.md): bone-length CV and largest
    deviation, grounded-toe median slide speed, foot skating, the lower toe's median height, how
    far off its direction of travel the walking body faces; for the output and for the network's own joints. Lists of S
    values."""
    parents = joint_set_for(motion.joint_names).parents
    out: dict[str, list] = {}
    for tag, joints in (("", motion.joints), ("network_", motion.joints_raw)):
        if joints is None:
            continue
        for s in range(motion.num_samples):
            for k, v in M.body_metrics(joints[s], motion.fps, parents).items():
                out.setdefault(tag + k, []).append(float(v))
    return out


def summary_lines(motion: Motion, sampler: SamplerSettings, figures: dict | None = None) -> list[str]:
    """The printed summary; figures: `body_figures(motion)` when already computed."""
    S, T = motion.joints.shape[:2]
    lines = [f"motion: {S} sample(s) x {T} frames = {motion.duration:.1f} s at {motion.fps:g} fps, "
             f"{len(motion.episode_starts)} episodes, {sampler.sampler.upper()}-{sampler.steps}"
             + (f", guidance {sampler.guidance_scale:g}" if sampler.guidance_scale != 1 else "")]
    for g, goal in enumerate(motion.route.goals):
        errs = motion.arrival_error[:, g]
        body = motion.arrival_error_body[:, g]
        reached = np.isfinite(errs)
        what = f" then {goal.action} {goal.duration:g} s" if goal.action else ""
        if reached.any():
            at = motion.arrival_frame[reached, g] / motion.fps
            lines.append(f"goal {g + 1} ({goal.xz[0]:.2f}, {goal.xz[1]:.2f}){what}: reached by {reached.sum()}/{S}, "
                         f"pelvis error {np.nanmean(errs):.3f} m (hips {np.nanmean(body):.3f} m), "
                         f"at {at.mean():.1f} s")
        else:
            lines.append(f"goal {g + 1} ({goal.xz[0]:.2f}, {goal.xz[1]:.2f}){what}: not reached")
    f = body_figures(motion) if figures is None else figures
    if f:
        lines.append("body: bone-length CV {} (network {}), largest bone deviation {} (network {}), "
                     "grounded-toe slide {} m/s (network {}), foot skating {} (network {}), "
                     "lower toe {} m up (network {}), walking {}° off its direction of travel (network {}°) "
                     "with its knees at {}° (network {}°)".format(
                         *[", ".join(f"{v:.1f}" if k.endswith("_deg") else f"{v:.3f}" for v in f.get(tag + k, []))
                           or "n/a"
                           for k in ("bone_cv", "bone_max_dev", "slide_mps", "foot_skating", "toe_height_m",
                                     "heading_deg", "knee_walk_deg")
                           for tag in ("", "network_")]))
    lines.append(f"wall time {motion.wall_time:.1f} s, real-time factor {motion.real_time_factor:.2f} "
                 f"({S} x {motion.duration:.1f} s of motion / {motion.wall_time:.1f} s)")
    return lines


# Why a goal was not reached, as the failure lines say it.
_WHY = {STALLED: "stalled, no progress towards it for loop.stall_s seconds",
        EPISODE_LIMIT: "stopped by the episode limit, loop.max_episodes"}


def failure_lines(failed: list[dict]) -> list[str]:
    """The lines naming the goals not reached (`Motion.failed_goals()`): one per goal a sample
    stopped at, one per sample for the goals after it, which it never set out for."""
    lines, later = [], {}
    for f in failed:
        if f["reason"] == NOT_ATTEMPTED:
            later.setdefault(f["sample"], []).append(f["goal"])
        else:
            lines.append(f"goal not reached: sample {f['sample']}, goal {f['goal']}: "
                         f"{_WHY.get(f['reason'], f['reason'])}; {f['distance_m']:.2f} m from it at the end")
    for s, goals in later.items():
        span = f"goal {goals[0]}" if len(goals) == 1 else f"goals {goals[0]}-{goals[-1]}"
        lines.append(f"goal not reached: sample {s}, {span}: not attempted")
    return lines
