"""The motion generated so far as a file: npz (joints, rotations, the body's shape), BVH, or a
skinned glTF (`motiongen.export.gltf`)."""

from __future__ import annotations

import io
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from motiongen.body.solve import BodyMotion
from motiongen.bvh.export import export_bvh
from motiongen.export.gltf import write_motion_glb
from motiongen.skeleton import NUM_BODY_JOINTS

DOWNLOADS = {"npz": "application/octet-stream", "bvh": "text/plain", "glb": "model/gltf-binary"}


def body_motion(frames: dict, body) -> BodyMotion:
    """The frames (LiveSampler.frames_since) as one body's SMPL-X parameters and joints."""
    quats = np.asarray(frames["quats"], np.float64)                                       # (T, 22, 4)
    T = len(quats)
    R = Rotation.from_quat(quats.reshape(-1, 4))
    aa = R.as_rotvec().reshape(T, NUM_BODY_JOINTS, 3)
    transl = np.asarray(frames["root"], np.float64) - body.rest[0, 0].double().numpy()     # (T, 3)
    return BodyMotion(aa[:, 0].astype(np.float32), aa[:, 1:].reshape(T, -1).astype(np.float32),
                      transl.astype(np.float32), body.betas[0].double().numpy().astype(np.float32),
                      np.asarray(frames["joints"], np.float32), R.as_matrix().reshape(T, NUM_BODY_JOINTS, 3, 3))


def download(fmt: str, session, body_model) -> bytes:
    """The bytes of the motion so far in format `fmt` (one of DOWNLOADS)."""
    live = session.live
    frames, fps = session.snapshot_frames(), live.out_fps
    if fmt == "npz":
        buf = io.BytesIO()
        np.savez(buf, joints=np.asarray(frames["joints"], np.float32)[None], fps=np.float64(fps),
                 joint_names=np.array(live.loaded.joint_set.names), root=frames["root"].astype(np.float32),
                 quats=frames["quats"].astype(np.float32), actions=frames["labels"].astype(np.int16)[None],
                 action_names=np.array(live.loaded.action_names),
                 betas=live.body.betas.double().numpy().astype(np.float32))
        return buf.getvalue()
    with tempfile.TemporaryDirectory(prefix="motiongen-download-") as d:
        path = Path(d) / f"motion.{fmt}"
        if fmt == "bvh":
            export_bvh(path, np.asarray(frames["joints"])[:, :NUM_BODY_JOINTS], fps)
        else:
            write_motion_glb(path, [body_motion(frames, live.body)], body_model, fps)
        return path.read_bytes()
