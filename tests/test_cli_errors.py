"""Malformed Hydra overrides are user errors: one line on stderr, exit status 2, for the three
Hydra scripts; well-formed overrides and Hydra's own flags still reach Hydra. The root scripts
run as processes once each; the rest of the table runs the commands in-process."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from motiongen.cli import check_hydra_overrides
from tests.run_inprocess import run_command

ROOT = Path(__file__).resolve().parents[1]


def run_script(script, *args):
    """`python <script> *args` from the repository root, as a user runs it."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, str(ROOT / script), *args], capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=120)


@pytest.mark.parametrize("script", ["train.py", "sample", "evaluate"])
def test_malformed_override_is_one_line_and_exit_2(script, tmp_path, capsys):
    args = ["goals=[[1,0", f"hydra.run.dir={tmp_path / 'run'}"]
    r = run_script(script, *args) if script.endswith(".py") else run_command(script, args, capsys)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, r.stderr
    assert lines == ["error: malformed override 'goals=[[1,0': no viable alternative at input '[[1,0'"], r.stderr
    assert not (tmp_path / "run").exists()                          # Hydra never started a run


@pytest.mark.parametrize("override,reason", [
    ("x", "missing EQUAL at '<EOF>'"),
    ('a="b', 'LexerNoViableAltException: a="b'),
    ("train.lr=[1,", "no viable alternative at input '[1,'"),
])
def test_malformed_override_reasons(override, reason, capsys):
    with pytest.raises(SystemExit) as e:
        check_hydra_overrides(["train.lr=0.1", override])
    assert e.value.code == 2
    assert capsys.readouterr().err == f"error: malformed override {override!r}: {reason}\n"


def test_valid_overrides_and_flags_pass(capsys):
    # sweeps, appends, deletions, interpolations, lists and Hydra's flags with their values
    check_hydra_overrides(["-m", "train.lr=0.1,0.2", "+extra=[1,2]", "~model", "a=${b}", "goals=[[1,0],[2,2]]",
                           "--cfg", "job", "--config-name", "train", "hydra.run.dir=runs/x"])
    assert capsys.readouterr().err == ""


def test_well_formed_overrides_still_reach_hydra():
    r = run_script("sample.py", "--cfg", "job", "goals=[[1,0],[2,2]]")
    assert r.returncode == 0, r.stderr
    assert "goals:\n- - 1\n  - 0\n- - 2\n  - 2\n" in r.stdout


@pytest.mark.parametrize("script", ["train", "sample", "evaluate"])
def test_unknown_key_and_missing_option_are_one_line_and_exit_2(script, tmp_path, capsys):
    r = run_command(script, ["nonsense_key=3", f"hydra.run.dir={tmp_path / 'run'}"], capsys)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines() == [
        "error: unknown key: Could not override 'nonsense_key'.; To append to your config use "
        "+nonsense_key=3 (see --cfg job for the keys)"], r.stderr
    assert not (tmp_path / "run").exists()
    if script == "train":
        r = run_command(script, ["model=nonexist", f"hydra.run.dir={tmp_path / 'run'}"], capsys)
        assert r.returncode == 2, r.stderr
        assert r.stderr.strip().splitlines() == [
            "error: Could not find 'model/nonexist'; available: paper, reference, tiny"], r.stderr


@pytest.mark.parametrize("script,override,line", [
    ("sample", "steps=many", "error: steps: expected an integer, got 'many'"),
    ("evaluate", "loop.project=maybe", "error: loop.project: expected true or false, got 'maybe'"),
    ("train", "train.lr=fast", "error: train.lr: expected a number, got 'fast'"),
])
def test_value_of_the_wrong_type_is_one_line_and_exit_2(script, override, line, tmp_path, capsys):
    """The structured configs type every key: OmegaConf refuses the value as the command line is
    read, before anything runs."""
    r = run_command(script, [override, f"hydra.run.dir={tmp_path / 'run'}"], capsys)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [line], r.stderr
    assert not (tmp_path / "run").exists()
