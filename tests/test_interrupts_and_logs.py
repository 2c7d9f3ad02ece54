"""What a refused or interrupted run leaves behind (nothing: no run directory Hydra made for it,
no temp file, no half set), how it ends (one line: `error: ...` exit 2, `interrupted...` exit
130), and the log a run writes when its output is not a terminal (lines, and train.log)."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from motiongen.cli import tool_main
from motiongen.commands import fit_command
from motiongen.commands import main as motiongen
from motiongen.commands import run_script
from motiongen.loading.checkpoint import remove_orphan_temps
from motiongen.training import trainer
from tests.helpers import REST, make_dataset, write_fake_release
from tests.run_inprocess import run_command
from tests.test_train_cli import TINY

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("ds") / "ds", scenes=(1, 2, 71, 91), seqs_per_scene=2, T=150)


def run_here(capsys, command, *args):
    """`motiongen COMMAND ARGS` in this process: (exit code, stdout, stderr)."""
    r = run_command(command, list(args), capsys)
    return r.returncode, r.stdout, r.stderr


def _train_args(dataset, run_dir, steps, **over):
    a = ["data=dataset", f"data.root={dataset}", f"hydra.run.dir={run_dir}", f"train.max_steps={steps}",
         "train.batch_size=8", "train.num_workers=0", "train.log_every=2", "train.val_every=0",
         "train.figure_every=0", "train.ckpt_every=3", "train.threads=1", *TINY]
    return a + [f"{k}={v}" for k, v in over.items()]


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


# ---------------------------------------------------------------------------------------
# Refused runs leave no directory behind

REFUSED = {
    # case: (command and keys; {run} is the run directory, {tmp} the test's folder; words of the error)
    "sample_missing_ckpt": (["sample", "ckpt={tmp}/none.pt", "out={run}"], "none.pt"),
    "sample_default_dir": (["sample", "ckpt={tmp}/none.pt"], "none.pt"),
    "evaluate_missing_ckpt": (["evaluate", "ckpt={tmp}/none.pt", "out={run}"], "none.pt"),
    "train_after_start_up": (["train", "data=dataset", "data.root={tmp}/no_dataset", "hydra.run.dir={run}",
                              "train.num_workers=0"], "no_dataset"),
    "train_body_mlp_bad_data": (["train-body-mlp", "out={run}", "data.root={tmp}/no_dataset"], "no_dataset"),
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_refused_run_leaves_no_run_directory(case, in_process, tmp_path, capsys):
    args, words = REFUSED[case]
    run = tmp_path / "deep" / "run"
    code, _, err = run_here(capsys, *(a.format(run=run, tmp=tmp_path) for a in args))
    assert code == 2 and err.startswith("error: ") and words in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "deep").exists()                 # nor the folder Hydra made on the way
    assert not (tmp_path / "runs").exists() and not (tmp_path / "outputs").exists()


@pytest.mark.parametrize("args, words", [
    (["sample", "out=/proc/run"], "out: cannot write under /proc"),
    (["evaluate", "out={tmp}/file"], "out: {tmp}/file exists and is not a directory"),
    (["train", "hydra.run.dir={tmp}/file/run"], "hydra.run.dir: {tmp}/file is a file, not a directory"),
    (["train-body-mlp", "out={tmp}/file"], "out: {tmp}/file exists and is not a directory"),
])
def test_an_unusable_output_directory_is_one_line_before_hydra_starts(args, words, in_process, tmp_path, capsys):
    """Hydra makes the run directory before the app runs: an unusable one was Hydra's traceback."""
    (tmp_path / "file").write_text("mine")
    code, _, err = run_here(capsys, *(a.format(tmp=tmp_path) for a in args))
    line = f"error: {words.format(tmp=tmp_path)}"
    assert code == 2 and err.startswith(line) and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"] and (tmp_path / "file").read_text() == "mine"


@pytest.mark.parametrize("command", ["sample", "evaluate"])
@pytest.mark.parametrize("user_file", [True, False])
def test_refused_run_keeps_a_directory_that_was_there(command, user_file, in_process, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    if user_file:
        (out / "keep.txt").write_text("mine")
    code, _, err = run_here(capsys, command, f"ckpt={tmp_path / 'none.pt'}", f"out={out}")
    assert code == 2 and err.startswith("error: ")
    assert out.is_dir() and sorted(p.name for p in out.iterdir()) == (["keep.txt"] if user_file else [])


def test_train_body_mlp_writes_nothing_beside_out(in_process, tmp_path, capsys):
    """Its Hydra run directory is `out` itself: no ./outputs/<date>/<time>/ in the working directory."""
    out = tmp_path / "mlp"
    code, _, err = run_here(capsys, "train-body-mlp", f"out={out}", "steps=2", "batch_size=4", "log_every=1",
                            "data.num_sequences=2", "data.seq_frames=8", "mlp.width=8", "mlp.layers=1")
    assert code == 0, err
    assert (out / "mlp.pt").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mlp"]


# ---------------------------------------------------------------------------------------
# Ctrl-C: one line, exit 130


def test_ctrl_c_in_a_hydra_app_is_one_line_and_leaves_nothing(in_process, tmp_path, capsys, monkeypatch):
    def interrupted(cfg):
        raise KeyboardInterrupt

    monkeypatch.setattr("motiongen.commands.sample_command.checkpoint_path", interrupted)
    code, _, err = run_here(capsys, "sample", f"out={tmp_path / 'run'}")
    assert code == 130 and err == "interrupted: nothing written\n"
    assert not (tmp_path / "run").exists()


def test_ctrl_c_in_a_small_tool_and_while_a_command_loads(capsys, monkeypatch):
    def interrupted(argv):
        raise KeyboardInterrupt

    with pytest.raises(SystemExit) as e:
        tool_main(interrupted)([])
    assert e.value.code == 130 and capsys.readouterr().err == "interrupted\n"
    monkeypatch.setenv("RANK", "1")                        # torchrun's other ranks: the status, no line
    with pytest.raises(SystemExit) as e:
        tool_main(interrupted)([])
    assert e.value.code == 130 and capsys.readouterr().err == ""
    monkeypatch.setenv("RANK", "0")
    monkeypatch.setattr("motiongen.commands.importlib.import_module", lambda name: interrupted(None))
    with pytest.raises(SystemExit) as e:
        motiongen(["fit", "input=x"])
    assert e.value.code == 130 and capsys.readouterr().err == "interrupted\n"
    with pytest.raises(SystemExit) as e:
        run_script("train")                                # python train.py: the same
    assert e.value.code == 130 and capsys.readouterr().err == "interrupted\n"


def test_sigint_during_training_ends_with_one_line_and_a_checkpoint(dataset, tmp_path):
    """A real Ctrl-C (SIGINT) in a training: one line naming the checkpoint to resume from,
    exit 130, no temp file left."""
    run = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen([sys.executable, str(ROOT / "train.py"), *_train_args(dataset, run, 100000)], cwd=ROOT,
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         # Python ignores SIGINT in a child of a shell's background job: restore it
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 300
    while not (run / "checkpoints" / "last.pt").exists():
        assert p.poll() is None and time.time() < deadline, p.communicate()[1][-2000:]
        time.sleep(0.02)
    time.sleep(0.3)
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=120)
    assert p.returncode == 130, err[-2000:]
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("interrupted: last checkpoint ") and "train.resume=auto" in lines[0]
    assert not [f for f in (run / "checkpoints").iterdir() if ".tmp" in f.name]
    assert "\r" not in out + err                              # not a terminal: no progress bar


# ---------------------------------------------------------------------------------------
# Logs when the output is not a terminal; orphan checkpoint temp files


def test_redirected_training_logs_lines_and_train_log(dataset, in_process, tmp_path, capsys, monkeypatch):
    """Output captured (not a terminal): progress as plain lines, no bar redraws; the same lines
    in <run dir>/train.log. A temp file left by a dead writer is removed at start, a live
    process's is not."""
    monkeypatch.setattr(trainer, "LINE_EVERY_S", 0.0)          # a line at every log interval
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    orphan = run / "checkpoints" / f".step_00000003.pt.tmp{_dead_pid()}"
    live = run / "checkpoints" / f".last.pt.tmp{os.getppid()}"      # a live process, not this one
    orphan.write_bytes(b"half")
    live.write_bytes(b"being written")
    code, out, err = run_here(capsys, "train", *_train_args(dataset, run, 6))
    assert code == 0, err[-2000:]
    assert "\r" not in out + err
    steps = [ln for ln in out.splitlines() if ln.startswith("step ")]
    assert [s.split()[1] for s in steps] == ["2/6", "4/6", "6/6"] and "loss" in steps[-1], out
    log = (run / "train.log").read_text()
    assert "training in" in log and "step 6/6" in log and "finished at step 6" in log
    assert not orphan.exists() and live.exists()


def test_orphan_temps_of_dead_writers_only(tmp_path):
    dead, mine = _dead_pid(), os.getpid()
    names = [f".step_00000009.pt.tmp{dead}", f".best.pt.tmp{dead}", f".last.pt.tmp{mine}", "step_00000009.pt",
             f"notes.tmp{dead}"]
    for n in names:
        (tmp_path / n).write_bytes(b"x")
    removed = remove_orphan_temps(tmp_path)
    assert sorted(p.name for p in removed) == sorted(names[:2])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names[2:])


# ---------------------------------------------------------------------------------------
# Messages that name the right culprit


def _fake_release_with_pickled_joints(tmp_path):
    root = tmp_path / "rel"
    arrays = write_fake_release(root)
    (root / "human_joints.npy").unlink()
    np.save(root / "human_joints.npy", arrays["human_joints"].astype(object), allow_pickle=True)
    return root


def _motion_checkpoint(tmp_path):
    path = tmp_path / "motion.pt"
    torch.save({"format": "motiongen-checkpoint", "config": {"a": np.zeros(2)}}, path)
    np.savez(tmp_path / "joints.npz", joints=np.repeat(REST[None], 10, 0))
    return path


CULPRITS = {
    # case: (command and keys built in tmp_path, the one line expected, words it must not hold)
    "fit_multiview_fps_0": (lambda t: ["fit-multiview", "cameras=c.json", "keypoints2d=k.npz", f"out={t}/o",
                                       "fps=0"], "error: fps: expected a number > 0", "k.npz"),
    "trumans_pickled_joints_with_allow_pickle": (
        lambda t: ["import-trumans", f"release={_fake_release_with_pickled_joints(t)}", f"out={t}/o",
                   "allow_pickle=true", "progress=false"],
        "human_joints.npy", "pass allow_pickle=true"),
    "fit_mlp_is_a_motion_checkpoint": (
        lambda t: ["fit", f"mlp={_motion_checkpoint(t)}", f"input={t}/joints.npz", f"out={t}/o", "mesh=false"],
        "not a joints-to-body MLP checkpoint", "weights_only"),
}


@pytest.mark.parametrize("case", sorted(CULPRITS))
def test_messages_name_the_right_culprit(case, tmp_path, capsys):
    make_args, words, not_words = CULPRITS[case]
    code, _, err = run_here(capsys, *make_args(tmp_path))
    assert code == 2 and len(err.splitlines()) == 1 and words in err and not_words not in err, err
    assert not (tmp_path / "o").exists()


def test_fit_interrupted_leaves_no_half_set(tmp_path, capsys, monkeypatch):
    """Ctrl-C after the first of two samples: no params_s00.npz without its report.json."""
    np.savez(tmp_path / "joints.npz", joints=np.repeat(REST[None, None], 2, 0).repeat(10, 1))
    real, calls = fit_command.fit_joints, []

    def fit_then_interrupt(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(fit_command, "fit_joints", fit_then_interrupt)
    code, _, err = run_here(capsys, "fit", f"input={tmp_path / 'joints.npz'}", f"out={tmp_path / 'o'}", "mlp=none",
                            "mesh=false", "steps=2")
    assert code == 130 and err.startswith("interrupted") and len(err.splitlines()) == 1, err
    left = sorted(p.name for p in (tmp_path / "o").iterdir()) if (tmp_path / "o").exists() else []
    assert not [n for n in left if n.startswith(("params", "report", ".tmp"))], left
