"""The video's follow camera: behind and above the body, looking at the pelvis, its heading
smoothed so it does not shake with every step; projection of floor-grid segments and
obstacle faces into a camera's image plane."""

from __future__ import annotations

import math

import numpy as np

from motiongen.export.camera import CAM_VIEW, CameraPath, PinholeCamera
from motiongen.skeleton import LEFT_HIP, PELVIS, RIGHT_HIP


def camera_heading(joints: np.ndarray, fps: float, tau: float = 0.8) -> np.ndarray:
    """(T,) camera yaw for joints (T, J, 3): the body's facing from the hips, exponentially
    smoothed (time constant tau seconds) on the unit circle so the camera turns calmly."""
    across = joints[:, LEFT_HIP] - joints[:, RIGHT_HIP]                                      # (T, 3)
    f = np.stack([-across[:, 2], across[:, 0]], -1)                                          # forward (x, z)
    f /= np.maximum(np.linalg.norm(f, axis=-1, keepdims=True), 1e-9)
    a = 1 - math.exp(-1.0 / (fps * tau))
    out = np.empty_like(f)
    out[0] = f[0]
    for t in range(1, len(f)):
        v = out[t - 1] + a * (f[t] - out[t - 1])
        out[t] = v / max(np.linalg.norm(v), 1e-9)
    return np.arctan2(out[:, 0], out[:, 1])


def follow_path(joints: np.ndarray, fps: float, dist: float = 3.2, height: float = 1.9,
                focal: float = 1.6) -> CameraPath:
    """Behind and above the pelvis of joints (T, J, 3), `dist` back along the smoothed heading
    at `height` metres, looking at the point 0.9 m above the floor under the pelvis."""
    p = joints[:, PELVIS].astype(np.float64)                                                 # (T, 3)
    yaw = camera_heading(joints, fps)                                                        # (T,)
    fwd = np.stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], -1)                       # (T, 3)
    eye = p.copy()
    eye[:, 1] = height
    eye -= dist * fwd
    target = p.copy()
    target[:, 1] = 0.9
    return CameraPath(eye, target, focal, "follow")


def project_segments(cam: PinholeCamera, segs: np.ndarray) -> np.ndarray:
    """World segments (N, 2, 3) -> image segments (M, 2, 2): those in front of the camera and
    not far outside its view."""
    if not len(segs):
        return np.zeros((0, 2, 2))
    uv, d = cam.project(segs.reshape(-1, 3))
    uv, d = uv.reshape(-1, 2, 2), d.reshape(-1, 2)
    ok = (d > 0.2).all(1) & (np.abs(uv) < 4).all(axis=(1, 2))
    return uv[ok]


def visible_faces(cam: PinholeCamera, body: np.ndarray, faces: np.ndarray, normals: np.ndarray, rgb: np.ndarray,
                  radius: float = 7.0, view: tuple[float, float] = CAM_VIEW) -> tuple[list, np.ndarray]:
    """Projected faces near the camera that face it, far to near (painter's algorithm), with
    faces between the camera and the body see-through so furniture never hides the person."""
    if not len(faces):
        return [], np.zeros((0, 4))
    centre = faces.mean(1)                                                                   # (F, 3)
    near = np.linalg.norm(centre - body, axis=-1) < radius
    facing = ((cam.eye - centre) * normals).sum(-1) > 0
    idx = np.nonzero(near & facing)[0]
    uv, d = cam.project(faces[idx].reshape(-1, 3))
    uv, d = uv.reshape(-1, 4, 2), d.reshape(-1, 4)
    ok = (d > 0.2).all(1) & (np.abs(uv) < 6).all(axis=(1, 2))
    # Faces wholly outside the panel's view cost matplotlib path building for nothing.
    ok &= (uv[..., 0].max(1) > -view[0]) & (uv[..., 0].min(1) < view[0]) & \
          (uv[..., 1].max(1) > -view[1]) & (uv[..., 1].min(1) < view[1])
    uv, d, idx = uv[ok], d[ok], idx[ok]
    order = np.argsort(-d.mean(1))
    body_depth = float(cam.project(body[None])[1][0])
    alpha = np.where(d.mean(1) < body_depth - 0.3, 0.25, 1.0)                                # (M,)
    colours = np.concatenate([rgb[idx], alpha[:, None]], -1)[order]                          # (M, 4)
    return list(uv[order]), colours
