"""Fit SMPL-X body parameters to joint trajectories.

    motiongen fit input=motion.npz out=DIR [body.model_path=SMPLX_NEUTRAL.npz]
        [mlp=auto|none|PATH] [steps=40] [mesh=auto|true|false] [mesh_format=obj|glb]
        [mesh_max_frames=60] [fps=30] [unit=m|cm|mm] [device=cpu]
        [foot_vel.weight=0] [foot_vel.a=0.1] [foot_vel.z_thres=0.1] [foot_vel.mask=height|contact] [floor_y=0]
        [motion_prior.smooth=PATH] [motion_prior.infill=PATH] [motion_prior.w_smooth=...]
        [motion_prior.w_infill=1] [motion_prior.steps=30]
    motiongen fit input=DATASET_DIR seq=NAME out=DIR ...

`input` is a joints npz (key `joints`: (T, 22, 3) or (S, T, 22, 3); 24 joints = body+index1
are accepted and the first 22 used; optional key `fps`) or a motiongen dataset directory
with `seq`; `unit` is the joints' length unit (scaled to metres). Writes `params.npz` (or `params_s{i}.npz` per sample; AMASS SMPL-X layout, see
`motiongen.body.fit.save_amass_npz`), `report.json` (MPJPE before/after refinement) and, with
the procedural body model (or mesh=true), a per-frame mesh sequence under `mesh/`.
`foot_vel.weight` > 0 adds LEMO's foot velocity term (`motiongen.body.foot_velocity`):
feet within `foot_vel.z_thres` m of `floor_y` (mask=height) or flagged by contact labels
(mask=contact: the dataset sequence's `contact.npy`, or the npz key `contact`) are held below
`foot_vel.a` m/s.

A NaN joint in `input` is a joint not observed at that frame (occluded, not detected): the fit
fills it by linear interpolation over time and fits the observed joints. `motion_prior.smooth`
and `motion_prior.infill` name LEMO motion priors (`motiongen train-motion-prior`): the
smoothness prior's latent term replaces the joint-acceleration term, and the infilling prior
fills the markers of the missing joints (`motiongen.capture.prior_fit`). MPJPE in the report is
then measured on the observed joints.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np

from motiongen.body.fit import RefineConfig, default_mlp, fit_joints, save_amass_npz
from motiongen.body.model import load_body_model
from motiongen.body.train_mlp import load_mlp
from motiongen.capture.prior_fit import MotionPriorConfig, PriorTerms, fill_linear, fit_observed
from motiongen.checks import require_choice, require_fps, require_range
from motiongen.cli import parse_key_values, tool_main
from motiongen.data.format import MotionDataset
from motiongen.errors import ConfigError, DataError
from motiongen.metrics import foot_skating_ratio
from motiongen.output_lock import OutputLock, refuse_output_over_input
from motiongen.rates import DATA_FPS
from motiongen.skeleton import FOOT_JOINTS, NUM_BODY_JOINTS
from motiongen.staging import StagedOutputs, record_outputs

_MP = MotionPriorConfig()        # the motion priors' defaults live there, once
# The files a fit writes (report.json, params.npz or params_s<i>.npz).
OUTPUT_NAMES = re.compile(r"report\.json|params(_s\d+)?\.npz")

SPEC = {"input": (str, None), "out": (str, None), "seq": (str, None), "body.model_path": (str, None),
        "body.num_betas": (int, 10), "mlp": (str, "auto"), "steps": (int, None), "mesh": (str, "auto"),
        "mesh_format": (str, "obj"), "mesh_max_frames": (int, 60), "fps": (float, None), "device": (str, "cpu"),
        "foot_vel.weight": (float, 0.0), "foot_vel.a": (float, 0.10), "foot_vel.z_thres": (float, 0.10),
        "foot_vel.mask": (str, "height"), "floor_y": (float, 0.0), "unit": (str, "m"),
        "motion_prior.smooth": (str, None), "motion_prior.infill": (str, None),
        "motion_prior.w_smooth": (float, _MP.w_smooth), "motion_prior.w_infill": (float, _MP.w_infill),
        "motion_prior.steps": (int, _MP.steps)}
UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}
# The two farthest joints of one frame of a person (arms raised: about 2.3 m); joints farther
# apart than this are in centimetres or millimetres (the fit then reported 16 m errors).
MAX_BODY_EXTENT_M = 3.0
MAX_COORD_M = 1e4                # metres from the origin: beyond, a typo or garbage (1e30)


def parse_args(argv: list[str]) -> dict:
    opts = parse_key_values(argv, SPEC, required=("input", "out"), usage="motiongen fit input=motion.npz out=DIR",
                            doc=__doc__)
    require_range("steps", opts["steps"], 0, 100000, integer=True, allow_none=True)   # 0: the MLP's guess alone
    require_fps("fps", opts["fps"], allow_none=True)
    require_range("mesh_max_frames", opts["mesh_max_frames"], 0, integer=True)
    require_range("floor_y", opts["floor_y"], -MAX_COORD_M, MAX_COORD_M)
    require_choice("unit", opts["unit"], UNITS_M)
    return opts


def joints_in_metres(joints: np.ndarray, unit: str, desc: str) -> np.ndarray:
    """The joints scaled from `unit` to metres, refused when their size says the unit is wrong."""
    joints = joints * np.float32(UNITS_M[unit])
    seen = np.isfinite(joints).all(-1)                                   # (S, T, 22): NaN is a missing joint
    if not seen.any():
        raise DataError(desc, "joints", "every joint is missing (NaN)")
    far = float(np.abs(joints[seen]).max())
    if far > MAX_COORD_M:
        raise DataError(desc, "joints", f"a joint {far:.3g} m from the origin with unit={unit} (at most "
                                        f"{MAX_COORD_M:g} m): not joint positions")
    frames = seen.sum(-1) >= 2                                           # (S, T) frames with a size
    lo = np.where(seen[..., None], joints, np.inf).min(2)
    hi = np.where(seen[..., None], joints, -np.inf).max(2)               # (S, T, 3)
    extent = float(np.median((hi - lo).max(-1)[frames])) if frames.any() else 0.0
    if extent > MAX_BODY_EXTENT_M:
        raise DataError(desc, "joints", f"a body {extent:.3g} m across with unit={unit} (at most "
                                        f"{MAX_BODY_EXTENT_M:g} m): the joints look like centimetres or "
                                        f"millimetres; pass unit=cm or unit=mm")
    return joints


def load_input(opts: dict) -> tuple[np.ndarray, float, str]:
    """-> joints (S, T, 22, 3) float32, fps, description."""
    path = Path(opts["input"])
    if path.is_dir():
        if not opts["seq"]:
            raise ConfigError("input is a dataset directory: name the sequence with seq=NAME")
        ds = MotionDataset.open(path)
        seq = next((s for s in ds.sequences if s.name == opts["seq"]), None)
        if seq is None:
            raise DataError(path / "sequences.json", opts["seq"], "no sequence with this name")
        joints = np.asarray(ds.joints[seq.start:seq.end], np.float32)[None, :, :NUM_BODY_JOINTS]
        return joints, ds.fps, f"{path}:{seq.name}"
    if not path.is_file():
        raise DataError(path, None, "input file does not exist")
    try:
        with np.load(path, allow_pickle=False) as z:
            if "joints" not in z.files:
                raise DataError(path, "joints", f"required key is missing (keys: {', '.join(z.files)})")
            joints = np.asarray(z["joints"])
            fps = float(z["fps"]) if "fps" in z.files else DATA_FPS
    except DataError:
        raise
    except Exception as e:
        raise DataError(path, None, f"not a readable .npz file ({type(e).__name__}: {e})") from None
    if joints.ndim == 3:
        joints = joints[None]
    if joints.ndim != 4 or joints.shape[-1] != 3 or joints.shape[1] < 1:
        raise DataError(path, "joints", f"expected shape (T, 22, 3) or (S, T, 22, 3), found {joints.shape}")
    if joints.shape[2] not in (NUM_BODY_JOINTS, NUM_BODY_JOINTS + 2):
        raise DataError(path, "joints", f"expected {NUM_BODY_JOINTS} SMPL-X body joints (or 24 with index1), "
                                        f"found {joints.shape[2]}")
    if not np.issubdtype(joints.dtype, np.floating):
        raise DataError(path, "joints", f"expected floating point values, found {joints.dtype}")
    joints = joints[:, :, :NUM_BODY_JOINTS].astype(np.float32)
    bad = np.isinf(joints).any(axis=(2, 3))
    if bad.any():                        # NaN is a joint not observed (filled by the fit); inf is an error
        s, t = np.argwhere(bad)[0]
        raise DataError(path, "joints", f"infinite value at sample {s} frame {t} (a missing joint is NaN)")
    if not (math.isfinite(fps) and fps > 0):
        raise DataError(path, "fps", f"expected a positive number, found {fps}")
    return joints, fps, str(path)


def load_contact(opts: dict, S: int, T: int) -> np.ndarray:
    """(S, T, 4) bool contact labels of `skeleton.FOOT_JOINTS` for foot_vel.mask=contact: the
    dataset sequence's `contact.npy` rows, or the input npz's key `contact` — (T, J) or
    (S, T, J) with J = 22 or 24 joints (the foot joints' columns are taken), or (T, 4) /
    (S, T, 4) in FOOT_JOINTS order (left ankle, left toe, right ankle, right toe)."""
    path = Path(opts["input"])
    if path.is_dir():
        ds = MotionDataset.open(path, check_values=False)
        seq = next(s for s in ds.sequences if s.name == opts["seq"])
        return np.asarray(ds.contact[seq.start:seq.end])[None][..., list(FOOT_JOINTS)]
    with np.load(path, allow_pickle=False) as z:
        if "contact" not in z.files:
            raise DataError(path, "contact", "foot_vel.mask=contact needs contact labels: key 'contact' (T, 22) bool "
                                             "is missing (or use foot_vel.mask=height)")
        c = np.asarray(z["contact"])
    if c.ndim == 2:
        c = c[None]
    widths = {NUM_BODY_JOINTS: True, NUM_BODY_JOINTS + 2: True, len(FOOT_JOINTS): False}
    if c.ndim != 3 or c.shape[:2] != (S, T) or c.shape[2] not in widths or c.dtype.kind not in "bui":
        raise DataError(path, "contact", f"expected bool ({T}, 22), ({T}, 24) or ({T}, 4) like the joints "
                                         f"({S} sample(s) of {T} frames), found {c.dtype} {c.shape}")
    c = c.astype(bool)
    return c[..., list(FOOT_JOINTS)] if widths[c.shape[2]] else c


def export_meshes(bm, fit, out_dir: Path, fmt: str, max_frames: int) -> list[Path]:
    """Per-frame meshes (every k-th frame, at most max_frames) -> the files written."""
    import trimesh  # trimesh's exporters load only when meshes are written

    T = fit.transl.shape[0]
    stride = max(1, math.ceil(T / max(max_frames, 1)))
    frames = list(range(0, T, stride))
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for i in range(0, len(frames), 32):
        idx = frames[i:i + 32]
        for t, v in zip(idx, bm.motion_vertices(fit, idx)):
            mesh = trimesh.Trimesh(v, bm.faces, process=False)
            tmp = out_dir / f".frame_{t:05d}.{os.getpid()}.tmp.{fmt}"
            mesh.export(tmp, file_type=fmt)
            os.replace(tmp, out_dir / f"frame_{t:05d}.{fmt}")
            written.append(out_dir / f"frame_{t:05d}.{fmt}")
    return written


def refuse_over_inputs(opts: dict, out: Path) -> None:
    """The outputs may not replace what the run reads: a dataset directory is not an output
    directory, and an input file named like an output is not overwritten."""
    inp = Path(opts["input"])
    if inp.is_dir():
        refuse_output_over_input(out, [inp], "out")
    for path in (inp, opts["mlp"], opts["body.model_path"]):
        if path and OUTPUT_NAMES.fullmatch(Path(path).name):
            refuse_output_over_input(out / Path(path).name, [path], "out")


def run(argv: list[str]) -> dict:
    opts = parse_args(argv)
    joints, fps, desc = load_input(opts)
    joints = joints_in_metres(joints, opts["unit"], desc)
    out = Path(opts["out"])
    refuse_over_inputs(opts, out)
    with OutputLock(out, "fit"):                     # one live run per output directory
        return fit_and_write(opts, out, joints, fps, desc)


def fit_and_write(opts: dict, out: Path, joints: np.ndarray, fps: float, desc: str) -> dict:  # long: the steps in order
    """The fit of every sample; params, report and meshes written to `out`, replacing the set a
    previous fit wrote there."""
    if opts["fps"] is not None:
        fps = opts["fps"]
    if opts["mesh"] not in ("auto", "true", "false"):
        raise ConfigError(f"mesh: expected auto, true or false, got {opts['mesh']!r}")
    if opts["mesh_format"] not in ("obj", "glb", "ply"):
        raise ConfigError(f"mesh_format: expected obj, glb or ply, got {opts['mesh_format']!r}")
    bm = load_body_model(opts["body.model_path"], num_betas=opts["body.num_betas"], device=opts["device"])
    priors = MotionPriorConfig(smooth=opts["motion_prior.smooth"], infill=opts["motion_prior.infill"],
                               w_smooth=opts["motion_prior.w_smooth"], w_infill=opts["motion_prior.w_infill"],
                               steps=opts["motion_prior.steps"])
    priors.check()
    terms = PriorTerms(bm, priors) if priors.any else None    # read before the MLP: a bad path fails fast
    mlp = opts["mlp"]
    if mlp in ("none", "None", "null", ""):
        mlp = None
    elif mlp != "auto":
        if not Path(mlp).is_file():
            raise DataError(mlp, None, "MLP checkpoint not found (use mlp=auto or mlp=none)")
        mlp = load_mlp(mlp, device=opts["device"])
    if mlp == "auto":
        print("preparing the default joints->SMPL-X MLP (trained once, then cached)...", flush=True)
        mlp = default_mlp(bm, verbose=False)
    cfg = RefineConfig(w_foot_vel=opts["foot_vel.weight"], foot_vel_a=opts["foot_vel.a"],
                       foot_z_thres=opts["foot_vel.z_thres"], foot_vel_mask=opts["foot_vel.mask"],
                       floor_y=opts["floor_y"])
    if opts["steps"] is not None:
        cfg.max_steps = opts["steps"]
    if cfg.w_foot_vel < 0 or cfg.foot_vel_a < 0:
        raise ConfigError("foot_vel.weight and foot_vel.a must be >= 0")
    if cfg.foot_vel_mask not in ("height", "contact"):
        raise ConfigError(f"foot_vel.mask={cfg.foot_vel_mask!r}: expected height or contact")
    contact = None
    if cfg.w_foot_vel and cfg.foot_vel_mask == "contact":
        contact = load_contact(opts, joints.shape[0], joints.shape[1])
    S = joints.shape[0]
    do_mesh = opts["mesh"] == "true" or (opts["mesh"] == "auto" and bm.is_procedural)
    report = {"input": desc, "fps": fps, "body_model": str(bm.path), "procedural_body": bm.is_procedural,
              "init": None, "samples": []}
    missing = int((~np.isfinite(joints).all(-1)).sum())
    if missing or priors.any:
        report["missing_joints"] = missing
        report["motion_prior"] = {"smooth": priors.smooth, "infill": priors.infill, "w_smooth": priors.w_smooth,
                                  "w_infill": priors.w_infill, "steps": priors.steps}
    if cfg.w_foot_vel:
        report["foot_velocity"] = {"weight": cfg.w_foot_vel, "a": cfg.foot_vel_a, "z_thres": cfg.foot_z_thres,
                                   "mask": cfg.foot_vel_mask, "floor_y": cfg.floor_y}
    stage, meshes = StagedOutputs(out), []
    try:
        for s in range(S):
            meshes += _fit_sample(opts, stage, report, s, joints, fps, bm, mlp, cfg, contact, do_mesh, terms)
        stage.tmp("report.json").write_text(json.dumps(report, indent=2))
        written = stage.commit()
    except BaseException:
        stage.abort()
        raise
    record_outputs(out, "fit", written + meshes, keep=[opts["input"]])   # the previous fit's extra files go
    return report


def _fit_sample(opts: dict, stage: StagedOutputs, report: dict, s: int, joints: np.ndarray, fps: float, bm, mlp,
                cfg: RefineConfig, contact, do_mesh: bool, terms: PriorTerms | None) -> list[Path]:
    """Sample `s` fitted, its params staged and its entry added to `report`; the mesh files written.
    terms: the loaded motion priors, or None."""
    out, S = stage.out, joints.shape[0]
    c = None if contact is None else contact[s]
    if terms is None and np.isfinite(joints[s]).all():
        fit = fit_joints(joints[s], bm, mlp, config=cfg, device=opts["device"], fps=fps, contact=c)
    else:
        fit = fit_observed(joints[s], bm, mlp, priors=terms.cfg if terms else MotionPriorConfig(), terms=terms,
                           config=cfg, contact=c, device=opts["device"], fps=fps, desc=f"{opts['input']} sample {s}")
    name = "params.npz" if S == 1 else f"params_s{s:02d}.npz"
    stage.add(save_amass_npz(stage.tmp(name), fit, fps), name)
    entry = {"sample": s, "frames": int(joints.shape[1]), "params": name,
             "mpjpe_mlp_cm": None if fit.mpjpe_mlp is None else round(fit.mpjpe_mlp * 100, 4),
             "mpjpe_init_cm": round(fit.mpjpe_init * 100, 4), "mpjpe_cm": round(fit.mpjpe * 100, 4),
             "max_frame_error_cm": round(float(np.nanmax(fit.per_frame_error)) * 100, 4),
             "steps": fit.steps, "seconds": round(fit.seconds, 3),
             "foot_skating": {"input": round(foot_skating_ratio(fill_linear(joints[s])[0], fps), 4),
                              "fit": round(foot_skating_ratio(fit.joints, fps), 4)}}
    report["init"] = fit.init
    meshes = []
    if do_mesh:
        mdir = out / ("mesh" if S == 1 else f"mesh_s{s:02d}")
        entry["mesh_dir"] = mdir.name
        meshes = export_meshes(bm, fit, mdir, opts["mesh_format"], opts["mesh_max_frames"])
        entry["mesh_frames"] = len(meshes)
    report["samples"].append(entry)
    mlp_txt = "" if fit.mpjpe_mlp is None else f"MLP alone {entry['mpjpe_mlp_cm']:.2f} cm, "
    print(f"sample {s}: {entry['frames']} frames, MPJPE {mlp_txt}init ({fit.init}) {entry['mpjpe_init_cm']:.2f} cm -> "
          f"refined {entry['mpjpe_cm']:.3f} cm ({fit.steps} steps, {fit.seconds:.2f} s) -> {out / name}",
          flush=True)
    return meshes


main = tool_main(run)


if __name__ == "__main__":
    main()
