"""No run destroys an input or mixes its outputs with another run's: outputs over inputs are
refused whatever overwrite= says, an output directory is locked by the live run using it (stale
locks taken over), runs without out= get directories of their own, and a second run into the
same directory replaces the first one's whole output set (motiongen/output_lock.py,
motiongen/staging.py `record_outputs`)."""

import hashlib
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from motiongen.annotation import annotate_contact, augment
from motiongen.body.procedural import ensure_procedural_model
from motiongen.commands import fit_command, sample_command, synthetic_command, train_command
from motiongen.errors import ConfigError
from motiongen.importers import amass, bvh, trumans
from motiongen.output_lock import LOCK_NAME, OutputLock, claim_run_dir, refuse_output_over_input
from motiongen.sampling.sample_config import SampleConfig
from motiongen.sampling.settings import LoopConfig
from motiongen.staging import MANIFEST, record_outputs
from tests.helpers import make_dataset, user_error
from tests.test_sample_cli import _checkpoint


def _tree_digest(root: Path) -> dict:
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


# ---------------------------------------------------------------------------------------
# The lock

def test_a_live_runs_lock_refuses_a_second_run_and_goes_with_the_run(tmp_path):
    d = tmp_path / "out"
    with OutputLock(d, "sample"):
        info = json.loads((d / LOCK_NAME).read_text())
        assert info["pid"] == os.getpid() and info["host"] == socket.gethostname() and info["command"] == "sample"
        with pytest.raises(ConfigError, match=rf"in use by sample \(pid {os.getpid()}, started .*\); wait for it"):
            with OutputLock(d, "fit"):
                pass
    assert not d.exists()                                   # the lock made it and nothing was written
    for exc in (RuntimeError, KeyboardInterrupt):          # released on errors and Ctrl-C too
        with pytest.raises(exc):
            with OutputLock(tmp_path, "train"):
                raise exc()
        assert not (tmp_path / LOCK_NAME).exists()


@pytest.mark.parametrize("content", ["dead", "{not json", ""])
def test_a_stale_lock_is_taken_over(tmp_path, capsys, content):
    lock = tmp_path / LOCK_NAME
    if content == "dead":
        content = json.dumps({"pid": _dead_pid(), "host": socket.gethostname(), "command": "train",
                              "started": "2020-01-01 00:00:00"})
    lock.write_text(content)
    with OutputLock(tmp_path, "sample"):
        assert json.loads(lock.read_text())["pid"] == os.getpid()
    err = capsys.readouterr().err
    assert "stale lock" in err and len(err.strip().splitlines()) == 1
    assert not lock.exists()


def test_train_into_a_run_dir_in_use_is_refused(tmp_path):
    """The lock is taken before the config is even read: the second run does nothing."""
    with OutputLock(tmp_path, "train"):
        with pytest.raises(ConfigError, match=rf"{tmp_path}: in use by train \(pid {os.getpid()}"):
            train_command.run(OmegaConf.create({}), tmp_path)


def test_runs_without_out_get_directories_of_their_own(tmp_path):
    base = tmp_path / "runs" / "sample" / "2024-01-01_00-00-00"
    base.mkdir(parents=True)                                # Hydra made it for both runs
    with claim_run_dir(base, "sample") as first, claim_run_dir(base, "sample") as second:
        assert first.dir == base and second.dir == base.with_name(base.name + "-2")
    (base / MANIFEST).write_text("{}")                       # a run that finished there
    with claim_run_dir(base, "sample") as third:
        assert third.dir == base.with_name(base.name + "-2")


# ---------------------------------------------------------------------------------------
# Outputs over inputs

@pytest.mark.parametrize("out, inp, where", [
    ("data", "data", "is"), ("data/aug", "data", "lies inside"), (".", "data", "contains"),
    ("link", "data", "is"),                                  # a symlink to the input is the input
])
def test_an_output_over_an_input_is_refused(tmp_path, out, inp, where):
    (tmp_path / "data").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "data")
    with pytest.raises(ConfigError, match=f"the output {where} the input"):
        refuse_output_over_input(tmp_path / out, [tmp_path / inp])
    refuse_output_over_input(tmp_path / "data2", [tmp_path / "data", None])   # a sibling is fine


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    root = make_dataset(tmp_path_factory.mktemp("src") / "ds", scenes=(1,), seqs_per_scene=2, T=20)
    (root / "clip.bvh").write_text("HIERARCHY\n")
    (root / "clip.npz").write_bytes(b"")
    return Path(root)


@pytest.mark.parametrize("main, args", [
    (augment.main, ["root={src}", "out={src}"]),
    (augment.main, ["root={src}", "out={src}/.."]),
    (augment.main, ["root={src}", "out={src}/aug"]),
    (bvh.main, ["inputs=[{src}/clip.bvh]", "out={src}"]),
    (amass.main, ["inputs=[{src}/clip.npz]", "out={src}"]),
    (trumans.main, ["release={src}", "out={src}/.."]),
])
def test_dataset_writers_never_replace_their_source(source, capsys, main, args):
    """The issue's case: augment out=<the source> overwrite=true replaced a 12-sequence dataset."""
    before = _tree_digest(source.parent)
    err = user_error(capsys, main, [a.format(src=source) for a in args] + ["overwrite=true"])
    assert "the input" in err and "which this run reads" in err
    assert _tree_digest(source.parent) == before


def test_a_dataset_being_annotated_is_locked(tmp_path, capsys):
    """annotate-contact writes its labels into the dataset: a second annotation of it, or a
    writer replacing it (synthetic/import overwrite=true), is refused while the first runs."""
    root = make_dataset(tmp_path / "ds", scenes=(1,), seqs_per_scene=1, T=5)
    before = _tree_digest(root)
    with OutputLock(root, "annotate-contact"):
        err = user_error(capsys, annotate_contact.main, [f"root={root}", "progress=false"])
        assert f"{root}: in use by annotate-contact (pid {os.getpid()}" in err
        err = user_error(capsys, synthetic_command.main, [f"out={root}", "size=small", "overwrite=true"])
        assert f"{root}: in use by annotate-contact" in err
    assert _tree_digest(root) == before
    assert not list(tmp_path.glob("ds.partial*"))


# ---------------------------------------------------------------------------------------
# A second run replaces the first one's whole output set

def test_record_outputs_removes_only_the_previous_sets_leftovers(tmp_path, capsys):
    for name in ("a.txt", "b.txt", "sub/c.txt", "mine.txt", "input.txt"):
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text(name)
    assert record_outputs(tmp_path, "fit", [tmp_path / "a.txt", tmp_path / "b.txt", tmp_path / "sub/c.txt",
                                            tmp_path / "input.txt"]) == 0
    assert "replaced" not in capsys.readouterr().out        # nothing before: nothing replaced
    assert record_outputs(tmp_path, "sample", [tmp_path / "a.txt"]) == 0     # another command's set is its own
    assert record_outputs(tmp_path, "fit", [tmp_path / "a.txt"], keep=[tmp_path / "input.txt"]) == 2
    assert f"replaced the previous fit outputs in {tmp_path} (2 old files" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == [MANIFEST, "a.txt", "input.txt", "mine.txt"]
    assert json.loads((tmp_path / MANIFEST).read_text())["fit"]["files"] == ["a.txt"]


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return _checkpoint(tmp_path_factory.mktemp("ck") / "tiny.pt")


def _sample(ckpt, out, default_out=None, **keys):
    cfg = SampleConfig(ckpt=str(ckpt), goals=[[0.5, 0.5]], video=False, plot=False, steps=2,
                       loop=LoopConfig(max_episodes=2), out=None if out is None else str(out), **keys)
    return sample_command.run(cfg, default_out or out)


def test_a_second_sample_replaces_the_first_ones_outputs(ckpt, tmp_path, capsys):
    out = tmp_path / "out"
    _sample(ckpt, out, num_samples=2, bvh=True)
    assert {"motion_0.bvh", "motion_1.bvh", "motion.npz"} <= {p.name for p in out.iterdir()}
    (out / "notes.txt").write_text("mine")
    _sample(ckpt, out)
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "motion.npz", "notes.txt", "summary.json"]
    assert "replaced the previous sample outputs" in capsys.readouterr().out
    with OutputLock(out, "train"):                           # a live run there: refused before any work
        with pytest.raises(ConfigError, match="in use by train"):
            _sample(ckpt, out)


def test_sample_without_out_beside_a_live_run_gets_its_own_directory(ckpt, tmp_path):
    base = tmp_path / "2024-01-01_00-00-00"
    with OutputLock(base, "sample"):
        _sample(ckpt, None, default_out=base)
    assert (tmp_path / "2024-01-01_00-00-00-2" / "motion.npz").is_file() and not (base / "motion.npz").exists()


def test_a_second_fit_replaces_the_first_ones_outputs(tmp_path, capsys):
    model = ensure_procedural_model(tmp_path / "SMPLX_NEUTRAL.npz")
    rng = np.random.default_rng(0)
    joints = (rng.normal(0, 0.01, (2, 6, 22, 3)) + np.linspace(0, 1.5, 22)[None, None, :, None]).astype(np.float32)
    np.savez(tmp_path / "two.npz", joints=joints)
    np.savez(tmp_path / "one.npz", joints=joints[0])
    out = tmp_path / "fit"
    common = [f"out={out}", f"body.model_path={model}", "mlp=none", "mesh=false", "steps=2"]
    fit_command.main([f"input={tmp_path / 'two.npz'}", *common])
    assert {"params_s00.npz", "params_s01.npz"} <= {p.name for p in out.iterdir()}
    fit_command.main([f"input={tmp_path / 'one.npz'}", *common])
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "params.npz", "report.json"]
    assert "replaced the previous fit outputs" in capsys.readouterr().out
    # An input named like an output in out= is never overwritten.
    (out / "params.npz").replace(tmp_path / "keep.npz")
    np.savez(out / "params.npz", joints=joints[0])
    before = (out / "params.npz").read_bytes()
    err = user_error(capsys, fit_command.main, [f"input={out / 'params.npz'}", *common])
    assert "the output is the input" in err and (out / "params.npz").read_bytes() == before
