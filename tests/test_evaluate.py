"""The evaluation protocol: pairs (deterministic, valid), the reference row on dataset motion,
and `evaluate.py` end to end on a tiny checkpoint, including its user errors."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.eval.motion_scores import reference_metrics
from motiongen.eval.pairs import SETTINGS, ProtocolConfig, make_pairs
from motiongen.eval.scene_context import SceneContext
from motiongen.eval.report import METRICS
from tests.run_inprocess import run_command

ROOT = Path(__file__).resolve().parents[1]
TINY = ["model.width=32", "model.layers=1", "model.heads=2", "model.ff=64", "model.scene_width=32",
        "model.scene_layers=1", "model.scene_heads=2", "model.scene_ff=64", "model.action_width=32",
        "model.action_layers=1", "model.action_heads=2", "model.action_ff=64"]
NAMES = ["walk", "stand", "sit", "lie down", "pick up", "carry"]


@pytest.fixture(scope="module")
def ds():
    return open_dataset(DataConfig(source="synthetic", size="small"), verbose=False)


@pytest.fixture(scope="module")
def ctxs(ds):
    return {sid: SceneContext(ds, sid) for sid in (91, 92)}


def test_pairs_deterministic_and_valid(ctxs):
    cfg = ProtocolConfig(pairs=5, seed=3)
    for sid, ctx in ctxs.items():
        for st in SETTINGS:
            a = make_pairs(ctx, st, cfg, NAMES)
            b = make_pairs(SceneContext(ctx.ds, sid), st, cfg, NAMES)
            assert [p.describe() for p in a] == [p.describe() for p in b]
            for p in a:
                assert ctx.fmap.is_free(p.start)                                  # start on free floor
                assert np.linalg.norm(p.goal.xz - p.start) >= cfg.min_distance / 2
                if p.goal.interacts:
                    assert p.goal.action in ("sit", "lie down", "pick up")
                else:
                    assert ctx.fmap.is_free(p.goal.xz)
                # The A* route is collision-free: every leg segment on free floor (the last
                # piece onto an interaction goal may leave the clearance margin).
                path = p.route.path
                segs = len(path) - 1 - (1 if p.goal.interacts else 0)
                assert all(ctx.fmap.segment_free(path[i], path[i + 1]) for i in range(segs))
                np.testing.assert_allclose(p.route.subgoals[-1], p.goal.xz)
    # Scene 91's data sits somewhere: the static setting sends some pairs there; 92 picks up.
    assert any(p.goal.action == "sit" for p in make_pairs(ctxs[91], "static", cfg, NAMES))
    dyn = make_pairs(ctxs[92], "dynamic", cfg, NAMES)
    assert len(dyn) == 5 and all(p.object_id is not None and p.goal.action == "pick up" for p in dyn)
    # Another seed gives other pairs.
    other = make_pairs(ctxs[92], "static", ProtocolConfig(pairs=5, seed=4), NAMES)
    assert [p.describe() for p in other] != [p.describe() for p in make_pairs(ctxs[92], "static", cfg, NAMES)]


def test_dynamic_pairs_approach_their_object_straight_on(ctxs):
    """`approach=A`: a pick-up pair's route ends walking straight at its object, from the same
    start to the same spot; the static pairs are untouched."""
    plain, straight = ProtocolConfig(pairs=5, seed=3), ProtocolConfig(pairs=5, seed=3, approach=1.2)
    a, b = make_pairs(ctxs[92], "dynamic", plain, NAMES), make_pairs(ctxs[92], "dynamic", straight, NAMES)
    turned = 0
    for p, q in zip(a, b):
        assert p.describe()["start"] == q.describe()["start"] and np.allclose(p.goal.xz, q.goal.xz)
        obj = p.object_pose[[0, 2], 3]
        np.testing.assert_allclose(q.goal.toward, obj)
        piece = q.route.legs[0][-1] - q.route.legs[0][-2]
        to_obj = obj - q.goal.xz
        if q.route.legs[0].shape == p.route.legs[0].shape and np.allclose(q.route.legs[0], p.route.legs[0]):
            continue                                                           # no open floor behind the spot
        turned += 1
        assert np.dot(piece, to_obj) / np.linalg.norm(piece) / np.linalg.norm(to_obj) > 0.999
        assert np.linalg.norm(piece) >= 0.4 - 1e-9
        assert all(ctxs[92].fmap.segment_free(x, y) for x, y in zip(q.route.path[:-1], q.route.path[1:]))
    assert turned >= 3
    assert [p.describe() for p in make_pairs(ctxs[91], "static", plain, NAMES)] == \
        [p.describe() for p in make_pairs(ctxs[91], "static", straight, NAMES)]


def test_reference_row_is_sane(ctxs):
    cfg = ProtocolConfig()
    st = reference_metrics(ctxs[91], "static", cfg, 42).per_sequence
    dy = reference_metrics(ctxs[92], "dynamic", cfg, 42).per_sequence
    for m in st + dy:
        assert m["foot_skating"] < 0.05                    # procedural feet are planted
        assert m["penetration_frames"] < 0.02 and m["floor_penetration_frames"] == 0.0
        assert 5 < m["jerk"] < 200
    # The "sit" label also covers sitting down and standing up, when the pelvis is still in
    # the air: about half of the labelled frames touch the seat, all of the seated ones do.
    hits, frames = sum(m["_contact_hits"] for m in st), sum(m["_contact_frames"] for m in st)
    assert frames > 0 and hits / frames > 0.4
    hits, frames = sum(m["_contact_hits"] for m in dy), sum(m["_contact_frames"] for m in dy)
    assert frames > 0 and hits / frames > 0.5
    assert all(m["object_dist_m"] < 0.05 for m in dy if "object_dist_m" in m)


# ---------------------------------------------------------------------------------------
# evaluate.py end to end


def _run(script, args, timeout=300):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, str(ROOT / script), *args], capture_output=True, text=True, env=env,
                          cwd=ROOT, timeout=timeout)


TRAIN = ["train.max_steps=100", "train.batch_size=8", "train.num_workers=0", "train.val_every=0", "train.figure_every=0",
         "train.ckpt_every=100", "train.progress=false", "train.threads=1", *TINY]


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    run = tmp_path_factory.mktemp("train")
    r = _run("train.py", ["data=small", f"hydra.run.dir={run}", *TRAIN])
    assert r.returncode == 0, r.stderr[-2000:]
    return run / "checkpoints" / "last.pt"


CMU = "/usr/share/assimp/models/BVH"                            # Debian's assimp-testmodels (scripts/test.sh)
EVAL = ["scenes=[92]", "pairs=1", "k=2", "steps=2", "max_episodes=6", "threads=1", "progress=false", "ablation_pairs=0"]


def test_evaluate_end_to_end(ckpt, tmp_path):
    out = tmp_path / "ev"
    ablated = [a if a != "ablation_pairs=0" else "ablation_pairs=1" for a in EVAL]
    r = _run("evaluate.py", [f"ckpt={ckpt}", f"out={out}", f"run_dir={tmp_path / 'tb'}", f"mocap={CMU}", *ablated])
    assert r.returncode == 0, r.stderr[-3000:]
    rep = json.loads((out / "report.json").read_text())
    mocap = rep["settings"]["static"]["mocap"]                 # real CMU clips measured the same way
    assert mocap["n_sequences"] == 3 and mocap["bone_cv"] < 0.005 and 0.0 < mocap["slide_mps"] < 0.1
    md = (out / "report.md").read_text()
    keys = [k for k, *_ in METRICS]
    for st in SETTINGS:
        block = rep["settings"][st]
        assert len(block["pairs"]) == 1 and len(block["pairs"][0]["samples"]) == 2
        for row in ("model", "model_raw", "reference"):
            missing = [k for k in keys if k not in block[row] and (st == "dynamic" or k != "object_dist_m")]
            assert not missing, (st, row, missing)
        assert block["reference"]["goal_dist_m"] is None and block["reference"]["apd_m"] is None
        assert block["model"]["apd_m"] is not None and block["model"]["foot_skating"] is not None
        assert block["model_raw"]["apd_m"] != block["model"]["apd_m"]     # the network's own samples, not the output's
        # the output is one body whatever a 100-step model predicts; the network's own joints are not
        assert block["model"]["bone_max_dev"] < 1e-3 < block["model_raw"]["bone_max_dev"]
        # every row is measured on a body mesh (the data and the network's joints on a body put on them)
        for row in ("model", "model_raw", "reference"):
            assert block[row]["mesh_penetration_frames"] is not None and "mesh_contact_rate" in block[row]
            # PSKL by action: a figure, or None where a set has too few chunks of it
            assert {"pskl_walk_gen_ref", "pskl_sit_ref_gen", "pskl_pick_up_gen_ref"} <= set(block[row]), row
        check_ablation(block, keys, st)
        assert f"## {st} setting" in md and (out / "plots" / f"{st}_scene92.png").is_file()
    # two tables (Body, Task) per setting, each with a model, network and reference row
    assert md.count("| model |") == 4 and md.count("| network joints |") == 6 and md.count("| reference |") == 4
    assert md.count("| without foot lock |") == 2 and md.count("| Ablation |") == 2       # one ablation table per setting
    assert md.count("| real mocap |") == 2                    # in the Body tables only
    assert not list(out.glob(".tmp-*")) and any((tmp_path / "tb").iterdir())
    # Deterministic: same seed, same numbers.
    out2 = tmp_path / "ev2"
    r = _run("evaluate.py", [f"ckpt={ckpt}", f"out={out2}", "plots=false", "settings=[static]", *EVAL])
    assert r.returncode == 0, r.stderr[-3000:]
    rep2 = json.loads((out2 / "report.json").read_text())
    assert not (out2 / "plots").exists() and "plots/" not in (out2 / "report.md").read_text()   # no links to figures not drawn
    assert rep2["settings"]["static"]["model"] == {**rep["settings"]["static"]["model"],
                                                   "seconds_per_pair": rep2["settings"]["static"]["model"]["seconds_per_pair"]}
    # loop.* keys reach the sampler: without the body the output is the network's own joints;
    # split=val evaluates a validation scene (where settings are chosen)
    out3 = tmp_path / "ev3"
    val = [a if a != "scenes=[92]" else "scenes=[71]" for a in EVAL]
    r = _run("evaluate.py", [f"ckpt={ckpt}", f"out={out3}", "plots=false", "settings=[static]", "loop.project=false",
                             "loop.smooth=0", "split=val", *val])
    assert r.returncode == 0, r.stderr[-3000:]
    rep3 = json.loads((out3 / "report.json").read_text())
    assert rep3["meta"]["split"] == "val" and rep3["meta"]["scenes"] == [71] and rep["meta"]["split"] == "test"
    assert "val scenes 71" in (out3 / "report.md").read_text()
    assert rep3["meta"]["protocol"]["loop"] == {"project": False, "smooth": 0.0}
    assert rep3["settings"]["static"]["model"]["bone_max_dev"] > 1e-3    # 0 with the body (above)
    assert "`loop.project=False`, `loop.smooth=0.0`" in (out3 / "report.md").read_text()


def _timeless(x):
    """A report without its timings (the only thing two runs of the same evaluation differ in)."""
    if isinstance(x, dict):
        return {k: _timeless(v) for k, v in x.items() if k not in ("seconds", "seconds_per_pair", "wall_s", "jobs")}
    return [_timeless(v) for v in x] if isinstance(x, list) else x


def test_evaluate_jobs_give_the_report_of_one_process(ckpt, tmp_path):
    """jobs=2: each setting in a worker process of its own; the report is the one-process run's,
    figure for figure, and the plots are drawn."""
    reps = {}
    for jobs in (1, 2):
        out = tmp_path / f"jobs{jobs}"
        r = _run("evaluate.py", [f"ckpt={ckpt}", f"out={out}", f"jobs={jobs}", f"plots={jobs == 2}", *EVAL])
        assert r.returncode == 0, r.stderr[-3000:]
        reps[jobs] = json.loads((out / "report.json").read_text())
    assert reps[2]["meta"]["jobs"] == 2 and list(reps[2]["settings"]) == list(SETTINGS)
    assert all(len(reps[2]["settings"][st]["pairs"]) == 1 for st in SETTINGS)
    assert _timeless(reps[2]) == _timeless(reps[1])
    assert all((tmp_path / "jobs2" / "plots" / f"{st}_scene92.png").is_file() for st in SETTINGS)


def check_ablation(block: dict, keys: list[str], setting: str) -> None:
    """The ablation rows of one setting: every stage, every figure, on the one pair; a stage that
    acts after the last episode leaves the episodes (the network's joints) as they were."""
    from motiongen.sampling.settings import CLEANUP_STAGES

    abl = block["ablation"]
    assert list(abl) == ["model", "model_raw", *CLEANUP_STAGES] and block["pairs"][0]["ablated"] == sorted(CLEANUP_STAGES)
    for row, fig in abl.items():
        assert fig["n_pairs"] == 1 and all(k in fig for k in keys if k in block["model"]), row
    assert abl["model"]["bone_max_dev"] == block["model"]["bone_max_dev"]        # one pair: the same motions
    assert abl["model_raw"]["bone_max_dev"] == block["model_raw"]["bone_max_dev"]
    # without the body, bones stretch; with it, every variant of the clean-up keeps one body
    assert abl["projection"]["bone_max_dev"] > 1e-3 > max(abl[s]["bone_max_dev"] for s in CLEANUP_STAGES if s != "projection")
    # no hand action in the static setting, no seat in the dynamic one: switching the hand reach
    # or the seat height off there changes nothing
    idle = "hand_reach" if setting == "static" else "seat_height"
    same = {k: v for k, v in abl[idle].items() if k != "seconds_per_pair"}
    assert same == {k: v for k, v in abl["model"].items() if k != "seconds_per_pair"}


def test_an_ablation_stage_with_nothing_to_act_on_is_the_output():
    """The stages whose row is the output itself, without sampling or solving again: no pick-up
    for the hand reach, no seat for the seat height, no smoothing at a 10 fps model's rate
    (loop.smooth unset), no hand goal for a checkpoint trained without them."""
    from types import SimpleNamespace as NS

    from motiongen.eval.pair_runs import stage_can_act
    from motiongen.sampling import LoopConfig

    loop = LoopConfig()
    sit = NS(route=NS(goals=[NS(action="walk"), NS(action="sit")]))
    pick = NS(route=NS(goals=[NS(action="pick up")]))
    at = lambda fps, hands=False: NS(model_fps=fps, mask=NS(hand_goals=hands))   # noqa: E731
    assert stage_can_act("seat_height", at(15), sit, loop) and not stage_can_act("seat_height", at(15), pick, loop)
    assert stage_can_act("hand_reach", at(15), pick, loop) and not stage_can_act("hand_reach", at(15), sit, loop)
    assert stage_can_act("smoothing", at(15), sit, loop) and not stage_can_act("smoothing", at(10), sit, loop)
    assert stage_can_act("smoothing", at(10), sit, LoopConfig(smooth=1.0))
    assert stage_can_act("hand_goal", at(15, True), pick, loop) and not stage_can_act("hand_goal", at(15), pick, loop)
    assert not stage_can_act("hand_goal", at(15, True), sit, loop)
    assert all(stage_can_act(s, at(10), sit, loop) for s in ("projection", "foot_lock", "seam_blend", "swing_lift"))


def test_each_sample_keeps_its_action_labels(ckpt, ds):
    """`evaluate`'s results carry every kept sample's per-frame action, frame for frame with its
    joints (what benchmarks/pskl_by_action.py cuts the chunks by): the warm-up's standing frames
    the first episode pins, then the walk; the network's row reads the same labels."""
    from motiongen.eval.protocol import evaluate, view
    from motiongen.loading.build import load_model
    from motiongen.sampling import SamplerSettings

    loaded = load_model(str(ckpt))
    cfg = ProtocolConfig(k=2, pairs=1, ablation_pairs=0, max_episodes=6)
    ev = evaluate(loaded, ds, [92], cfg, ["static"], SamplerSettings("ddim", 2), progress=False)
    (r,) = ev.results["static"]
    names = list(loaded.action_names)
    assert len(r.labels) == len(r.kept) == 2
    for js, lab in zip(r.kept, r.labels):
        assert lab.shape == (len(js),) and lab.dtype == np.int64
        # standing (the warm-up's last frames, which the first episode pins), then walking
        assert lab[0] == names.index("stand") and names.index("walk") in lab
        assert set(lab) <= set(range(len(names)))
    assert all(a is b for a, b in zip(view(r, "model_raw").labels, r.labels))


def test_evaluate_over_several_checkpoints_reports_mean_and_spread(ckpt, tmp_path, capsys):
    """ckpt=[a,b]: the same recipe with another training seed; each figure is the mean of the two
    single-checkpoint evaluations, its spread their sample standard deviation, and the data row
    (the same motion for both) has no spread."""
    from motiongen.eval.seeds import aggregate_reports

    other = tmp_path / "seed1"
    r = _run("train.py", ["data=small", f"hydra.run.dir={other}", "seed=1", *TRAIN])
    assert r.returncode == 0, r.stderr[-2000:]
    other = other / "checkpoints" / "last.pt"
    args = ["plots=false", "settings=[static]", "progress=false", *EVAL]
    reps = []
    for name, ck in (("a", ckpt), ("b", other), ("ab", f"[{ckpt},{other}]")):
        res = run_command("evaluate", [f"ckpt={ck}", f"out={tmp_path / name}", *args], capsys)
        assert res.returncode == 0, res.stderr[-2000:]
        reps.append(json.loads((tmp_path / name / "report.json").read_text()))
    a, b, ab = (x["settings"]["static"] for x in reps)
    for key in ("bone_max_dev", "foot_skating", "goal_dist_body_m"):
        va, vb = a["model_raw"][key], b["model_raw"][key]
        assert va != vb                                                        # two different networks
        assert ab["model_raw"][key] == pytest.approx((va + vb) / 2)
        assert ab["spread"]["model_raw"][key] == pytest.approx(abs(va - vb) / np.sqrt(2))
        assert ab["per_ckpt"]["model_raw"][key] == [va, vb]
    assert ab["reference"]["foot_skating"] == a["reference"]["foot_skating"] and not ab["spread"]["reference"]["foot_skating"]
    assert reps[2]["meta"]["ckpts"] == [str(ckpt), str(other)] and len(reps[2]["checkpoints"]) == 2
    md = (tmp_path / "ab" / "report.md").read_text()
    assert md.startswith("# Evaluation: 2 checkpoints") and " ± " in md
    assert aggregate_reports([reps[0]])["settings"]["static"]["spread"]["model"]["foot_skating"] is None


def test_several_checkpoints_average_the_ablation_rows_too():
    from motiongen.eval.seeds import aggregate_reports

    def report(ckpt, skate):
        rows = {"model": {"foot_skating": skate}, "model_raw": {"foot_skating": 2 * skate},
                "foot_lock": {"foot_skating": 3 * skate}}
        return {"meta": {"ckpt": ckpt, "step": 1}, "metrics": [], "notes": [], "wall_s": 1.0,
                "settings": {"static": {"pairs": [], "model": rows["model"], "ablation": rows}}}

    agg = aggregate_reports([report("a", 0.1), report("b", 0.3)])["settings"]["static"]
    assert agg["ablation"]["foot_lock"]["foot_skating"] == pytest.approx(0.6)
    # one value from every checkpoint: that value, no spread (the mean of three 0.0859s is not 0.0859)
    same = aggregate_reports([report(c, 0.0859) for c in "abc"])["settings"]["static"]
    assert same["model"]["foot_skating"] == 0.0859 and same["spread"]["model"]["foot_skating"] == 0.0
    assert agg["ablation_spread"]["foot_lock"]["foot_skating"] == pytest.approx(0.6 / np.sqrt(2))
    assert agg["ablation"]["model_raw"]["foot_skating"] == pytest.approx(0.4)


@pytest.mark.parametrize("args, needle", [
    (["ckpt=/nonexistent/x.pt"], "does not exist"),
    (["scenes=[5]"], "not among the test scenes"),
    (["scenes=[1234]"], "not among the test scenes"),
    (["split=val", "scenes=[91]"], "not among the val scenes"),
    (["split=train"], "split: expected one of val, test, got 'train'"),
    (["ckpt=[]"], "ckpt=PATH is required"),
    (["ckpt=[CKPT,/nonexistent/x.pt]"], "/nonexistent/x.pt: checkpoint file does not exist"),   # before any evaluation
    (["ckpt=[CKPT,CKPT]"], "ckpt: a checkpoint is listed twice"),
    (["settings=[bogus]"], "settings"),
    (["data=dataset", "data.root=NOTEST"], "no test scenes"),
    (["loop.smooth=-1"], "loop.smooth: expected a number >= 0"),
    (["loop.foot_lock=maybe"], "loop.foot_lock: expected true or false"),
    (["loop.foot_height=floor"], "loop.foot_height: expected one of network, body, free"),
    (["max_episodes=0"], "max_episodes: expected an integer >= 1"),
    (["min_distance=-1"], "min_distance: expected a number >= 0"),
    (["k=abc"], "k: expected an integer, got 'abc'"),
    (["mocap=/no/such/clips.bvh"], "mocap: /no/such/clips.bvh does not exist"),   # before the evaluation, not after
    (["ablate=[foot_lock,nope]"], "ablate: expected one of projection, body_scale, seam_blend, foot_lock"),
    (["ablation_pairs=-1"], "ablation_pairs: expected an integer >= 0"),
    (["jobs=0"], "jobs: expected an integer >= 1"),
    (["loop.seat_shift=maybe"], "loop.seat_shift: expected true or false"),
    (["loop.solve=newton"], "loop.solve: expected one of lbfgs, joint-space, refined"),
])
def test_evaluate_user_errors(ckpt, tmp_path, args, needle, capsys):
    if "data.root=NOTEST" in args:
        from tests.helpers import make_dataset

        root = make_dataset(tmp_path / "notest", scenes=(1, 71), seqs_per_scene=1, T=60)
        args = [a.replace("NOTEST", str(root)) for a in args]
    args = [x.replace("CKPT", str(ckpt)) for x in args]
    a = [f"ckpt={ckpt}", f"out={tmp_path}", *args] if not args[0].startswith("ckpt=") else [f"out={tmp_path}", *args]
    r = run_command("evaluate", a, capsys)
    assert r.returncode == 2, (r.stdout[-1000:], r.stderr[-1000:])
    lines = [x for x in r.stderr.strip().splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and needle in lines[0], r.stderr
    assert "Traceback" not in r.stderr
