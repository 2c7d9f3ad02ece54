"""Synthetic SMPL-X motion for training and testing joints → body-parameter fitting.

Without licensed mocap we sample plausible *parameter* sequences directly: every body-joint
rotation component follows a smooth random signal squashed into per-joint limits (so poses
stay anatomically possible and change smoothly), optionally overlaid with a gait cycle (legs
and arms in antiphase, forward travel), and the root turns and drifts smoothly.
Rotations are axis-angle in the SMPL-X rest frame (T-pose, y-up, facing +z, left at +x).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from motiongen.rates import DATA_FPS
from motiongen.skeleton import BODY_JOINT_NAMES

# Per left/central joint: (lo, hi, typical) for each axis-angle component x, y, z (radians).
# Right-side joints mirror these through the x = 0 plane: (x, y, z) -> (x, -y, -z).
_LIMITS = {
    "left_hip":      ((-1.9, 0.5, -0.1), (-0.6, 0.6, 0.0), (-0.3, 0.9, 0.05)),
    "left_knee":     ((0.0, 2.3, 0.15), (-0.1, 0.1, 0.0), (-0.1, 0.1, 0.0)),
    "left_ankle":    ((-0.5, 0.6, 0.0), (-0.3, 0.3, 0.0), (-0.25, 0.25, 0.0)),
    "left_foot":     ((-0.3, 0.4, 0.0), (-0.1, 0.1, 0.0), (-0.1, 0.1, 0.0)),
    "spine1":        ((-0.25, 0.6, 0.05), (-0.3, 0.3, 0.0), (-0.25, 0.25, 0.0)),
    "spine2":        ((-0.2, 0.4, 0.05), (-0.25, 0.25, 0.0), (-0.2, 0.2, 0.0)),
    "spine3":        ((-0.2, 0.4, 0.0), (-0.25, 0.25, 0.0), (-0.2, 0.2, 0.0)),
    "neck":          ((-0.4, 0.6, 0.05), (-0.6, 0.6, 0.0), (-0.35, 0.35, 0.0)),
    "head":          ((-0.4, 0.5, 0.0), (-0.5, 0.5, 0.0), (-0.3, 0.3, 0.0)),
    "left_collar":   ((-0.2, 0.2, 0.0), (-0.3, 0.3, 0.0), (-0.3, 0.3, 0.0)),
    "left_shoulder": ((-1.0, 1.0, 0.0), (-1.4, 0.6, -0.1), (-1.45, 0.6, -1.1)),
    "left_elbow":    ((-0.3, 0.3, 0.0), (-2.3, 0.0, -0.3), (-0.3, 0.3, 0.0)),
    "left_wrist":    ((-0.8, 0.8, 0.0), (-0.4, 0.4, 0.0), (-0.9, 0.9, 0.0)),
}


def joint_limits() -> np.ndarray:
    """(21, 3, 3) [joint, component, (lo, hi, typical)] for the 21 body joints 1..21."""
    out = np.zeros((21, 3, 3))
    for j, name in enumerate(BODY_JOINT_NAMES[1:]):
        lim = np.array(_LIMITS[name.replace("right_", "left_")], dtype=float)  # (3 comps, 3)
        if name.startswith("right_"):
            for c in (1, 2):
                lo, hi, typ = lim[c]
                lim[c] = (-hi, -lo, -typ)
        out[j] = lim
    return out


def smooth_noise(rng: np.random.Generator, t: np.ndarray, shape: tuple, fmin=0.08, fmax=1.2, terms=4) -> np.ndarray:
    """Sums of random sinusoids, unit variance per channel: (len(t),) + shape."""
    f = np.exp(rng.uniform(np.log(fmin), np.log(fmax), size=(terms,) + shape))
    ph = rng.uniform(0, 2 * np.pi, size=(terms,) + shape)
    a = rng.normal(size=(terms,) + shape)
    a = a / np.sqrt((a ** 2).sum(0, keepdims=True) / 2 + 1e-9)
    tt = t.reshape((-1, 1) + (1,) * len(shape))
    return (a[None] * np.sin(2 * np.pi * f[None] * tt + ph[None])).sum(1)


def sample_motion(num_frames: int, fps: float = DATA_FPS, rng: np.random.Generator | None = None,
                  gait: bool | None = None, num_betas: int = 10) -> dict[str, np.ndarray]:
    """One random sequence: global_orient (T, 3), body_pose (T, 63), transl (T, 3), betas (nβ,)."""
    rng = rng if rng is not None else np.random.default_rng()
    T = num_frames
    t = np.arange(T) / fps
    lim = joint_limits()                                    # (21, 3, 3)
    lo, hi, typ = lim[..., 0], lim[..., 1], lim[..., 2]     # (21, 3)
    frac = np.clip((typ - lo) / (hi - lo), 0.02, 0.98)
    base = np.log(frac / (1 - frac)) + rng.normal(0, 0.6, size=(21, 3))   # per-sequence posture
    activity = rng.uniform(0.3, 1.6)
    z = base + activity * smooth_noise(rng, t, (21, 3))      # (T, 21, 3) logits
    pose = lo + (hi - lo) / (1 + np.exp(-z))                 # within limits, smooth

    walking = rng.random() < 0.5 if gait is None else gait
    yaw = rng.uniform(-np.pi, np.pi) + rng.uniform(0.2, 1.2) * smooth_noise(rng, t, (), 0.03, 0.3, 3)
    pitch = rng.uniform(0.0, 0.15) * smooth_noise(rng, t, (), 0.05, 0.6, 3)
    roll = rng.uniform(0.0, 0.1) * smooth_noise(rng, t, (), 0.05, 0.6, 3)
    transl = np.zeros((T, 3))
    # SMPL-X-like templates have the rest pelvis ~0.35 m below the origin: feet near y = 0.
    transl[:, 1] = 1.28 + 0.02 * smooth_noise(rng, t, (), 0.1, 1.0, 3)
    if walking:
        idx = {n: i - 1 for i, n in enumerate(BODY_JOINT_NAMES)}
        freq = rng.uniform(0.75, 1.05)                      # strides per second
        phase = 2 * np.pi * freq * t + rng.uniform(0, 2 * np.pi)
        amp = rng.uniform(0.6, 1.0)
        w = 0.85                                              # gait dominates the noise
        keep = 1 - w

        def mix(name, comp, value):
            pose[:, idx[name], comp] = keep * pose[:, idx[name], comp] + w * value

        for side, sgn, ph in (("left", 1, 0.0), ("right", -1, np.pi)):
            s = np.sin(phase + ph)
            mix(f"{side}_hip", 0, -0.1 - 0.4 * amp * s)
            mix(f"{side}_knee", 0, 0.15 + 0.9 * amp * np.clip(np.sin(phase + ph + 1.2), 0, None) ** 2)
            mix(f"{side}_ankle", 0, 0.15 * amp * np.sin(phase + ph + 2.0))
            mix(f"{side}_shoulder", 1, sgn * 0.35 * amp * s)          # arms swing against legs
            mix(f"{side}_shoulder", 2, -sgn * 1.2)
            mix(f"{side}_elbow", 1, -sgn * (0.35 + 0.15 * amp * (1 + s)))
        pitch = pitch + 0.05 * np.sin(2 * phase)
        speed = 1.3 * freq * amp
        heading = yaw
        step = speed / fps * np.stack([np.sin(heading), np.cos(heading)], -1)   # (T, 2)
        transl[:, [0, 2]] = np.cumsum(step, 0)
        transl[:, 1] += 0.02 * np.cos(2 * phase)
    else:
        transl[:, [0, 2]] = 0.3 * smooth_noise(rng, t, (2,), 0.03, 0.3, 3)
    transl[:, [0, 2]] += rng.uniform(-2, 2, size=2)
    root = Rotation.from_euler("YXZ", np.stack([yaw, pitch, roll], -1))
    betas = np.clip(rng.normal(0, 1, size=num_betas), -2.5, 2.5)
    return {"global_orient": root.as_rotvec().astype(np.float32),
            "body_pose": pose.reshape(T, 63).astype(np.float32),
            "transl": transl.astype(np.float32), "betas": betas.astype(np.float32)}
