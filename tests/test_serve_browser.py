"""The `motiongen serve` page in a real browser: Debian's headless Chromium (software WebGL through
SwiftShader) driven by Playwright, against a running server (fixture `live_url`).

Skipped where /usr/bin/chromium, the playwright package or the vendored three.js
(motiongen/serve/static/vendor/, made by `pip install -e .` with npm) is missing;
scripts/test.sh installs the first two.
"""

import base64
import io
import json
import math
import os
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from motiongen.body.model import load_body_model
from motiongen.export.gltf import body_glb_bytes
from motiongen.routing import walkable_map
from motiongen.sampling import LoopConfig, SamplerSettings
from motiongen.sampling.live import LiveSampler
from motiongen.scene.voxelize import voxelize_mesh
from motiongen.serve.launch import app_info
from motiongen.serve.server import App, serve_in_thread
from motiongen.serve.session import LiveSession
from motiongen.serve.vendor import missing_assets
from tests.oracle import oracle_loaded

sync_api = pytest.importorskip("playwright.sync_api")

# Real time: a server plays the motion on the wall clock (scripts/test.sh runs these alone).
pytestmark = pytest.mark.live

CHROMIUM = "/usr/bin/chromium"
# WebGL without a GPU: ANGLE on SwiftShader. The rest keeps Chromium off the network; the
# resolver rule makes every host but 127.0.0.1 unresolvable (the Recorder still sees the attempt).
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader", "--disable-background-networking", "--disable-component-update",
    "--disable-sync", "--no-first-run", "--disable-quic",
    "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
]
LOCAL_HOSTS = {"127.0.0.1"}
STATIC = Path(__file__).resolve().parents[1] / "motiongen" / "serve" / "static"

if not os.access(CHROMIUM, os.X_OK):
    pytest.skip(f"{CHROMIUM} missing (apt-get install chromium; scripts/test.sh does)",
                allow_module_level=True)


if missing_assets():
    pytest.skip("three.js not vendored into motiongen/serve/static/vendor/ "
                f"(missing {', '.join(missing_assets())}): run `pip install -e .` with npm on PATH",
                allow_module_level=True)


def room_mesh():
    """A 6 x 6 m room (origin at a corner) with walls 2 m high and a table in the middle."""
    parts = [trimesh.creation.box((6.0, 0.02, 6.0), trimesh.transformations.translation_matrix((3, -0.01, 3))),
             trimesh.creation.box((1.2, 0.75, 0.8), trimesh.transformations.translation_matrix((3, 0.375, 3)))]
    for center, extent in (((3, 1, 0.05), (6, 2, 0.1)), ((3, 1, 5.95), (6, 2, 0.1)),
                           ((0.05, 1, 3), (0.1, 2, 6)), ((5.95, 1, 3), (0.1, 2, 6))):
        parts.append(trimesh.creation.box(extent, trimesh.transformations.translation_matrix(center)))
    return trimesh.util.concatenate(parts)


@pytest.fixture(scope="module")
def live_url():
    """The real server (motiongen.serve) in this process on a free port of 127.0.0.1, driving the
    oracle denoiser of the loop tests (it walks straight to each goal) in `room_mesh`."""
    mesh = room_mesh()
    grid = voxelize_mesh(mesh, voxel_size=0.05)
    fmap = walkable_map(grid, 0.25)
    bm = load_body_model()
    live = LiveSampler(oracle_loaded(), grid, fmap, body_model=bm, start_xz=(1.5, 1.5),
                       sampler=SamplerSettings("ddim", 2), loop=LoopConfig(tolerance=0.2),
                       generator=torch.Generator().manual_seed(0))
    session = LiveSession(live, fmap)
    app = App(session, app_info(live.loaded, fmap, True, 100, live.out_fps), mesh.export(file_type="glb"),
              body_glb_bytes(bm, live.body.betas[0]), bm)
    server, url = serve_in_thread(app, "127.0.0.1", 0)
    yield url
    server.shutdown()
    server.server_close()
    session.stop()


def api(base, method, path, body=None):
    """(status, JSON answer) of one API call."""
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(base + path, data=data, method=method,
                                 headers={"Content-Type": "application/json"} if data else {})
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as err:
        return err.code, json.loads(err.read() or b"null")


def wait_for(predicate, timeout, message, interval=0.1):
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s: {message}")
        time.sleep(interval)


class Recorder:
    """Console errors, page errors and requests to hosts other than 127.0.0.1.

    Listens to events only: routing every request through Playwright (page.route) would stall
    the page's polling whenever the test is not calling into Playwright (time.sleep)."""

    def __init__(self, page):
        self.errors, self.foreign, self.urls = [], [], []
        page.on("console", lambda m: self.errors.append(f"console: {m.text} @ {m.location}")
                if m.type == "error" else None)
        page.on("pageerror", lambda e: self.errors.append(f"pageerror: {e}"))
        page.on("request", self._request)

    def _request(self, request):
        url = request.url
        self.urls.append(url)
        parsed = urllib.parse.urlparse(url)
        if parsed.scheme not in ("data", "blob") and parsed.hostname not in LOCAL_HOSTS:
            self.foreign.append(url)

    def take_rejected_goals(self):
        """Drop the console lines that POST /api/goals answered 400 leaves (a goal the test
        expected the server to reject); return how many."""
        kept = [e for e in self.errors if not ("status of 400" in e and "/api/goals" in e)]
        n = len(self.errors) - len(kept)
        self.errors[:] = kept
        return n

    def assert_clean(self):
        assert self.foreign == [], f"requests to other hosts: {self.foreign}"
        assert self.errors == [], "\n".join(self.errors)


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        yield browser
        browser.close()


@pytest.fixture(scope="module")
def app(browser, live_url):
    """The page, loaded and ready, shared by the tests (one server, one page)."""
    context = browser.new_context(viewport={"width": 960, "height": 640})
    page = context.new_page()
    page.rec = Recorder(page)
    page.base = live_url
    page.info = api(live_url, "GET", "/api/info")[1]
    page.goto(live_url + "/")
    page.wait_for_function("window.motiongen && window.motiongen.ready === true", timeout=30_000)
    yield page
    context.close()


# ---------------------------------------------------------------- helpers

def state(page):
    return api(page.base, "GET", "/api/state")[1]


def set_playing(page, playing):
    status, _ = api(page.base, "POST", "/api/play", {"playing": playing})
    assert status == 200


def clear_goals(page):
    assert api(page.base, "DELETE", "/api/goals") == (200, {"pending": 0})
    wait_for(lambda: page.evaluate("window.motiongen.goalMarkerCount()") == 0, 5,
             "goal markers gone after DELETE /api/goals")


def inside(info, x, z, margin=0.3):
    if info["bounds"] is None:
        return True
    (x0, z0), (x1, z1) = info["bounds"]
    return x0 + margin <= x <= x1 - margin and z0 + margin <= z <= z1 - margin


def nearby_points(page, distance=1.2):
    """Floor points `distance` from the body, inside the bounds, towards the scene's middle
    first."""
    hips = state(page)["hips"]
    info = page.info
    if info["bounds"]:
        (x0, z0), (x1, z1) = info["bounds"]
        toward = math.atan2((x0 + x1) / 2 - hips[0], (z0 + z1) / 2 - hips[2])
    else:
        toward = 0.0
    points = []
    for k in range(12):
        a = toward + (k + 1) // 2 * (-1) ** k * math.pi / 6
        x, z = hips[0] + distance * math.sin(a), hips[2] + distance * math.cos(a)
        if inside(info, x, z):
            points.append((round(x, 3), round(z, 3)))
    assert points, f"no floor point {distance} m from the body at {hips} inside {info['bounds']}"
    return points


def add_goal(page, via, distance=1.2):
    """Post a goal near the body via the page (window.motiongen.pickFloor) or the API; points the
    server rejects (in furniture, say) are skipped. Returns (x, z)."""
    rejected = []
    for x, z in nearby_points(page, distance):
        if via == "page":
            answer = page.evaluate("([x, z]) => window.motiongen.pickFloor(x, z)", [x, z])
            ok = answer["ok"]
        else:
            status, answer = api(page.base, "POST", "/api/goals", {"goals": [{"x": x, "z": z}]})
            ok = status == 200
        if ok:
            assert answer["accepted"] == 1 and answer["pending"] >= 1, answer
            break
        rejected.append(answer)
    else:
        raise AssertionError(f"every nearby goal was rejected: {rejected}")
    if via == "page" and rejected:
        assert page.rec.take_rejected_goals() == len(rejected)
    return x, z


def bones(page):
    return np.array(page.evaluate("window.motiongen.boneWorldPositions()"))


def canvas_image(page):
    """The WebGL canvas's pixels (readable because of preserveDrawingBuffer: true)."""
    from PIL import Image
    url = page.evaluate("document.querySelector('#view canvas').toDataURL('image/png')")
    data = base64.b64decode(url.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def wait_paused_frame(page):
    """After pausing: the frame the page shows once it agrees with the server's play head."""
    def settled():
        s = state(page)
        held = page.evaluate("window.motiongen.held()")
        return s if (not s["playing"] and not held["playing"] and held["rev"] == s["rev"]
                     and held["shown"] == s["frame_played"]) else None
    return wait_for(settled, 5, "page shows the server's paused frame")


# ---------------------------------------------------------------- tests

def test_page_loads_offline_without_errors(app):
    assert app.evaluate("window.motiongen.ready") is True
    assert app.evaluate("window.motiongen.frameShown") >= 0
    vendored = [u for u in app.rec.urls if "/static/vendor/" in u]
    assert any(u.endswith("/three.module.js") for u in vendored), app.rec.urls
    # actions come from /api/info
    options = app.eval_on_selector_all("#action option", "os => os.map(o => o.value)")
    assert options == app.info["actions"]
    assert app.input_value("#action") == app.info["default_action"]
    app.wait_for_timeout(500)  # some polling and playing
    app.rec.assert_clean()


def test_canvas_is_drawn_and_changes_as_the_body_moves(app):
    set_playing(app, True)
    clear_goals(app)
    first = canvas_image(app)
    rgb = first.astype(np.int64)
    _, counts = np.unique((rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2], return_counts=True)
    assert len(counts) > 50, f"only {len(counts)} colours: blank canvas?"
    assert counts.max() < 0.9 * counts.sum(), "canvas nearly one colour"

    rev = state(app)["rev"]
    add_goal(app, "api", distance=1.5)
    # The goal rolls the unplayed frames back: wait for the page to hold the new ones and to have
    # played half a second of them.
    after = wait_for(lambda: (s := state(app))["rev"] > rev and s, 10, "the motion changed for the goal")
    wait_for(lambda: app.evaluate("window.motiongen.held()")["rev"] >= after["rev"]
             and app.evaluate("window.motiongen.frameShown") >= after["changed_from"] + 15, 10,
             "half a second of the new frames played")
    second = canvas_image(app)
    changed = np.abs(first.astype(int) - second.astype(int)).max(axis=2) > 24
    assert changed.mean() > 0.001, f"only {changed.mean():.5f} of the pixels changed"
    app.rec.assert_clean()


@pytest.mark.parametrize("via", ["page", "api"])
def test_goal_is_reached_by_the_displayed_body(app, via):
    set_playing(app, True)
    clear_goals(app)
    # Paused, the goal stays pending (its marker up) however slowly a loaded machine polls.
    set_playing(app, False)
    x, z = add_goal(app, via)
    wait_for(lambda: app.evaluate("window.motiongen.goalMarkerCount()") >= 1, 5, "goal marker shown")
    set_playing(app, True)

    def pelvis_distance():
        p = bones(app)[0]
        return math.hypot(p[0] - x, p[2] - z)
    wait_for(lambda: pelvis_distance() < 0.3, 30,
             f"displayed pelvis within 0.3 m of goal ({x}, {z})")
    app.rec.assert_clean()


def test_displayed_bones_match_state_joints_when_paused(app):
    set_playing(app, True)
    clear_goals(app)
    add_goal(app, "api", distance=1.5)
    app.wait_for_timeout(700)  # mid-stride: a pose far from the rest pose
    try:
        set_playing(app, False)
        s = wait_paused_frame(app)
        shown = bones(app)
        expected = np.array(s["joints"])
        assert shown.shape == expected.shape == (len(app.info["joint_names"]), 3)
        error = np.linalg.norm(shown - expected, axis=1)
        worst = int(error.argmax())
        assert error.max() < 0.01, (
            f"{app.info['joint_names'][worst]} is {error.max() * 100:.2f} cm off at frame "
            f"{s['frame_played']}")
    finally:
        set_playing(app, True)
    app.rec.assert_clean()


def test_pause_button_stops_the_play_head_and_resume_restarts_it(app):
    set_playing(app, True)
    wait_for(lambda: app.text_content("#play") == "Pause", 5, "button reads Pause while playing")
    app.click("#play")
    s = wait_paused_frame(app)
    assert app.text_content("#play") == "Resume"
    app.wait_for_timeout(500)
    assert app.evaluate("window.motiongen.frameShown") == s["frame_played"]
    assert state(app)["frame_played"] == s["frame_played"]
    app.click("#play")
    wait_for(lambda: app.evaluate("window.motiongen.frameShown") > s["frame_played"] + 5, 5,
             "frames advance after Resume")
    assert state(app)["playing"] is True
    app.rec.assert_clean()


def test_scrub_shows_an_earlier_frame_and_resume_returns_live(app):
    set_playing(app, True)
    wait_for(lambda: state(app)["frames_generated"] > 20, 10, "some frames generated")
    app.eval_on_selector("#scrub", "el => { el.value = 10; el.dispatchEvent(new Event('input')); }")
    wait_for(lambda: app.evaluate("window.motiongen.frameShown") == 10, 5, "slider shows frame 10")
    wait_for(lambda: state(app)["playing"] is False, 5, "scrubbing pauses the server")
    frames = api(app.base, "GET", f"/api/frames?from=10&rev={state(app)['rev']}")[1]
    expected = np.array(frames["joints"][10 - frames["start"]])
    assert np.abs(bones(app) - expected).max() < 0.01
    app.wait_for_timeout(500)
    assert app.evaluate("window.motiongen.frameShown") == 10
    app.click("#play")
    s = wait_for(lambda: (st := state(app))["playing"] and st, 5, "Resume plays again")
    # within a second of the server's play head (a CPU-only machine renders slowly)
    wait_for(lambda: abs(app.evaluate("window.motiongen.frameShown") - state(app)["frame_played"])
             <= app.info["fps"], 5, "page follows the live play head again")
    assert s["frame_played"] > 10
    app.rec.assert_clean()


def test_click_on_the_floor_posts_a_goal_and_a_drag_does_not(app):
    set_playing(app, True)
    clear_goals(app)
    floor_y = app.info["floor_y"]
    # a drag orbits the camera: no goal
    hips = state(app)["hips"]
    x, y = app.evaluate("p => window.motiongen.toScreen(p)", [hips[0], floor_y, hips[2]])
    app.mouse.move(x, y)
    app.mouse.down()
    app.mouse.move(x + 60, y + 20, steps=5)
    app.mouse.up()
    app.wait_for_timeout(300)
    assert state(app)["goals"] == [] and app.text_content("#error") == ""
    # a click raycasts the scene (or the floor) and posts the goal
    for gx, gz in nearby_points(app):
        sx, sy = app.evaluate("p => window.motiongen.toScreen(p)", [gx, floor_y, gz])
        app.evaluate("document.querySelector('#error').textContent = ''")  # not the last point's refusal
        app.mouse.click(sx, sy)
        posted = wait_for(lambda: state(app)["goals"] or app.text_content("#error"), 5,
                          "a click posts a goal or shows why not")
        if isinstance(posted, list):
            break
        app.rec.take_rejected_goals()  # furniture there: try the next point
    else:
        raise AssertionError("no click on a nearby floor point was accepted")
    goal = posted[-1]
    assert goal["action"] in (None, app.info["default_action"])
    # on the floor the hit is the point itself; on furniture its top, a little off in x, z
    assert math.hypot(goal["x"] - gx, goal["z"] - gz) < 0.25, (goal, gx, gz)
    clear_goals(app)
    app.rec.assert_clean()


def test_clear_button_removes_goal_markers(app):
    set_playing(app, True)
    clear_goals(app)
    add_goal(app, "api", distance=2.0)
    add_goal(app, "page", distance=1.0)
    wait_for(lambda: app.evaluate("window.motiongen.goalMarkerCount()") >= 1, 5, "markers shown")
    app.click("#clear")
    wait_for(lambda: app.evaluate("window.motiongen.goalMarkerCount()") == 0, 5,
             "markers gone after Clear goals")
    assert state(app)["goals"] == []
    assert app.eval_on_selector_all("#goals li", "lis => lis.length") == 0
    app.rec.assert_clean()


def test_rejected_goal_shows_the_server_error(app):
    bounds = app.info["bounds"] or [[-1000.0, -1000.0], [1000.0, 1000.0]]
    x, z = bounds[1][0] + 100.0, bounds[1][1] + 100.0
    status, answer = api(app.base, "POST", "/api/goals", {"goals": [{"x": x, "z": z}]})
    assert status == 400 and answer["error"]
    result = app.evaluate("([x, z]) => window.motiongen.pickFloor(x, z)", [x, z])
    assert result["ok"] is False and result["error"] == answer["error"]
    assert app.text_content("#error") == answer["error"]
    assert app.is_visible("#error")
    assert app.rec.take_rejected_goals() == 1
    app.rec.assert_clean()
    # the next accepted goal clears the message
    add_goal(app, "page")
    assert app.text_content("#error") == ""
    clear_goals(app)


def test_downloaded_gltf_matches_the_frames(app):
    """motion.glb played in three.js (AnimationMixer) puts the bones where /api/frames says."""
    set_playing(app, True)
    wait_for(lambda: state(app)["frames_generated"] > 40, 10, "some frames generated")
    set_playing(app, False)
    try:
        s = wait_paused_frame(app)
        frames = api(app.base, "GET", f"/api/frames?from=0&rev={s['rev']}")[1]
        fps = app.info["fps"]
        for k in (0, s["frame_played"] // 2):
            joints = app.evaluate("([t]) => window.motiongen.loadGlbJoints('/api/download?format=glb', t, 0)",
                                  [k / fps])
            assert None not in joints, f"motion.glb lacks bones: {joints}"
            expected = np.array(frames["joints"][k - frames["start"]])
            error = np.linalg.norm(np.array(joints) - expected, axis=1)
            assert error.max() < 0.01, f"frame {k}: {error.max() * 100:.2f} cm off"
    finally:
        set_playing(app, True)
    app.rec.assert_clean()
