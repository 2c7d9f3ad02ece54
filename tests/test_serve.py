"""Live control (`motiongen serve`): the live sampler, the session's clock and rollbacks, and the
JSON API over real HTTP, driven with the oracle denoiser (tests/oracle.py), which walks straight
to each goal, so that arrivals and latencies are the loop's, not a model's."""

import io
import json
import socket
import time
import urllib.error
import urllib.request

import numpy as np
import pygltflib
import pytest
import torch
import trimesh

from motiongen.body.model import load_body_model
from motiongen.export.gltf import body_glb_bytes
from motiongen.routing import walkable_map
from motiongen.sampling import Goal, LoopConfig, SamplerSettings
from motiongen.sampling.live import Cancelled, LiveSampler, slerp
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.serve.launch import app_info
from motiongen.serve.server import App, serve_in_thread
from motiongen.serve.session import LiveSession
from motiongen.skeleton import PELVIS
from tests.oracle import oracle_loaded
from tests.run_inprocess import run_command
from tests.test_sample_cli import _checkpoint

# Real time: a server plays the motion on the wall clock (scripts/test.sh runs these alone).
pytestmark = pytest.mark.live

SAMPLER = SamplerSettings("ddim", 2)


def room(size=6.0, voxel=0.1):
    """An empty 6 x 6 m room (walls 0.1 m thick), its origin at a corner: (grid, walkable map)."""
    n, h = int(size / voxel), int(2.0 / voxel)
    occ = np.zeros((n, h, n), bool)
    occ[0], occ[-1], occ[:, :, 0], occ[:, :, -1] = True, True, True, True
    grid = OccupancyGrid.from_dense(occ, [0.0, 0.0, 0.0], voxel)
    return grid, walkable_map(grid, 0.25)


def live_sampler(start=(1.0, 1.0), walkable=None, grid=None, **loop):
    loop = {"tolerance": 0.2, "warmup": 1, **loop}
    return LiveSampler(oracle_loaded(), grid, walkable, body_model=load_body_model(), start_xz=start,
                       sampler=SAMPLER, loop=LoopConfig(**loop), generator=torch.Generator().manual_seed(0))


def test_slerp_closed_form():
    """Halfway between the identity and 90 degrees about y is 45 degrees about y, either sign of q1."""
    q0 = np.array([[[0, 0, 0, 1.0]]])
    q1 = np.array([[[0, np.sin(np.pi / 4), 0, np.cos(np.pi / 4)]]])
    half = np.array([0, np.sin(np.pi / 8), 0, np.cos(np.pi / 8)])
    for q in (q1, -q1):
        assert np.allclose(slerp(q0, q, np.array([[0.5]]))[0, 0], half)
    assert np.allclose(slerp(q0, q1, np.array([[0.0]])), q0) and np.allclose(slerp(q0, q1, np.array([[1.0]])), q1)


def test_live_sampler_walks_to_goals_and_its_frames_are_the_body_posed():
    live = live_sampler()
    live.add_goals([Goal([1.0, 3.0]), Goal([2.5, 3.0])])
    for _ in range(40):
        live.step()
        if not live.goals:
            break
    assert not live.goals and [r.stalled for r in live.reached] == [False, False]
    assert np.linalg.norm(live.pelvis_xz() - [2.5, 3.0]) < 0.2
    f = live.frames_since(0)
    T = len(f["root"])
    assert f["quats"].shape == (T, 22, 4) and f["joints"].shape == (T, 22, 3)
    # The served joints are the body posed by the served rotations and root: what a viewer skins.
    from scipy.spatial.transform import Rotation
    R = torch.as_tensor(Rotation.from_quat(f["quats"].reshape(-1, 4)).as_matrix().reshape(T, 22, 3, 3))
    body = live.body
    transl = torch.as_tensor(f["root"]) - body.rest[0, 0].double()
    posed = body.pose(R[None].float(), transl[None].float())[0].double().numpy()
    assert np.abs(posed - f["joints"]).max() < 1e-4
    assert np.allclose(f["root"], f["joints"][:, PELVIS], atol=1e-4)
    # 30 fps with no jumps: the oracle walks at most ~2 m/s.
    assert np.linalg.norm(np.diff(f["root"][:, [0, 2]], axis=0), axis=-1).max() < 2.5 / 30


def test_rollback_regenerates_from_the_kept_frame_and_restores_goals_done_after_it():
    live = live_sampler()
    live.add_goals([Goal([1.0, 2.0])])
    while live.goals:
        live.step()
    done_at = live.reached[0].frame
    keep = 10                                                   # output frames: well before the arrival
    before = live.frames_since(0)["joints"][:keep].copy()
    first = live.rollback(keep)
    # The change starts at the first output frame that needs a new model frame: within one model frame.
    assert first == live.num_frames and keep <= first < keep + live.out_fps / live.model_fps
    assert np.array_equal(live.frames_since(0)["joints"][:keep], before)
    assert [g.xz.tolist() for g in live.goals] == [[1.0, 2.0]] and live.reached == [] and done_at > first
    # Nothing after the end: a rollback past the last frame changes nothing.
    assert live.rollback(10 ** 6) == live.num_frames


def test_an_episode_cancelled_after_denoising_changes_nothing(monkeypatch):
    """A cancel that comes once the network is done (no network call left to stop at) stops the
    episode before the projection: no frame, no tail, no goal progress kept; the next step
    carries on as if the cancelled one had never run."""
    import motiongen.sampling.autoregressive as ar

    live = live_sampler()
    live.add_goals([Goal([1.0, 3.0])])
    live.step()
    real, calls = ar.denoise, []

    def denoise_then_cancel(*args):
        out = real(*args)
        calls.append(1)
        live.cancel.set()
        return out

    n, tail, legs = live.num_frames, live.state.tail, live.progress.leg.copy()
    joints = live.frames_since(0)["joints"].copy()
    monkeypatch.setattr(ar, "denoise", denoise_then_cancel)
    with pytest.raises(Cancelled):
        live.step()
    assert calls == [1] and live.num_frames == n and live.state.tail is tail and np.array_equal(live.progress.leg, legs)
    monkeypatch.setattr(ar, "denoise", real)
    live.cancel.clear()
    live.step()
    after = live.frames_since(0)["joints"]
    assert live.num_frames > n and np.array_equal(after[:n], joints)
    assert np.linalg.norm(after[n] - after[n - 1], axis=-1).max() < 0.1       # continues from the last frame


def test_appending_while_acting_does_not_restart_the_action():
    live = live_sampler()
    live.add_goals([Goal([1.0, 2.0], "sit", 2.0)])
    while live.progress.acting[0] == 0:
        live.step()
    left = int(live.progress.acting[0])
    live.add_goals([Goal([2.0, 2.0])])
    assert live.progress.acting[0] == left and len(live.goals) == 2


class Clock:
    """A hand-driven clock for the session's playback."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_session_clock_plays_pauses_and_counts_stalls():
    clock = Clock()
    s = LiveSession(live_sampler(), None, clock=clock)           # not started: nothing generates
    end = (s.live.num_frames - 1) / s.fps
    clock.t = 1.0
    assert s.state()["time_played"] == pytest.approx(1.0) and s.stall_s == 0
    s.set_playing(False)
    clock.t = 2.0
    assert s.state()["time_played"] == pytest.approx(1.0)
    s.set_playing(True)
    clock.t = 2.0 + end + 0.5                                    # 0.5 s past the last frame generated
    st = s.state()
    assert st["time_played"] == pytest.approx(end) and s.stall_s == pytest.approx(1.5)
    assert st["frame_played"] == st["frames_generated"] - 1


def test_a_click_stops_the_episode_being_generated_only_when_frames_reach_past_the_rollback_point():
    """A goal for an idle body stops the episode in progress when what is generated reaches past
    the play head plus the margin (that episode's frames would be thrown away); a click soon after
    another, when playback is about to reach the episode in progress, lets it finish (stopping it
    would stall playback)."""
    clock = Clock()
    s = LiveSession(live_sampler(), None, clock=clock)           # not started: nothing generates
    end = (s.live.num_frames - 1) / s.fps
    s.recent.clear()
    s.recent.append(0.2)                                         # margin = 1.15 * 0.2 + 0 + 0.03 = 0.26 s
    clock.t = end - 0.5                                          # 0.5 s generated ahead of playback
    s.add_goals([Goal([2.0, 2.0])])
    assert s.live.cancel.is_set()
    s.live.cancel.clear()
    s.clear_goals()
    s.live.cancel.clear()
    clock.t = end - 0.1                                          # 0.1 s ahead: less than the margin
    s.add_goals([Goal([2.0, 2.0])])
    assert not s.live.cancel.is_set() and s.state()["goals"] == [{"x": 2.0, "z": 2.0, "action": None}]


# ---- the API over HTTP --------------------------------------------------------------------------------


@pytest.fixture
def served():
    grid, fmap = room()
    live = live_sampler(start=(1.0, 1.0), walkable=fmap, grid=grid)
    bm = load_body_model()
    session = LiveSession(live, fmap, max_pending=5)
    box = trimesh.creation.box((6, 0.02, 6))
    app = App(session, app_info(live.loaded, fmap, True, 5, live.out_fps), box.export(file_type="glb"),
              body_glb_bytes(bm, live.body.betas[0]), bm)
    server, url = serve_in_thread(app)
    yield url, session
    server.shutdown()
    server.server_close()
    session.stop()


def call(url, method="GET", body=None, raw: bytes | None = None):
    data = raw if raw is not None else (json.dumps(body).encode() if body is not None else None)
    req = urllib.request.Request(url, data=data, method=method, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=20) as r:
            return r.status, r.read(), r.headers
    except urllib.error.HTTPError as e:
        return e.code, e.read(), e.headers


def api(url, method="GET", body=None):
    status, data, _ = call(url, method, body)
    return status, json.loads(data)


def wait_for(pred, timeout=30.0, every=0.05):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = pred()
        if v:
            return v
        time.sleep(every)
    raise AssertionError("timed out")


def test_api_goals_arrive_and_state_follows(served):
    url, session = served
    status, info = api(url + "/api/info")
    assert status == 200 and info["actions"][0] == "walk" and "sit" in info["actions"]
    assert np.allclose(info["bounds"], [[0.0, 0.0], [6.0, 6.0]]) and len(info["joint_names"]) == 22
    t0 = time.monotonic()
    status, out = api(url + "/api/goals", "POST", {"goals": [{"x": 2.0, "z": 2.0}, {"x": 2.8, "z": 1.6, "action": "sit",
                                                                                    "seconds": 0.5}]})
    assert status == 200 and out == {"pending": 2, "accepted": 2}
    st = wait_for(lambda: (s := api(url + "/api/state")[1])["goals_reached"] == 2 and s)
    assert time.monotonic() - t0 < 30
    # Played frames follow the clock; the body is where the last goal is once it has played there.
    st = wait_for(lambda: (s := api(url + "/api/state")[1])["action_now"] == "sit" and s)
    assert np.linalg.norm(np.array(st["hips"])[[0, 2]] - [2.8, 1.6]) < 0.3
    assert st["goals"] == [] and st["time_generated"] >= st["time_played"] > 0
    fr = api(url + f"/api/frames?from=0&rev={st['rev']}")[1]
    assert fr["start"] == 0 and len(fr["root"]) == fr["total"] >= st["frames_generated"]
    assert np.allclose(np.array(fr["joints"])[st["frame_played"]], st["joints"], atol=1e-4)


def test_a_goal_for_an_idle_body_changes_the_motion_within_half_a_second(served):
    url, session = served
    wait_for(lambda: api(url + "/api/state")[1]["time_generated"] > 1.5)
    st0 = api(url + "/api/state")[1]
    t0 = time.monotonic()
    api(url + "/api/goals", "POST", {"goals": [{"x": 1.0, "z": 4.0}]})
    st = wait_for(lambda: (s := api(url + "/api/state")[1])["rev"] > st0["rev"] and s)
    assert st["changed_from"] <= st0["frame_played"] + 0.5 * st["fps"] + 2
    wait_for(lambda: api(url + "/api/state")[1]["frame_played"] >= st["changed_from"])
    assert time.monotonic() - t0 < 1.0                       # generous: the host may be loaded
    # A viewer at the old revision gets frames from the first frame that changed.
    fr = api(url + f"/api/frames?from={st0['frames_generated']}&rev={st0['rev']}")[1]
    assert fr["start"] == st["changed_from"] and fr["rev"] == st["rev"]


def test_replace_changes_course_at_once(served):
    url, session = served
    api(url + "/api/goals", "POST", {"goals": [{"x": 4.5, "z": 1.0}, {"x": 4.5, "z": 4.5}]})
    # Under way, with frames generated ahead to throw away.
    st0 = wait_for(lambda: (s := api(url + "/api/state")[1])["time_generated"] - s["time_played"] > 1.0
                   and s["time_played"] > 0.5 and s)
    status, out = api(url + "/api/goals", "POST", {"goals": [{"x": 1.0, "z": 2.5}], "replace": True})
    assert status == 200 and out == {"pending": 1, "accepted": 1}
    st = wait_for(lambda: (s := api(url + "/api/state")[1])["rev"] > st0["rev"] and s)
    assert [(g["x"], g["z"]) for g in st["goals"]] == [(1.0, 2.5)]
    wait_for(lambda: api(url + "/api/state")[1]["goals_reached"] >= 1)
    hips = np.array(api(url + "/api/state")[1]["hips"])[[0, 2]]
    assert np.linalg.norm(hips - [1.0, 2.5]) < 0.3


def test_api_refuses_bad_requests_with_one_line_and_goes_on(served):
    url, _ = served
    bad = [({"goals": [{"x": 9.0, "z": 1.0}]}, "outside the scene bounds"),
           ({"goals": [{"x": 0.05, "z": 3.0}]}, "inside an obstacle"),
           ({"goals": [{"x": 2.0, "z": 2.0, "action": "dance"}]}, "unknown action"),
           ({"goals": [{"x": "2", "z": 2.0}]}, "goals[0].x"),
           ({"goals": [{"x": 2.0, "z": 2.0, "path": "/etc/passwd"}]}, "unknown field"),
           ({"goals": []}, "at least one goal"),
           ({"goals": [{"x": 2.0, "z": 2.0}], "replace": "yes"}, "replace"),
           ({"goals": [{"x": 2.0, "z": 2.0}], "file": "x"}, "unknown field"),
           ({"goals": [{"x": 2.0, "z": 2.0}] * 6}, "too many goals")]
    for body, why in bad:
        status, out = api(url + "/api/goals", "POST", body)
        assert status == 400 and why in out["error"] and "\n" not in out["error"], (body, out)
    status, data, _ = call(url + "/api/goals", "POST", raw=b"{not json")
    assert status == 400 and b"not JSON" in data
    status, _, _ = call(url + "/api/goals", "POST", raw=b"[" + b" " * 70000 + b"]")
    assert status == 413
    assert call(url + "/api/frames?from=abc")[0] == 400
    assert call(url + "/api/download?format=exe")[0] == 400
    assert call(url + "/static/../server.py")[0] == 404 and call(url + "/static/%2e%2e/server.py")[0] == 404
    assert call(url + "/nothing")[0] == 404 and call(url + "/api/play", "POST", {"playing": "yes"})[0] == 400
    # Still serving, nothing queued.
    status, st = api(url + "/api/state")
    assert status == 200 and st["goals"] == []


def test_clear_pause_and_downloads(served):
    url, session = served
    api(url + "/api/goals", "POST", {"goals": [{"x": 5.0, "z": 5.0}, {"x": 1.0, "z": 5.0}]})
    assert len(api(url + "/api/state")[1]["goals"]) == 2
    assert api(url + "/api/goals", "DELETE")[1] == {"pending": 0}
    assert wait_for(lambda: api(url + "/api/state")[1]["goals"] == [])
    st = api(url + "/api/play", "POST", {"playing": False})[1]
    time.sleep(0.3)
    assert not st["playing"] and api(url + "/api/state")[1]["time_played"] == pytest.approx(st["time_played"], abs=1e-6)
    api(url + "/api/play", "POST", {"playing": True})
    status, data, headers = call(url + "/api/download?format=npz")
    z = np.load(io.BytesIO(data))
    T = z["joints"].shape[1]
    assert status == 200 and "motion.npz" in headers["Content-Disposition"] and z["joints"].shape[2:] == (22, 3)
    assert z["quats"].shape == (T, 22, 4) and float(z["fps"]) == 30.0
    status, data, _ = call(url + "/api/download?format=bvh")
    assert status == 200 and data.startswith(b"HIERARCHY") and b"MOTION" in data
    status, data, _ = call(url + "/api/download?format=glb")
    doc = pygltflib.GLTF2.load_from_bytes(data)
    assert status == 200 and len(doc.animations) == 1 and len(doc.skins) == 1


# ---- the command ------------------------------------------------------------------------------------


def test_serve_command_errors_are_one_line(tmp_path, capsys):
    ckpt = _checkpoint(tmp_path / "tiny.pt")
    r = run_command("serve", [f"ckpt={tmp_path / 'none.pt'}"], capsys)
    assert r.returncode == 2 and "checkpoint file does not exist" in r.stderr and "Traceback" not in r.stderr
    for args, why in ((["port=70000"], "port"), (["lead_s=0"], "lead_s"), (["host=a b"], "host"),
                      (["steps=0"], "steps")):
        r = run_command("serve", [f"ckpt={ckpt}"] + args, capsys)
        assert r.returncode == 2 and why in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    with socket.socket() as taken:                                    # a port in use: one line, not a traceback
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = run_command("serve", [f"ckpt={ckpt}", f"port={port}", "loop.warmup=1", "steps=2", "threads=1"], capsys)
    assert r.returncode == 2 and f"cannot listen on 127.0.0.1:{port}" in r.stderr, r.stderr[-2000:]
    assert len(r.stderr.strip().splitlines()) == 1
