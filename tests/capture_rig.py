"""A multi-view capture rig with a known answer, for the multi-view fitting tests and benchmark.

The procedural body (`load_body_model()`) performs a known motion: a few frames of A-pose
(the multi-view capture paper's stage-1 "simple pose"), blending into a `sample_motion`
sequence. 3–6 virtual OpenCV cameras stand on a circle around it looking at its mean pelvis;
its 22 joints are projected with Gaussian pixel noise, some detections dropped (confidence 0)
and some replaced by outliers (displaced 60–300 px in a random direction with ordinary
confidence, as a detector's confident mistakes are).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from motiongen.body.model import BodyModel
from motiongen.body.random_motion import sample_motion
from motiongen.capture.cameras import Cameras
from motiongen.skeleton import BODY_JOINT_NAMES

A_POSE = {"left_shoulder": (0.0, 0.0, -1.1), "right_shoulder": (0.0, 0.0, 1.1)}


@dataclass
class Rig:
    cams: Cameras
    params: dict                 # true global_orient (T,3), body_pose (T,63), transl (T,3), betas (10,)
    joints: np.ndarray           # (T, 22, 3) true joints, metres
    uv: np.ndarray               # (C, T, 22, 2) detections, pixels
    conf: np.ndarray             # (C, T, 22) confidences (0 = dropped)
    outlier: np.ndarray          # (C, T, 22) bool
    clean_uv: np.ndarray         # (C, T, 22, 2) noise-free projections


def look_at_cameras(center: np.ndarray, num: int, radius: float = 3.5, f: float = 1000.0,
                    size=(1280, 720), rng: np.random.Generator | None = None, distortion: bool = True) -> Cameras:
    """`num` cameras on a circle of `radius` around `center` (y-up world), at 1.2–2.4 m
    height, looking at `center`; OpenCV axes (x right, y down, z forward)."""
    rng = rng if rng is not None else np.random.default_rng(0)
    Ks, Rs, ts, ds = [], [], [], []
    for i in range(num):
        a = 2 * np.pi * i / num + rng.uniform(-0.2, 0.2)
        c = center + np.array([radius * np.sin(a), rng.uniform(1.2, 2.4) - center[1], radius * np.cos(a)])
        fwd = (center - c) / np.linalg.norm(center - c)
        right = np.cross(fwd, [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        R = np.stack([right, down, fwd])
        fi = f * rng.uniform(0.9, 1.1)
        Ks.append(np.array([[fi, 0, size[0] / 2], [0, fi, size[1] / 2], [0, 0, 1]]))
        Rs.append(R)
        ts.append(-R @ c)
        ds.append([rng.uniform(-0.08, 0.02), rng.uniform(-0.02, 0.02), 0.0, 0.0, 0.0] if distortion else [0.0] * 5)
    return Cameras([f"cam{i}" for i in range(num)], np.stack(Ks), np.stack(Rs), np.stack(ts),
                   np.array(ds, float), np.tile(np.array(size, float), (num, 1)))


def rig_motion(bm: BodyModel, T: int, seed: int, still: int = 10, ramp: int = 20) -> dict:
    """Parameters of `still` A-pose frames, blending over `ramp` frames into a sampled motion."""
    # Not walking: a walk leaves the capture volume within seconds; the subject moves in place.
    p = sample_motion(T, 30.0, np.random.default_rng(seed), gait=False, num_betas=bm.num_betas)
    a = np.zeros((21, 3))
    for name, v in A_POSE.items():
        a[BODY_JOINT_NAMES.index(name) - 1] = v
    s = np.clip((np.arange(T) - still) / max(ramp, 1), 0, 1)[:, None]
    s = s * s * (3 - 2 * s)                                                     # smoothstep
    p["body_pose"] = ((1 - s) * a.reshape(1, 63) + s * p["body_pose"]).astype(np.float32)
    p["betas"] = (0.8 * p["betas"]).astype(np.float32)
    return p


def make_rig(bm: BodyModel, T: int = 60, cameras: int = 4, noise_px: float = 1.5, drop: float = 0.05,
             outliers: float = 0.0, seed: int = 0) -> Rig:
    rng = np.random.default_rng(seed + 1000)
    p = rig_motion(bm, T, seed)
    with torch.no_grad():
        J = bm.joints(*(torch.as_tensor(p[k]) for k in ("global_orient", "body_pose", "transl", "betas")))
    J = J.double().numpy()                                                      # (T, 22, 3)
    cams = look_at_cameras(J[:, 0].mean(0), cameras, rng=rng)
    clean, depth = cams.project_np(J)                                          # (T, 22, C, 2)
    clean = clean.transpose(2, 0, 1, 3)                                        # (C, T, 22, 2)
    assert (depth > 0.5).all()
    uv = clean + rng.normal(0, noise_px, clean.shape)
    conf = rng.uniform(0.6, 1.0, clean.shape[:3])
    out = rng.random(clean.shape[:3]) < outliers
    ang = rng.uniform(0, 2 * np.pi, clean.shape[:3])
    mag = rng.uniform(60, 300, clean.shape[:3])
    uv[out] += (mag[..., None] * np.stack([np.cos(ang), np.sin(ang)], -1))[out]
    dropped = rng.random(clean.shape[:3]) < drop
    conf[dropped] = 0.0
    return Rig(cams, p, J, uv, conf, out & ~dropped, clean)
