"""The video's cameras: a pinhole camera looking from an eye at a target (`PinholeCamera`),
and a camera path (`CameraPath`), one eye and target per motion frame, which `motion.npz`
saves so that a user can reproduce the shot (e.g. in Blender). The paths themselves:
`follow_camera` (behind the body), `adaptive_camera` (the TRUMANS supplement's ring camera)
and `top_path` here (high above the body)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from motiongen.skeleton import PELVIS

CAM_VIEW = (1.0, 0.8)      # the camera panel shows image-plane x in ±1.0, y in ±0.8
CAMERA_MODES = ("adaptive", "follow", "top")


class PinholeCamera:
    """World (N, 3) -> image plane (N, 2) (x right, y up, the panel showing ±CAM_VIEW) and depth
    along the view direction, for a camera at `eye` (3,) looking at `target` (3,), y up."""

    def __init__(self, eye: np.ndarray, target: np.ndarray, focal: float = 1.6):
        self.eye = np.asarray(eye, np.float64)
        z = np.asarray(target, np.float64) - self.eye
        z = z / np.linalg.norm(z)
        x = np.cross(np.array([0.0, 1.0, 0.0]), z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        self.R = np.stack([-x, y, z])          # rows: image right, image up, forward
        self.focal = float(focal)

    def project(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = (p - self.eye) @ self.R.T                                                        # (N, 3)
        d = c[:, 2]
        uv = self.focal * c[:, :2] / np.maximum(d, 1e-3)[:, None]
        return uv, d

    def in_view(self, p: np.ndarray, view: tuple[float, float] = CAM_VIEW) -> np.ndarray:
        """(N,) bool: in front of the camera and inside the panel."""
        uv, d = self.project(p)
        return (d > 0.05) & (np.abs(uv[:, 0]) <= view[0]) & (np.abs(uv[:, 1]) <= view[1])


@dataclass
class CameraPath:
    """One camera per frame: position (T, 3) and target (T, 3), metres, world frame (y up);
    focal: one for the path, or (T,) one per frame."""
    position: np.ndarray
    target: np.ndarray
    focal: float | np.ndarray = 1.6
    mode: str = "follow"

    def focal_at(self, t: int) -> float:
        return float(np.broadcast_to(self.focal, (len(self.position),))[t])

    def at(self, t: int) -> PinholeCamera:
        return PinholeCamera(self.position[t], self.target[t], self.focal_at(t))

    def arrays(self) -> dict:
        """The motion.npz entries: camera_focal (T,) whether the path has one focal or many."""
        T = len(self.position)
        return {"camera_position": self.position.astype(np.float32), "camera_target": self.target.astype(np.float32),
                "camera_focal": np.broadcast_to(np.asarray(self.focal, np.float64), (T,)).copy(),
                "camera_view": np.asarray(CAM_VIEW, np.float64), "camera_mode": np.array(self.mode)}


def top_path(joints: np.ndarray, height: float = 6.0, back: float = 1.5) -> CameraPath:
    """High above the pelvis of joints (T, J, 3), a little behind it in z (a camera looking
    straight down has no 'up'), looking at the pelvis on the floor."""
    p = joints[:, PELVIS].astype(np.float64)                                                 # (T, 3)
    target = p * np.array([1.0, 0.0, 1.0])
    return CameraPath(target + np.array([0.0, height, -back]), target, 1.6, "top")
