"""sample.py end to end: outputs written atomically, and every bad input -> one line, exit 2."""

import json
import os
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.run_inprocess import run_command

ROOT = Path(__file__).resolve().parents[1]


def _checkpoint(path: Path) -> Path:
    """A checkpoint of a random-init very small model in train.py's format (the CLI's
    mechanics do not depend on training; tests/test_sampling.py covers the loop)."""
    from motiongen.data.windows import WindowConfig
    from motiongen.importers.sources import DataConfig
    from motiongen.diffusion import DiffusionConfig, MaskConfig
    from motiongen.models import build_model, model_config
    from motiongen.skeleton import BODY

    mcfg = model_config("tiny", width=32, layers=1, heads=2, ff=64, scene_width=32, scene_layers=1, scene_heads=2,
                        scene_ff=64, action_width=32, action_layers=1, action_heads=2, action_ff=64)
    torch.manual_seed(0)
    D = 66 + 4                                                   # pose + the default stance channels
    model = build_model(mcfg, 22, 2, 16, channels=D)
    center = np.zeros(D, np.float32)
    center[1:66:3] = 0.9
    half = np.full(D, 1.5, np.float32)
    half[66:] = 1.0
    cfg = {"model": asdict(mcfg), "diffusion": asdict(DiffusionConfig()), "window": asdict(WindowConfig()),
           "mask": asdict(MaskConfig()), "data": asdict(DataConfig(source="dataset", root=str(path.parent)))}
    state = {"format": "motiongen-checkpoint", "config": cfg, "step": 0, "joint_names": list(BODY.names),
             "action_names": ["walk", "sit"], "stats": {"center": center.tolist(), "half_range": half.tolist()},
             "ema": model.state_dict(), "model": model.state_dict()}
    torch.save(state, path)
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    ck = _checkpoint(d / "tiny.pt")
    import trimesh

    # A 4 x 4 m floor with a 1 m box at the centre and a wall splitting off z > 1.1.
    box = trimesh.creation.box([1.0, 1.0, 1.0], trimesh.transformations.translation_matrix([0, 0.5, 0]))
    wall = trimesh.creation.box([4.0, 1.5, 0.2], trimesh.transformations.translation_matrix([0, 0.75, 1.0]))
    floor = trimesh.creation.box([4.0, 0.02, 4.0], trimesh.transformations.translation_matrix([0, -0.01, 0]))
    scene = d / "room.obj"
    room = trimesh.util.concatenate([box, wall, floor])
    room.export(scene)
    room.apply_scale(100.0)
    room.export(d / "room_cm.obj")                       # the same room in centimetres
    (d / "bad.ckpt").write_bytes(b"not a checkpoint")
    diverged = torch.load(ck, weights_only=False)
    next(iter(diverged["ema"].values())).fill_(float("inf"))
    torch.save(diverged, d / "diverged.pt")
    (d / "goals.json").write_text(json.dumps({"goals": [[1.5, -1.0], {"xz": [-1.5, 0.5], "action": "sit", "duration": 0.5}]}))
    (d / "bad.json").write_text('{"goals": [[1.0]]}')
    return {"ckpt": ck, "scene": scene, "dir": d}


def _popen(args, env_extra):
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1", **env_extra)
    return subprocess.Popen([sys.executable, str(ROOT / "sample.py"), *args], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_end_to_end_writes_all_outputs(files, tmp_path):
    out = tmp_path / "out"
    p = _popen([f"ckpt={files['ckpt']}", f"scene={files['scene']}", "start=[-1.5,-1.5]",
                f"goals_file={files['dir'] / 'goals.json'}", "steps=2", "num_samples=2", "bvh=true",
                "loop.max_episodes=6", "loop.warmup=1", "video_fps=5", f"out={out}", "threads=1"],
               {"MOTIONGEN_CACHE": os.environ["MOTIONGEN_CACHE"]})
    stdout, stderr = p.communicate(timeout=300)
    assert p.returncode == 3, stderr[-2000:]            # all written; the random model reached no goal
    names = sorted(f.name for f in out.iterdir())
    video = "motion.mp4" if "motion.mp4" in names else "motion.gif"
    assert names == sorted(["motion.npz", video, "trajectories.png", "summary.json", "motion_0.bvh", "motion_1.bvh",
                            ".motiongen-outputs.json"])                   # the manifest of this output set
    with np.load(out / "motion.npz", allow_pickle=False) as z:
        assert z["joints"].shape[0] == 2 and z["joints"].shape[2:] == (22, 3) and float(z["fps"]) == 30.0
        assert z["goals"].shape == (2, 2) and list(z["goal_actions"]) == ["", "sit"]
        assert z["actions"].shape == z["joints"].shape[:2] and z["path"].shape[1] == 2
        assert z["episode_starts"][0] == 0 and z["arrival_error"].shape == (2, 2)
        # the video's camera, one per output frame, kept so the shot can be reproduced
        T = z["joints"].shape[1]
        assert z["camera_position"].shape == z["camera_target"].shape == (T, 3) and str(z["camera_mode"]) == "adaptive"
        assert np.all(np.abs(z["camera_position"][:, 1] - 1.4) < 1e-6)        # the ring camera's height
    assert "real-time factor" in stdout and "goal 1" in stdout
    from motiongen.commands.fit_command import load_input  # the fitting tool reads it

    joints, fps, _ = load_input({"input": str(out / "motion.npz")})
    assert joints.shape[0] == 2 and fps == 30.0


BAD = {
    "goal_in_obstacle": (["goals=[[0.0,0.0]]"], "inside an obstacle"),
    "goal_outside": (["goals=[[9.0,0.0]]"], "outside the scene bounds"),
    "no_path": (["goals=[[0.0,1.6]]"], "no collision-free path"),
    "unknown_action": (["goals=[[1.5,-1.0]]", "actions=[dance]"], "unknown action 'dance'"),
    "bad_ckpt": (["goals=[[1.5,-1.0]]", "ckpt={dir}/bad.ckpt"], "not a readable checkpoint"),
    "missing_ckpt": (["goals=[[1.5,-1.0]]", "ckpt={dir}/none.pt"], "checkpoint file does not exist"),
    "missing_scene": (["goals=[[1.5,-1.0]]", "scene={dir}/nothing.obj"], "scene mesh file or folder is missing"),
    "bad_goals_file": (["goals_file={dir}/bad.json"], "goals[0]"),
    "bad_precision": (["goals=[[1.5,-1.0]]", "precision=fp16"], "precision: expected one of fp32, bf16, int8, int8-encoders, auto"),
    "int8_on_gpu": (["goals=[[1.5,-1.0]]", "precision=int8", "device=cuda"], "precision=int8: int8 layers run on the CPU only"),
    "bad_camera": (["goals=[[1.5,-1.0]]", "video_camera=orbit"], "video_camera: expected one of adaptive, follow, top"),
    "diverged_ckpt": (["goals=[[1.5,-1.0]]", "ckpt={dir}/diverged.pt"], "diverged.pt [ema]: non-finite weights"),
    "goal_far": (["goals=[[1e300,0.0]]"], "goals[0]: expected a point [x, z] of two numbers within"),
    "negative_duration": (["goals=[[1.5,-1.0]]", "durations=[-5]"], "durations[0]: expected a number >= 0"),
    "scene_up": (["goals=[[1.5,-1.0]]", "scene_up=x"], "scene_up: expected one of y, z"),
    "bad_solve": (["goals=[[1.5,-1.0]]", "loop.solve=newton"], "loop.solve: expected one of lbfgs, joint-space, refined"),
    "bad_foot_height": (["goals=[[1.5,-1.0]]", "loop.foot_height=floor"], "loop.foot_height: expected one of network, body, free"),
    "scene_in_cm": (["goals=[[1.5,-1.0]]", "scene={dir}/room_cm.obj"], "use scene_unit=cm"),
}


@pytest.mark.parametrize("name", list(BAD))
def test_bad_inputs_exit_2_with_one_line(files, tmp_path, capsys, name):
    extra, needle = BAD[name]
    args = [f"ckpt={files['ckpt']}", f"scene={files['scene']}", "start=[-1.5,-1.5]", f"out={tmp_path / name}"]
    r = run_command("sample", args + [a.format(dir=files["dir"]) for a in extra], capsys)
    assert r.returncode == 2, r.stderr[-1500:]
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr[-1500:]
    assert needle in lines[0], lines[0]
    out = tmp_path / name
    assert not out.exists() or not any(out.iterdir()), list(out.iterdir())


def test_obstacle_faces_hide_shared_sides():
    """Two adjacent equal columns expose 2 tops + 6 sides (the shared pair is hidden)."""
    from motiongen.export.obstacles import obstacle_faces
    cols = np.array([[0.1, 0.1, 1.0], [0.3, 0.1, 1.0]])
    corners, normals, shade = obstacle_faces(cols, 0.2)
    assert corners.shape == (8, 4, 3) and (normals[:, 1] == 1).sum() == 2
    assert not ((normals[:, 0] == 1) & np.isclose(corners[:, 0, 0], 0.2)).any()   # no face on the shared wall
    taller = obstacle_faces(np.array([[0.1, 0.1, 1.0], [0.3, 0.1, 0.5]]), 0.2)[0]
    assert len(taller) == 9                                                        # the taller column's side shows


def test_checkpoints_from_before_the_body_changes_load_as_they_were_trained(tmp_path):
    """A checkpoint whose config predates window.representation / stance channels /
    mask.predict_goal holds absolute joints (66 channels) and pinned goals: it must load as
    such, not with today's defaults."""
    from motiongen.loading.build import load_model

    path = _checkpoint(tmp_path / "new.pt")
    state = torch.load(path, weights_only=False)
    for k in ("representation", "contact_joints", "stance_speed"):
        state["config"]["window"].pop(k)
    state["config"]["mask"].pop("predict_goal")
    from motiongen.models import build_model, model_config
    mcfg = model_config("tiny", **{k: v for k, v in state["config"]["model"].items() if k != "name"})
    old = build_model(mcfg, 22, 2, 16)                                         # 66 channels, as then
    state["ema"] = state["model"] = old.state_dict()
    state["stats"] = {"center": state["stats"]["center"][:66], "half_range": state["stats"]["half_range"][:66]}
    torch.save(state, tmp_path / "old.pt")
    ld = load_model(tmp_path / "old.pt")
    assert ld.layout.channels == 66 and ld.layout.representation == "absolute" and not ld.predict_goal
    assert ld.fps == 30.0                                                      # no fps recorded: the old assumption
    assert ld.model_fps == 10.0                                                # the data rate: 30 fps, every 3rd frame
    new = load_model(path)
    assert new.layout.channels == 70 and new.predict_goal


def test_default_output_directory_is_a_timestamped_run_dir(files, tmp_path):
    """Without out=, outputs go to runs/sample/<date_time>/ under the working directory (the
    config's `${mg.default:${out},...}`; `oc.select` returned None for `out: null` and Hydra
    stopped with a traceback before this was fixed)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    r = subprocess.run([sys.executable, str(ROOT / "sample.py"), f"ckpt={files['ckpt']}", "video=false",
                        "goals=[[0.5,0.5]]", "loop.max_episodes=2"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 3, r.stderr                   # all written; the random model reached no goal
    runs = list((tmp_path / "runs" / "sample").iterdir())
    assert len(runs) == 1 and (runs[0] / "motion.npz").is_file() and (runs[0] / "summary.json").is_file()


def test_scene_unit_scales_the_mesh_to_metres(files, tmp_path):
    """scene_unit=cm reads the centimetre room as the metre one (the grid is the same)."""
    from motiongen.scene.mesh_files import load_scene_grid

    m = load_scene_grid(files["scene"], voxel_size=0.05, use_cache=False)
    cm = load_scene_grid(files["dir"] / "room_cm.obj", voxel_size=0.05, use_cache=False, unit="cm")
    assert m.shape == cm.shape and np.allclose(m.origin, cm.origin) and np.array_equal(m.bits, cm.bits)


def test_int8_layers_sample_end_to_end_and_say_so(files, tmp_path, capsys):
    """precision=int8 from the command line: the run completes on quantized layers and
    summary.json and motion.npz record the precision that ran."""
    out = tmp_path / "int8"
    r = run_command("sample", [f"ckpt={files['ckpt']}", f"scene={files['scene']}", "start=[-1.5,-1.5]",
                               "goals=[[1.5,-1.0]]", "precision=int8", "video=false", "plot=false", "steps=2",
                               "loop.max_episodes=2", f"out={out}", "threads=1"], capsys)
    assert r.returncode in (0, 3), r.stderr[-2000:]                # 3: the random model reached no goal
    assert "int8 layers" in r.stdout
    assert json.loads((out / "summary.json").read_text())["precision"] == "int8"
    with np.load(out / "motion.npz", allow_pickle=False) as z:
        assert str(z["precision"]) == "int8" and np.isfinite(z["joints"]).all()
