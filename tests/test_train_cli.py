"""train.py end to end: smoke run, SIGKILL + resume equality, 2-process DDP, user errors."""

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from motiongen.data.swing_rise import EMBEDDED
from motiongen.loading.build import load_model
from tests.helpers import make_dataset
from tests.run_inprocess import run_command

ROOT = Path(__file__).resolve().parents[1]
# A very small model so each step takes milliseconds; dropout stays on (RNG must resume too).
TINY = ["model.width=32", "model.layers=1", "model.heads=2", "model.ff=64", "model.scene_width=32",
        "model.scene_layers=1", "model.scene_heads=2", "model.scene_ff=64", "model.action_width=32",
        "model.action_layers=1", "model.action_heads=2", "model.action_ff=64"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("ds") / "ds", scenes=(1, 2, 71, 91), seqs_per_scene=2, T=150)


def _args(dataset, run_dir, steps, **over):
    a = ["data=dataset", f"data.root={dataset}", f"hydra.run.dir={run_dir}", f"train.max_steps={steps}",
         "train.batch_size=8", "train.num_workers=0", "train.log_every=2", "train.val_every=0",
         "train.figure_every=0", "train.ckpt_every=3", "train.progress=false", "train.threads=1", *TINY]
    a += [f"{k}={v}" for k, v in over.items()]
    return a


def _run(args, **kw):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, str(ROOT / "train.py"), *args], capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=600, **kw)


def _weights(path):
    ck = torch.load(path, map_location="cpu", weights_only=False)
    return ck


def test_smoke_run_writes_events_and_checkpoint(dataset, tmp_path):
    r = _run(_args(dataset, tmp_path, 4, **{"train.val_every": 2, "train.figure_every": 4}))
    assert r.returncode == 0, r.stderr[-2000:]
    ck = _weights(tmp_path / "checkpoints" / "last.pt")
    assert ck["step"] == 4 and ck["format"] == "motiongen-checkpoint"
    assert ck["joint_names"][0] == "pelvis" and ck["action_names"] == ["walk", "sit"]
    assert ck["config"]["model"]["width"] == 32 and len(ck["stats"]["center"]) == 66 + 4   # pose + stance
    assert ck["fps"] == 30.0                                 # the data's frame rate travels with the model
    events = list((tmp_path / "tb").glob("events.out.tfevents.*"))
    assert events
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    acc = EventAccumulator(str(tmp_path / "tb"), size_guidance={"images": 0}).Reload()
    tags = acc.Tags()
    for t in ("train/loss", "train/lr", "train/grad_norm", "train/samples_per_s", "val/loss"):
        assert t in tags["scalars"], (t, tags["scalars"])
    assert "samples/windows" in tags["images"]


def test_the_checkpoint_carries_the_datas_swing_table(dataset, tmp_path):
    """The tiny dataset's walks have no swing between two plants to measure: no table, and the
    sampler takes the embedded one. A checkpoint with a table gives it to the sampler as saved."""
    r = _run(_args(dataset, tmp_path, 1))
    assert r.returncode == 0, r.stderr[-2000:]
    ck = _weights(tmp_path / "checkpoints" / "last.pt")
    assert "swing_rise" not in ck and load_model(tmp_path / "checkpoints" / "last.pt").swing_rise is None
    ck["swing_rise"] = EMBEDDED.state_dict()
    torch.save(ck, tmp_path / "with_table.pt")
    got = load_model(tmp_path / "with_table.pt").swing_rise
    assert got.state_dict() == EMBEDDED.state_dict()


def test_sigkill_then_resume_is_bitwise_identical(dataset, tmp_path):
    steps = 40   # long enough that the kill after the first checkpoint lands mid-run, even under load
    ref = _run(_args(dataset, tmp_path / "ref", steps))
    assert ref.returncode == 0, ref.stderr[-2000:]

    run = tmp_path / "killed"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen([sys.executable, str(ROOT / "train.py"), *_args(dataset, run, steps)], cwd=ROOT, env=env,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    # last.pt is linked just after the step file is renamed in: wait for the link, or a kill
    # between the two leaves a run with no checkpoint yet (a fresh start, not a resume)
    while not (run / "checkpoints" / "last.pt").exists():
        assert p.poll() is None and time.time() < deadline, "training ended before the first checkpoint"
        time.sleep(0.01)
    p.send_signal(signal.SIGKILL)
    p.wait()
    assert (run / "checkpoints" / "last.pt").exists()
    assert _weights(run / "checkpoints" / "last.pt")["step"] < steps
    res = _run(_args(dataset, run, steps, **{"train.resume": "auto"}))
    assert res.returncode == 0, res.stderr[-2000:]
    a, b = _weights(tmp_path / "ref" / "checkpoints" / "last.pt"), _weights(run / "checkpoints" / "last.pt")
    assert a["step"] == b["step"] == steps
    for part in ("model", "ema"):
        for k in a[part]:
            assert torch.equal(a[part][k], b[part][k]), (part, k)
    sa, sb = a["optimizer"]["state"], b["optimizer"]["state"]
    for i in sa:
        assert torch.equal(sa[i]["exp_avg_sq"], sb[i]["exp_avg_sq"])


def _free_port() -> int:
    """A TCP port nothing listens on now (a fixed one was once taken on a busy host)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("per_rank", [1, 4])
def test_two_process_ddp(dataset, tmp_path, per_rank):
    """2 processes, heavy condition dropout: whole batches without a condition on one rank
    and not the other (batch 1 per rank: every other step). Before the fix DDP stopped with
    "Expected to have finished reduction" within a few steps; now 30 steps run and both ranks
    end with bitwise equal weights (checked at every checkpoint)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    args = _args(dataset, tmp_path, 30, **{"train.batch_size": 2 * per_rank, "train.cond_drop_scene": 0.5,
                                           "train.cond_drop_actions": 0.5, "train.ckpt_every": 10})
    r = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--nproc_per_node=2",
                        f"--master_port={_free_port()}", str(ROOT / "train.py"), *args],
                       capture_output=True, text=True, env=env, cwd=ROOT, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    ck = _weights(tmp_path / "checkpoints" / "last.pt")
    assert ck["step"] == 30 and len(ck["rng"]) == 2         # one RNG state per rank
    sums = ck["rank_checksums"]
    assert len(sums) == 2 and sums[0] == sums[1]            # both ranks hold the same weights
    assert r.stdout.count("checkpoint:") == 1               # rank 0 alone reports/writes


def test_user_errors_exit_2(dataset, tmp_path, capsys):
    r = run_command("train", _args(dataset, tmp_path, 4, **{"train.resume": str(tmp_path / "missing.pt")}), capsys)
    assert r.returncode == 2 and "missing.pt" in r.stderr and "Traceback" not in r.stderr
    r = run_command("train", _args(tmp_path / "no_such_dataset", tmp_path, 4), capsys)
    assert r.returncode == 2 and "no_such_dataset" in r.stderr and "Traceback" not in r.stderr
    r = run_command("train", _args(dataset, tmp_path, 4, **{"train.batch_size": 100000}), capsys)
    assert r.returncode == 2 and "batch_size" in r.stderr
    r = run_command("train", _args(dataset, tmp_path, 4, **{"model.temporal_basis": 8, "diffusion": "paper"}), capsys)   # eps prediction
    assert r.returncode == 2 and "temporal_basis" in r.stderr and "Traceback" not in r.stderr
    # Out-of-range keys (tests/test_config.py has the whole table): one line before any data is read.
    r = run_command("train", _args(dataset, tmp_path / "ema", 4, **{"train.ema_decay": 1.5}), capsys)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "error: train.ema_decay: expected a number >= 0 and < 1, got 1.5"], r.stderr
    assert not (tmp_path / "ema" / "checkpoints").exists()


def test_training_on_from_a_checkpoint_with_other_keys(dataset, tmp_path):
    """Training on (docs/config.md): `train.resume=PATH` into another run directory with more
    steps and another loss weight starts at the checkpoint's step, takes the cosine over the
    new step count from the checkpoint's learning rate (a `train.lr` given again is not
    applied), and leaves the first run's files alone."""
    cosine = {"train.lr_schedule": "cosine", "train.warmup_steps": 0, "train.lr": 1e-3}
    r = _run(_args(dataset, tmp_path / "a", 3, **cosine))
    assert r.returncode == 0, r.stderr[-2000:]
    first = tmp_path / "a" / "checkpoints" / "last.pt"
    before = first.read_bytes()
    on = {**cosine, "train.lr": 5e-2, "train.resume": first, "train.w_bone_length": 0.5}
    r = _run(_args(dataset, tmp_path / "b", 9, **on))
    assert r.returncode == 0, r.stderr[-2000:]
    assert f"resumed from {first} at step 3" in r.stdout
    assert first.read_bytes() == before
    at6, last = (_weights(tmp_path / "b" / "checkpoints" / n) for n in ("step_00000006.pt", "last.pt"))
    assert at6["step"] == 6 and last["step"] == 9 and last["config"]["train"]["w_bone_length"] == 0.5
    # cosine from 1 to 0.1 over 9 steps, at step 6: 0.1 + 0.9 * (1 + cos(2π/3)) / 2 = 0.325
    assert at6["optimizer"]["param_groups"][0]["lr"] == pytest.approx(1e-3 * 0.325)
    assert _weights(first)["optimizer"]["param_groups"][0]["lr"] == pytest.approx(1e-4)    # its own end


def test_resume_from_another_model_or_diverged_weights_is_one_line(dataset, tmp_path, capsys):
    """Resuming with another width (97 lines of load_state_dict before) or from a checkpoint
    whose weights are NaN: one line naming the file."""
    r = run_command("train", _args(dataset, tmp_path / "a", 3), capsys)
    assert r.returncode == 0, r.stderr[-2000:]
    last = tmp_path / "a" / "checkpoints" / "last.pt"
    wider = [a.replace("model.width=32", "model.width=64") for a in _args(dataset, tmp_path / "b", 6)]
    r = run_command("train", [*wider, f"train.resume={last}"], capsys)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith(f"error: {last} [model]: weights of another "
                                                                         "architecture than this run's config"), r.stderr
    ck = _weights(last)
    next(iter(ck["ema"].values())).fill_(float("nan"))
    torch.save(ck, tmp_path / "nan.pt")
    r = run_command("train", _args(dataset, tmp_path / "c", 6, **{"train.resume": tmp_path / "nan.pt"}), capsys)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "[ema]: non-finite weights" in lines[0], r.stderr


def test_batch_that_does_not_split_over_processes(monkeypatch):
    """Under torchrun, rank 0 says it in one line and the other ranks exit 2 silently (before
    the process group, rather than 74 lines of both ranks' tracebacks)."""
    from motiongen.errors import ConfigError
    from motiongen.training.distributed import check_batch_split

    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("RANK", "0")
    check_batch_split("train.batch_size", 8)
    with pytest.raises(ConfigError, match=r"train.batch_size: 7 does not split evenly over 2 processes"):
        check_batch_split("train.batch_size", 7)
    monkeypatch.setenv("RANK", "1")
    with pytest.raises(SystemExit) as e:
        check_batch_split("train.batch_size", 7)
    assert e.value.code == 2


def test_non_finite_loss_stops_and_keeps_last_checkpoint(dataset, tmp_path):
    # lr 1e20 without clipping: step 1 is finite (weights jump to ~1e20), step 2 overflows.
    r = _run(_args(dataset, tmp_path, 10, **{"train.lr": 1e20, "train.grad_clip": 0, "train.ckpt_every": 1,
                                              "train.log_every": 1}))
    assert r.returncode == 2 and "non-finite" in r.stderr and "Traceback" not in r.stderr
    ck = _weights(tmp_path / "checkpoints" / "last.pt")
    assert ck["step"] == 1
    assert all(torch.isfinite(v).all() for v in ck["model"].values() if v.is_floating_point())
