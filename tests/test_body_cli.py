"""The fitting CLI: `motiongen fit input=... out=...` (`motiongen/commands/fit_command.py`)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from motiongen.body.model import BodyModel
from motiongen.body.random_motion import sample_motion
from motiongen.commands.fit_command import main
from tests.helpers import user_error
from tests.run_inprocess import run_command

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def joints(model_path):
    bm = BodyModel(model_path)
    out = []
    for s in range(2):
        m = {k: torch.as_tensor(v) for k, v in sample_motion(30, 30.0, np.random.default_rng(s)).items()}
        with torch.no_grad():
            out.append(bm.joints(m["global_orient"], m["body_pose"], m["transl"], m["betas"]).numpy())
    return np.stack(out)                                           # (2, 30, 22, 3)


def test_fit_cli_samples_report_and_meshes(tmp_path, joints, model_path):
    src = tmp_path / "motion.npz"
    np.savez(src, joints=joints, fps=np.array(30.0))
    out = tmp_path / "fit"
    main([f"input={src}", f"out={out}", f"body.model_path={model_path}", "mlp=none", "mesh_max_frames=3"])
    report = json.loads((out / "report.json").read_text())
    assert report["procedural_body"] and report["init"] == "analytic" and len(report["samples"]) == 2
    for s, entry in enumerate(report["samples"]):
        assert entry["mpjpe_cm"] < 1.0 and entry["mpjpe_cm"] <= entry["mpjpe_init_cm"]
        with np.load(out / entry["params"]) as z:
            assert z["poses"].shape == (30, 165) and float(z["mocap_framerate"]) == 30.0
        meshes = sorted((out / entry["mesh_dir"]).glob("frame_*.obj"))
        assert len(meshes) == entry["mesh_frames"] == 3
    assert not [p for p in out.rglob(".*tmp*")]


def test_fit_cli_single_sequence_24_joints(tmp_path, joints, model_path):
    src = tmp_path / "one.npz"
    j24 = np.concatenate([joints[0], joints[0][:, 20:22]], 1)    # body+index1 layout
    np.savez(src, joints=j24)
    out = tmp_path / "fit"
    main([f"input={src}", f"out={out}", f"body.model_path={model_path}", "mlp=none", "mesh=false", "steps=10"])
    assert (out / "params.npz").is_file() and not (out / "mesh").exists()


def test_fit_cli_dataset_sequence(tmp_path, model_path):
    from helpers import make_dataset

    root = make_dataset(tmp_path / "ds", scenes=(1,), seqs_per_scene=1, T=20)
    out = tmp_path / "fit"
    main([f"input={root}", "seq=s1_0", f"out={out}", f"body.model_path={model_path}", "mlp=none", "mesh=false",
          "steps=5"])
    assert json.loads((out / "report.json").read_text())["samples"][0]["frames"] == 20


def test_fit_cli_user_errors(tmp_path, capsys, joints, model_path):
    ok = tmp_path / "ok.npz"
    np.savez(ok, joints=joints[0])
    base = [f"out={tmp_path / 'o'}", "mlp=none"]
    assert "does not exist" in user_error(capsys, main, [f"input={tmp_path / 'missing.npz'}"] + base)
    bad = tmp_path / "j21.npz"
    np.savez(bad, joints=joints[0][:, :21])
    assert "22" in user_error(capsys, main, [f"input={bad}"] + base)
    inf = tmp_path / "inf.npz"
    j = joints[0].copy()
    j[5, 3, 0] = np.inf                        # NaN is a missing joint (tests/test_prior_fit.py); inf an error
    np.savez(inf, joints=j)
    assert "infinite value at sample 0 frame 5" in user_error(capsys, main, [f"input={inf}"] + base)
    never = tmp_path / "never.npz"
    j = joints[0].copy()
    j[:, 7] = np.nan
    np.savez(never, joints=j)
    assert "left_ankle is missing (NaN) in every frame" in user_error(capsys, main, [f"input={never}"] + base)
    nokey = tmp_path / "nokey.npz"
    np.savez(nokey, positions=joints[0])
    assert "[joints]" in user_error(capsys, main, [f"input={nokey}"] + base)
    assert "not found" in user_error(capsys, main, [f"input={ok}", f"body.model_path={tmp_path / 'SMPLX.npz'}"] + base)
    assert "checkpoint" in user_error(capsys, main, [f"input={ok}", f"out={tmp_path / 'o'}", f"mlp={tmp_path / 'x.pt'}"])
    assert "unknown key" in user_error(capsys, main, [f"input={ok}", "bogus=1"] + base)
    assert "out" in user_error(capsys, main, [f"input={ok}"])
    assert "seq=" in user_error(capsys, main, [f"input={tmp_path}"] + base)


# Keys and inputs that used to give wrong results or a traceback with exit 0: (extra keys,
# how the joints are scaled, the message's words). Refused before anything is written.
FIT_BAD = [
    (["fps=0"], 1, "fps: expected a number > 0"),
    (["fps=-30"], 1, "fps: expected a number > 0"),
    (["fps=nan"], 1, "fps: expected a number > 0"),
    (["fps=1e9"], 1, "fps: expected a number > 0 and <= 1000"),
    (["steps=-1"], 1, "steps: expected an integer >= 0"),
    (["unit=km"], 1, "unit: expected one of m, cm, mm"),
    ([], 100, "look like centimetres or millimetres; pass unit=cm"),          # joints in cm
    (["unit=cm"], 1000, "look like centimetres or millimetres"),             # mm read as cm
    ([], 1e30, "from the origin with unit=m"),
]


@pytest.mark.parametrize("extra, scale, message", FIT_BAD)
def test_fit_cli_refuses_bad_keys_and_units(tmp_path, capsys, joints, extra, scale, message):
    inp = tmp_path / "in.npz"
    np.savez(inp, joints=joints[0] * scale)
    assert message in user_error(capsys, main, [f"input={inp}", f"out={tmp_path / 'o'}", "mlp=none", *extra])
    assert not (tmp_path / "o").exists()


def test_fit_cli_subprocess_exit_code(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    r = subprocess.run([sys.executable, "-m", "motiongen.commands.fit_command", f"input={tmp_path / 'nope.npz'}", f"out={tmp_path}"],
                       capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert r.returncode == 2 and r.stderr.startswith("error: ") and "Traceback" not in r.stderr


def test_train_mlp_entry_point(tmp_path, model_path, capsys):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "motiongen.commands.train_body_mlp_command", f"out={out}", "steps=4", "batch_size=16",
                        "log_every=2", "mlp.width=32", "data.num_sequences=2", "data.seq_frames=20",
                        f"body.model_path={model_path}", "threads=1", f"hydra.run.dir={tmp_path / 'hydra'}"],
                       capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    ckpt = torch.load(out / "mlp.pt", weights_only=True)
    assert ckpt["train_config"]["mlp"]["width"] == 32 and ckpt["mlp"]["width"] == 32
    assert any((out / "tb").iterdir())
    # The bad-input rows in-process (the run above checked the module entry point).
    for key, message in (("steps=0", "steps"), ("lr=-1", "lr: expected a number > 0"),
                         ("device=tpu", "device: expected cpu, cuda"), ("bogus=1", "unknown key")):
        bad = run_command("train-body-mlp", [key, f"out={out}", f"body.model_path={model_path}",
                                             f"hydra.run.dir={tmp_path / 'hydra'}"], capsys)
        lines = bad.stderr.strip().splitlines()
        assert bad.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], \
            bad.stderr
