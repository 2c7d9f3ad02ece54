"""`motiongen sample` says when a run did not do what was asked: every output written, then
`completed: false` and `goals_failed` in summary.json, one line per goal not reached on stderr,
exit status 3 (docs/sampling.md, "Exit status"). In-process, on a random-init tiny checkpoint:
it does not walk to its goal, so a goal 20 m away stalls."""

import json

import numpy as np
import pytest

from motiongen.commands.sample_command import main
from tests.helpers import user_error
from tests.test_sample_cli import _checkpoint

FAST = ["steps=2", "loop.warmup=1", "video=false", "plot=false", "threads=1"]


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    return _checkpoint(tmp_path_factory.mktemp("outcome") / "tiny.pt")


def test_a_stalled_run_writes_its_outputs_and_exits_3(ckpt, tmp_path, capsys):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as e:
        main([f"ckpt={ckpt}", "goals=[[0.0,20.0]]", "loop.stall_s=3", "loop.max_episodes=40", f"out={out}", *FAST])
    assert e.value.code == 3
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] is False
    assert [(f["sample"], f["goal"], f["reason"]) for f in summary["goals_failed"]] == [(0, 1, "stalled")]
    assert summary["goals_failed"][0]["distance_m"] > 5
    assert summary["episodes"] < 20                                  # stopped early, not at max_episodes
    with np.load(out / "motion.npz", allow_pickle=False) as z:
        assert z["goal_outcome"].tolist() == [["stalled"]] and not z["completed"]
    err = capsys.readouterr().err
    assert "goal not reached: sample 0, goal 1: stalled" in err and "Traceback" not in err


@pytest.mark.parametrize("value", ["-1", "inf", "nan"])
def test_stall_s_out_of_range_is_one_line(ckpt, tmp_path, capsys, value):
    out = tmp_path / "out"
    err = user_error(capsys, main, [f"ckpt={ckpt}", "goals=[[0.0,2.0]]", f"loop.stall_s={value}", f"out={out}", *FAST])
    assert "loop.stall_s" in err
    assert not out.exists() or not any(out.iterdir())
