"""Convert AMASS-style SMPL-X / SMPL-H sequences (.npz) into a motiongen dataset.

    motiongen import-amass inputs=[a.npz,b.npz] out=DIR [body_model=PATH]
        [up=z|y] [scene=GRID_STEM] [scene_id=0] [split=train] [fps=30] [action=walk] [overwrite=true]

Each file holds `poses` (T, 165) SMPL-X (root 3 + body 63 + jaw 3 + eyes 6 + hands 90) or
(T, 156) SMPL-H (root 3 + body 63 + hands 90) axis-angle, `trans` (T, 3), `betas` (B,),
`mocap_framerate` or `mocap_frame_rate`, optionally `gender` and `up`. Only the root and the
21 body joints are used. Per sequence: z-up -> y-up (AMASS is z-up; our own exports say `up`
in the file; `up=` overrides both), resampling to `fps` (Slerp on rotations, cubic spline on
the translation), joints by the body model's kinematics from the resampled parameters (so the
stored SMPL-X parameters reproduce the stored joints exactly), the floor put at y = 0 under
the feet, contact labels from the floor as in `import_bvh`, and the plausibility check of
`bvh_detect` (a wrong up axis would write a body lying on its side). Scenes and splits as in
`import_bvh`. User mistakes print one line naming the file and field and exit 2; nothing is
written unless every file converts.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, Slerp

from motiongen.body.model import BodyModel, load_body_model
from motiongen.checks import require_fps
from motiongen.cli import parse_key_values, tool_main
from motiongen.bvh.retarget import resample_times
from motiongen.bvh.detect import check_plausible
from motiongen.data.format import SMPLX_FIELDS
from motiongen.importers.bvh import load_clips, refuse_over_sources, write_clips
from motiongen.errors import ConfigError, DataError
from motiongen.geometry import up_rotation
from motiongen.rates import DATA_FPS
from motiongen.skeleton import FOOT_JOINTS, HEAD

LAYOUTS = {165: "smplx", 156: "smplh"}      # poses width -> layout; the body is columns 0:66 in both
RATE_KEYS = ("mocap_framerate", "mocap_frame_rate")
UPS = ("y", "z")
NUM_BETAS = SMPLX_FIELDS["betas"]           # the dataset stores 10 shape coefficients
FLOOR_PERCENTILE = 2.0                      # of the per-frame lowest foot joint: ignores a few glitches
Z_TO_Y = Rotation.from_matrix(up_rotation("+z"))     # z-up -> y-up: (x, y, z) -> (x, z, -y)

SPEC = {"inputs": (list, []), "out": (str, None), "body_model": (str, None), "up": (str, None),
        "scene": (str, None), "scene_id": (int, 0), "split": (str, "train"), "fps": (float, DATA_FPS),
        "action": (str, None), "overwrite": (bool, False)}
USAGE = "inputs=[a.npz,b.npz] out=DIR [body_model=PATH] [up=z|y]"


@dataclass
class AmassFile:
    """The body part of one AMASS-style file, as stored (float64)."""

    path: str
    global_orient: np.ndarray    # (T, 3) axis-angle
    body_pose: np.ndarray        # (T, 63) axis-angle
    transl: np.ndarray           # (T, 3) metres
    betas: np.ndarray            # (B,)
    fps: float
    layout: str                  # "smplx" | "smplh"
    gender: str
    up: str | None               # the file's own `up` key, None when absent (AMASS: z)


@dataclass
class ImportedAmass:
    joints: np.ndarray           # (T, 22, 3) float32, metres, y-up, floor at y = 0, at `fps`
    params: dict[str, np.ndarray]  # SMPLX_FIELDS: global_orient (T,3), body_pose (T,63), transl (T,3), betas (10,)
    fps: float
    source_fps: float
    layout: str
    gender: str
    up: str                      # the file's up axis as used
    up_from: str                 # "given" | "file" | "default (AMASS)"
    betas_used: int              # shape coefficients that entered the kinematics
    height: float                # rest skeleton: head joint above the lowest foot joint, metres


def _array(z, path: str, key: str) -> np.ndarray:
    try:
        return z[key]
    except ValueError:           # numpy refuses object arrays without allow_pickle
        raise DataError(path, key, "stored as a pickled object array, which is not read") from None


def _finite(a: np.ndarray, path: str, key: str) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        frame = int(np.argmax(bad.reshape(len(a), -1).any(1))) if a.ndim > 1 else int(np.argmax(bad))
        raise DataError(path, key, f"non-finite value (NaN or inf) at {'frame' if a.ndim > 1 else 'index'} {frame}")


def _text(z, path: str, key: str) -> str | None:
    if key not in z.files:
        return None
    v = _array(z, path, key)
    if v.ndim != 0 or v.dtype.kind not in "US":
        raise DataError(path, key, f"expected a string, found {v.dtype} array of shape {v.shape}")
    return (v.item().decode() if v.dtype.kind == "S" else str(v)).strip()


def load_amass(path: str | Path) -> AmassFile:
    """Read and validate one AMASS-style .npz (see the module doc). Raises DataError naming
    the file and the field."""
    path = str(path)
    if not Path(path).is_file():
        raise DataError(path, None, "AMASS file is missing")
    try:
        z = np.load(path, allow_pickle=False)
    except Exception as e:       # zipfile / format errors of all kinds
        raise DataError(path, None, f"not a readable .npz file ({type(e).__name__}: {e})") from None
    with z:
        for key in ("poses", "trans", "betas"):
            if key not in z.files:
                raise DataError(path, key, f"required AMASS array is missing (found: {', '.join(sorted(z.files))})")
        rate_key = next((k for k in RATE_KEYS if k in z.files), None)
        if rate_key is None:
            raise DataError(path, RATE_KEYS[0], f"frame rate is missing (expected {' or '.join(RATE_KEYS)})")
        poses, trans = _array(z, path, "poses"), _array(z, path, "trans")
        betas, rate = _array(z, path, "betas"), _array(z, path, rate_key)
        gender, up = _text(z, path, "gender") or "unknown", _text(z, path, "up")
    if poses.ndim != 2 or poses.shape[1] not in LAYOUTS or poses.dtype.kind not in "fi" or len(poses) == 0:
        raise DataError(path, "poses", f"expected (T, 165) SMPL-X or (T, 156) SMPL-H axis-angle with T >= 1, "
                                       f"found {poses.dtype} {poses.shape}")
    if trans.shape != (len(poses), 3) or trans.dtype.kind not in "fi":
        raise DataError(path, "trans", f"expected ({len(poses)}, 3) like poses, found {trans.dtype} {trans.shape}")
    if betas.ndim == 2 and betas.shape[0] == 1:
        betas = betas[0]
    if betas.ndim != 1 or betas.dtype.kind not in "fi":
        raise DataError(path, "betas", f"expected a vector (B,) of shape coefficients, found {betas.dtype} {betas.shape}")
    if rate.size != 1 or rate.dtype.kind not in "fi" or not np.isfinite(rate).all() or not float(rate) > 0:
        raise DataError(path, rate_key, f"expected a positive frame rate, found {rate!r}")
    for key, a in (("poses", poses), ("trans", trans), ("betas", betas)):
        _finite(a, path, key)
    if up is not None and up.lower() not in UPS:
        raise DataError(path, "up", f"expected 'y' or 'z', found {up!r}")
    poses = poses.astype(np.float64)
    return AmassFile(path, poses[:, :3], poses[:, 3:66], trans.astype(np.float64), betas.astype(np.float64),
                     float(rate), LAYOUTS[poses.shape[1]], gender, None if up is None else up.lower())


def parse_up(up: str) -> str:
    """'z' / 'Z' / 'y' -> 'z' / 'y'; anything else is a ConfigError."""
    if str(up).strip().lower() not in UPS:
        raise ConfigError(f"up={up!r}: expected z (AMASS) or y")
    return str(up).strip().lower()


def to_y_up(global_orient: np.ndarray, transl: np.ndarray, pelvis_rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """z-up root (T, 3) axis-angle and (T, 3) translation -> y-up. The root turns about the
    rest pelvis J0(β), not the origin: a world point p = G·x + J0 + transl becomes R·p, so the
    new root is R·G and the new translation R·(transl + J0) − J0."""
    go = (Z_TO_Y * Rotation.from_rotvec(global_orient)).as_rotvec()
    return go, Z_TO_Y.apply(transl + pelvis_rest) - pelvis_rest


def resample_params(rotvecs: np.ndarray, transl: np.ndarray, src_fps: float, dst_fps: float):
    """Rotations (T, J, 3) axis-angle by Slerp and translations (T, 3) by a cubic spline, from
    src_fps to dst_fps over the same duration (the grid of `bvh_import.resample`, `resample_times`)."""
    T = len(transl)
    if abs(src_fps - dst_fps) < 1e-3 * dst_fps or T < 2:
        return rotvecs, transl
    t_src, t_dst = resample_times(T, src_fps, dst_fps)
    t_dst = np.minimum(t_dst, t_src[-1])                               # Slerp refuses times past the end
    rot = np.stack([Slerp(t_src, Rotation.from_rotvec(rotvecs[:, j]))(t_dst).as_rotvec()
                    for j in range(rotvecs.shape[1])], 1)                # (T', J, 3)
    return rot, CubicSpline(t_src, transl, axis=0)(t_dst)


def amass_to_body(f: AmassFile, bm: BodyModel, fps: float = DATA_FPS, up: str | None = None) -> ImportedAmass:
    """One validated file -> y-up, resampled parameters and joints on the floor (see module doc).
    up: "z" | "y" overrides the file's `up` key; without either the file is AMASS, z-up."""
    if up is not None:
        up_axis, up_from = parse_up(up), "given"
    elif f.up is not None:
        up_axis, up_from = f.up, "file"
    else:
        up_axis, up_from = "z", "default (AMASS)"
    n = min(len(f.betas), bm.num_betas, NUM_BETAS)
    betas = np.zeros(NUM_BETAS, np.float32)
    betas[:n] = f.betas[:n]
    dt = bm.J_template.dtype
    b = torch.as_tensor(betas[: bm.num_betas], dtype=dt)
    rest = bm.rest_joints(b).double().numpy()                           # (22, 3)
    go, transl = (f.global_orient, f.transl) if up_axis == "y" else to_y_up(f.global_orient, f.transl, rest[0])
    rot = np.concatenate([go[:, None], f.body_pose.reshape(-1, 21, 3)], 1)   # (T, 22, 3)
    rot, transl = resample_params(rot, transl, f.fps, fps)
    T = len(transl)
    params = {"global_orient": rot[:, 0].astype(np.float32), "body_pose": rot[:, 1:].reshape(T, 63).astype(np.float32),
              "transl": transl.astype(np.float32)}
    # Joints from the float32 parameters as stored, so that FK(stored) == stored joints.
    with torch.no_grad():
        joints = bm.joints(*(torch.as_tensor(params[k], dtype=dt) for k in ("global_orient", "body_pose", "transl")),
                           b).double().numpy()                          # (T, 22, 3)
    floor = np.percentile(joints[:, list(FOOT_JOINTS), 1].min(1), FLOOR_PERCENTILE)
    joints[..., 1] -= floor
    params["transl"][:, 1] -= np.float32(floor)
    params["betas"] = betas
    height = float(rest[HEAD, 1] - rest[list(FOOT_JOINTS), 1].min())
    check_plausible(joints, height, f.path, f"up {up_axis} from {up_from}",
                    "check up= (AMASS files are z-up; motiongen exports record theirs)")
    return ImportedAmass(joints.astype(np.float32), params, float(fps), f.fps, f.layout, f.gender, up_axis, up_from,
                         n, height)


def _body_model(body_model) -> BodyModel:
    if isinstance(body_model, BodyModel):
        return body_model
    return load_body_model(body_model, num_betas=NUM_BETAS, dtype=torch.float64)


def import_amass(path: str | Path, body_model: BodyModel | str | Path | None = None, fps: float = DATA_FPS,
                 up: str | None = None) -> ImportedAmass:
    """`load_amass` + `amass_to_body`. body_model: a BodyModel, a model .npz path, or None
    (``$MOTIONGEN_SMPLX_MODEL``, else the procedural model)."""
    return amass_to_body(load_amass(path), _body_model(body_model), fps, up)


def parse_args(argv: list[str]) -> dict:
    return parse_key_values(argv, SPEC, required=("inputs", "out"), usage=USAGE, doc=__doc__)


def run(args: dict) -> Path:
    inputs = args["inputs"]
    if not inputs:
        raise ConfigError("inputs=[]: give at least one AMASS .npz file")
    refuse_over_sources(args)
    fps = require_fps("fps", args["fps"])        # the output rate: 1e9 asked for billions of frames
    up = parse_up(args["up"]) if args.get("up") else None
    bm = _body_model(args.get("body_model"))
    motions = load_clips(inputs, lambda path: import_amass(path, bm, fps, up))
    info = [{"name": name, "file": str(path), "layout": m.layout, "gender": m.gender, "up": m.up,
             "up_from": m.up_from, "source_fps": m.source_fps, "betas_used": m.betas_used,
             "height_m": round(m.height, 4)} for (name, m), path in zip(motions, inputs)]
    return write_clips(args, motions, fps, source="amass", smplx=True,
                       extra={"amass_import": {"body_model": str(bm.path), "sequences": info}})


main = tool_main(lambda argv: run(parse_args(argv)), lambda root: print(f"wrote {root}"))


if __name__ == "__main__":
    main()
