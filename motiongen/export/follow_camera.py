"""The video's follow camera: behind and above the body, looking at the pelvis, its heading
smoothed so it does not shake with every step; projection of points, floor-grid segments and
obstacle faces into its image plane."""

from __future__ import annotations

import math

import numpy as np

from motiongen.skeleton import LEFT_HIP, RIGHT_HIP

CAM_VIEW = (1.0, 0.8)      # the camera panel shows image-plane x in ±1.0, y in ±0.8 (focal 1.6)


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


class FollowCamera:
    """Pinhole camera behind the body looking at the pelvis: world (N, 3) -> image (N, 2), depth."""

    def __init__(self, target: np.ndarray, yaw: float, dist: float = 3.2, height: float = 1.9, focal: float = 1.6):
        fwd = np.array([math.sin(yaw), 0.0, math.cos(yaw)])
        self.eye = target + np.array([0.0, height - target[1], 0.0]) - dist * fwd
        look = target + np.array([0.0, 0.9 - target[1], 0.0]) - self.eye
        z = look / np.linalg.norm(look)
        x = np.cross(np.array([0.0, 1.0, 0.0]), z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        self.R = np.stack([-x, y, z])          # image x to the right: world-left is body +x
        self.focal = focal

    def project(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = (p - self.eye) @ self.R.T                                                        # (N, 3)
        d = c[:, 2]
        uv = self.focal * c[:, :2] / np.maximum(d, 1e-3)[:, None]
        return uv, d


def project_segments(cam: FollowCamera, segs: np.ndarray) -> np.ndarray:
    """World segments (N, 2, 3) -> image segments (M, 2, 2): those in front of the camera and
    not far outside its view."""
    if not len(segs):
        return np.zeros((0, 2, 2))
    uv, d = cam.project(segs.reshape(-1, 3))
    uv, d = uv.reshape(-1, 2, 2), d.reshape(-1, 2)
    ok = (d > 0.2).all(1) & (np.abs(uv) < 4).all(axis=(1, 2))
    return uv[ok]


def visible_faces(cam: FollowCamera, body: np.ndarray, faces: np.ndarray, normals: np.ndarray, rgb: np.ndarray,
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
