"""One configuration mechanism and one command: the small tools parse key=value with Hydra's
override grammar (tool_help lists keys and defaults), and `motiongen <command>` reaches every
tool with the same errors as the scripts."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from motiongen.cli import parse_key_values
from motiongen.commands import COMMANDS, main
from motiongen.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
SPEC = {"inputs": (list, [], "files to read"), "out": (str, None), "fps": (float, 30.0), "n": (int, 3),
        "overwrite": (bool, False), "up": (str, "y")}


def test_values_follow_hydra_grammar_and_types():
    got = parse_key_values(["inputs=a.bvh", "out='my dir/x'", "fps=25", "overwrite=yes", "+n=4", "up=null"], SPEC)
    assert got == {"inputs": ["a.bvh"], "out": "my dir/x", "fps": 25.0, "n": 4, "overwrite": True, "up": None}
    got = parse_key_values(["inputs=[a.bvh,'b c.bvh']", "out=007", "fps=1e1"], SPEC)
    assert got["inputs"] == ["a.bvh", "b c.bvh"] and got["out"] == "007" and got["fps"] == 10.0
    assert parse_key_values(["inputs=a.bvh,b.bvh"], SPEC)["inputs"] == ["a.bvh", "b.bvh"]
    # Items with characters the grammar reserves are read as quoted items (sensor thresholds).
    assert parse_key_values(["inputs=[right_foot=700,left_foot:heel=250]"], SPEC)["inputs"] == [
        "right_foot=700", "left_foot:heel=250"]


@pytest.mark.parametrize("argv,message", [
    (["n=1.5"], "n='1.5': expected an integer"),
    (["fps=fast"], "fps='fast': expected a number"),
    (["overwrite=maybe"], "overwrite='maybe': expected true or false"),
    (["n=1,2"], "expected one value, not a sweep"),
    (["inputs=[a,"], "inputs='[a,': no viable alternative"),
    (["out="], "out= is empty"),
    (["color=red"], "unknown key 'color'; expected one of inputs, out, fps, n, overwrite, up"),
    (["x.bvh"], "argument 'x.bvh': expected key=value"),
    (["fps=24"], "missing out=..."),
])
def test_bad_values_are_config_errors(argv, message):
    with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("+", r"\+")):
        parse_key_values(argv, SPEC, required=("out",))


def test_help_lists_every_key_with_type_and_default(capsys):
    with pytest.raises(SystemExit) as e:
        parse_key_values(["out=x", "--help"], SPEC, required=("out",), usage="tool out=DIR", doc="Does a thing.")
    assert e.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith("Does a thing.") and "usage: tool out=DIR" in text
    rows = {ln.split()[0]: ln.split()[1:] for ln in text.splitlines() if ln.startswith("  ")}
    assert rows["out"] == ["str", "(required)"] and rows["fps"] == ["float", "default:", "30.0"]
    assert rows["inputs"] == ["list", "default:", "[]", "files", "to", "read"] and rows["up"][-1] == "y"


def motiongen(*args):
    """The console script as a user runs it (a fresh interpreter)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "motiongen.commands", *args], capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=120)


def motiongen_here(capsys, *args):
    """`motiongen` in this process (no interpreter start-up): (exit code, stdout, stderr)."""
    with pytest.raises(SystemExit) as e:
        main(list(args))
    out = capsys.readouterr()
    return e.value.code, out.out, out.err


def test_console_script_is_installed():
    text = (ROOT / "pyproject.toml").read_text()
    assert 'motiongen = "motiongen.commands:main"' in text
    assert (Path(sys.executable).parent / "motiongen").exists()      # pip install -e . made it


def test_command_list_and_unknown_command():
    r = motiongen("--help")
    assert r.returncode == 0 and all(f"  {name} " in r.stdout for name in COMMANDS)
    r = motiongen("trian")
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"error: unknown command 'trian'; expected one of {', '.join(COMMANDS)}"]


@pytest.mark.parametrize("name", [n for n in COMMANDS if n not in ("train", "distill", "sample", "serve", "evaluate", "train-body-mlp", "train-motion-prior")])
def test_every_small_tool_has_help_and_one_line_errors(name, capsys):
    code, out, err = motiongen_here(capsys, name, "--help")
    assert code == 0 and "keys (key=value" in out and "default:" in out, err
    code, out, err = motiongen_here(capsys, name, "bogus_key=1")
    assert code == 2 and err.startswith("error: unknown key 'bogus_key'") and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("name", ["train", "distill", "sample", "serve", "evaluate"])
def test_hydra_apps_through_the_command(name, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", list(sys.argv))                  # the command rewrites it for Hydra
    code, out, err = motiongen_here(capsys, name, "nonsense_key=1", f"hydra.run.dir={tmp_path / 'run'}")
    assert code == 2 and err.startswith("error: unknown key") and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()


def test_a_hydra_app_runs_through_the_console_script(tmp_path):
    r = motiongen("sample", f"ckpt={tmp_path / 'none.pt'}", f"out={tmp_path / 'o'}")
    assert r.returncode == 2 and "checkpoint file does not exist" in r.stderr and "Traceback" not in r.stderr


def test_every_command_is_a_module_with_main_argv():
    """One shape for every entry point: `main(argv=None)`; a module that is only a command line
    is motiongen/commands/<command>_command.py."""
    import importlib
    import inspect

    for name, (module, _) in COMMANDS.items():
        main_ = importlib.import_module(module).main
        assert list(inspect.signature(main_).parameters) == ["argv"], name
        if module.startswith("motiongen.commands."):
            assert module == f"motiongen.commands.{name.replace('-', '_')}_command", name
