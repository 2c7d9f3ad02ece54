"""Keypoint files and layouts: 2D detections per camera and frame, optional 3D keypoints,
and the common 2D body-keypoint orders mapped onto our 22 SMPL-X body joints.

2D file (npz): `keypoints` (C, T, K, 3) = pixel u, v and confidence in [0, 1] (or (C, T, K, 2)
plus `confidence` (C, T, K)); optional `layout` (a name in `LAYOUTS`; required unless K = 22),
`camera_names` (C,) (matched to the camera file by name; otherwise the camera file's order),
`fps`. A missed detection is confidence 0 or NaN coordinates.

3D file (npz): `keypoints3d` (T, K, 4) = x, y, z and confidence (or (T, K, 3), confidence 1
where finite), in the camera file's world and units; optional `layout`.

Everything downstream works on our 22 joints: a layout's keypoints that have no SMPL-X
body joint (eyes, ears, nose, heels, small toes) are dropped, joints the layout lacks get
confidence 0. Some correspondences are approximate (a detector's hip keypoint is not the
SMPL-X hip-joint centre): `APPROXIMATE` lists them, docs/capture.md says by how much.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from motiongen.errors import DataError
from motiongen.skeleton import BODY_JOINT_NAMES, NUM_BODY_JOINTS

COCO17 = ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
          "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
          "right_knee", "left_ankle", "right_ankle")
BODY25 = ("nose", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder", "left_elbow",
          "left_wrist", "mid_hip", "right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle",
          "right_eye", "left_eye", "right_ear", "left_ear", "left_big_toe", "left_small_toe", "left_heel",
          "right_big_toe", "right_small_toe", "right_heel")
LAYOUTS: dict[str, tuple[str, ...]] = {"smplx22": BODY_JOINT_NAMES, "coco17": COCO17, "body25": BODY25}
# Keypoint name -> our joint name, where the names differ (same names map to themselves).
_RENAME = {"mid_hip": "pelvis", "left_big_toe": "left_foot", "right_big_toe": "right_foot"}
# Correspondences that are not the same anatomical point (see docs/capture.md).
APPROXIMATE = {"coco17": ("left_hip", "right_hip", "left_shoulder", "right_shoulder"),
               "body25": ("left_hip", "right_hip", "left_shoulder", "right_shoulder", "neck", "pelvis",
                          "left_foot", "right_foot")}


def layout_to_joints(layout: str) -> np.ndarray:
    """(K,) index of our body joint for each keypoint of `layout`, −1 where there is none."""
    if layout not in LAYOUTS:
        raise KeyError(layout)
    return np.array([BODY_JOINT_NAMES.index(_RENAME.get(n, n)) if _RENAME.get(n, n) in BODY_JOINT_NAMES else -1
                     for n in LAYOUTS[layout]], np.int64)


def to_body_joints(values: np.ndarray, conf: np.ndarray, layout: str, axis: int):
    """Reorder keypoints (..., K, ...) along `axis` into our 22 joints: values (.., 22, ..)
    (zeros where unmapped) and conf (..., 22) (0 where unmapped)."""
    idx = layout_to_joints(layout)
    keep = np.flatnonzero(idx >= 0)
    vshape = list(values.shape)
    vshape[axis] = NUM_BODY_JOINTS
    out_v = np.zeros(vshape, np.float64)
    out_c = np.zeros(conf.shape[:axis] + (NUM_BODY_JOINTS,) + conf.shape[axis + 1:], np.float64)
    sl_v = [slice(None)] * values.ndim
    sl_c = [slice(None)] * conf.ndim
    sl_v[axis], sl_c[axis] = idx[keep], idx[keep]
    src_v = [slice(None)] * values.ndim
    src_c = [slice(None)] * conf.ndim
    src_v[axis], src_c[axis] = keep, keep
    out_v[tuple(sl_v)] = values[tuple(src_v)]
    out_c[tuple(sl_c)] = conf[tuple(src_c)]
    return out_v, out_c


@dataclass
class Observations:
    """2D detections (and optional 3D keypoints) on our 22 body joints."""

    uv: np.ndarray                 # (C, T, 22, 2) pixels (0 where missing)
    conf: np.ndarray               # (C, T, 22) confidence in [0, 1]; 0 = missing / unmapped
    layout: str
    fps: float
    observed: np.ndarray           # (22,) bool: joints the layout has
    x3d: np.ndarray | None = None  # (T, 22, 3) metres, our world (0 where missing)
    conf3d: np.ndarray | None = None   # (T, 22)

    @property
    def num_frames(self) -> int:
        return self.uv.shape[1]


def _layout_name(path, value, K: int, override: str | None) -> str:
    name = override or (None if value is None else str(value))
    if name is None:
        if K == NUM_BODY_JOINTS:
            return "smplx22"
        raise DataError(path, "layout", f"{K} keypoints per frame: name their order with layout= "
                                        f"(one of {', '.join(LAYOUTS)})")
    if name not in LAYOUTS:
        raise DataError(path, "layout", f"unknown layout {name!r}; expected one of {', '.join(LAYOUTS)}")
    if len(LAYOUTS[name]) != K:
        raise DataError(path, "layout", f"layout {name} has {len(LAYOUTS[name])} keypoints, the file has {K}")
    return name


def _load(path: Path) -> dict:
    if not path.is_file():
        raise DataError(path, None, "keypoint file does not exist")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except Exception as e:       # zipfile / format / pickle errors of all kinds
        raise DataError(path, None, f"not a readable .npz file ({type(e).__name__}: {e})") from None


def _confidence(path, field, c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, np.float64)
    bad = np.isfinite(c) & ((c < 0) | (c > 1))
    if bad.any():
        raise DataError(path, field, f"confidences must lie in [0, 1], found {c[bad].flat[0]:g}")
    return np.nan_to_num(c, nan=0.0)


def load_keypoints2d(path: str | Path, camera_names: list[str], layout: str | None = None,
                     fps: float | None = None) -> Observations:
    """Read 2D detections (see the module doc), put their cameras in `camera_names` order and
    their keypoints on our joints."""
    path = Path(path)
    d = _load(path)
    if "keypoints" not in d:
        raise DataError(path, "keypoints", f"required array is missing (found: {', '.join(sorted(d)) or 'nothing'})")
    kp = d["keypoints"]
    if kp.ndim != 4 or kp.shape[-1] not in (2, 3) or kp.dtype.kind not in "fi" or kp.shape[1] < 1:
        raise DataError(path, "keypoints", f"expected (C, T, K, 3) [u, v, confidence], found {kp.dtype} {kp.shape}")
    C, T, K = kp.shape[:3]
    if kp.shape[-1] == 3:
        conf = kp[..., 2]
    elif "confidence" in d:
        conf = d["confidence"]
        if conf.shape != (C, T, K):
            raise DataError(path, "confidence", f"expected {(C, T, K)} like keypoints, found {conf.shape}")
    else:
        conf = np.ones((C, T, K))
    conf = _confidence(path, "confidence", conf)
    uv = kp[..., :2].astype(np.float64)
    missing = ~np.isfinite(uv).all(-1)
    conf[missing] = 0.0
    uv[missing] = 0.0
    if "camera_names" in d:
        names = [str(n) for n in np.atleast_1d(d["camera_names"])]
        if len(names) != C:
            raise DataError(path, "camera_names", f"{len(names)} names for {C} cameras of keypoints")
        unknown = [n for n in names if n not in camera_names]
        if unknown or len(set(names)) != C:
            raise DataError(path, "camera_names", f"{unknown or names} do not match the camera file's "
                                                  f"cameras {camera_names} one to one")
        order = [names.index(n) for n in camera_names if n in names]
        if len(order) != len(camera_names):
            raise DataError(path, "camera_names", f"the camera file has cameras without keypoints: "
                                                  f"{[n for n in camera_names if n not in names]}")
        uv, conf = uv[order], conf[order]
    elif C != len(camera_names):
        raise DataError(path, "keypoints", f"{C} cameras of keypoints but {len(camera_names)} in the camera file")
    name = _layout_name(path, d.get("layout"), K, layout)
    rate = fps if fps is not None else (float(d["fps"]) if "fps" in d else 30.0)
    if not (np.isfinite(rate) and rate > 0):
        raise DataError(path, "fps", f"expected a positive frame rate, found {rate}")
    uv22, conf22 = to_body_joints(uv, conf, name, axis=2)
    observed = np.zeros(NUM_BODY_JOINTS, bool)
    observed[layout_to_joints(name)[layout_to_joints(name) >= 0]] = True
    return Observations(uv22, conf22, name, float(rate), observed)


def load_keypoints3d(path: str | Path, num_frames: int, to_world, layout: str | None = None):
    """Read 3D keypoints (see the module doc) -> (T, 22, 3) metres in our world (to_world maps
    the file's points, e.g. `Cameras.file_points_to_world`), conf (T, 22)."""
    path = Path(path)
    d = _load(path)
    if "keypoints3d" not in d:
        raise DataError(path, "keypoints3d", f"required array is missing (found: {', '.join(sorted(d)) or 'nothing'})")
    kp = d["keypoints3d"]
    if kp.ndim != 3 or kp.shape[-1] not in (3, 4) or kp.dtype.kind not in "fi":
        raise DataError(path, "keypoints3d", f"expected (T, K, 4) [x, y, z, confidence], found {kp.dtype} {kp.shape}")
    if kp.shape[0] != num_frames:
        raise DataError(path, "keypoints3d", f"{kp.shape[0]} frames, the 2D keypoints have {num_frames}")
    name = _layout_name(path, d.get("layout"), kp.shape[1], layout)
    X = kp[..., :3].astype(np.float64)
    conf = _confidence(path, "keypoints3d", kp[..., 3]) if kp.shape[-1] == 4 else np.ones(kp.shape[:2])
    missing = ~np.isfinite(X).all(-1)
    conf[missing] = 0.0
    X[missing] = 0.0
    X = to_world(X)
    return to_body_joints(X, conf, name, axis=1)
