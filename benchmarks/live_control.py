"""Live control (`motiongen serve`): click-to-motion latency and playback stalls, measured by
driving a real server (its own process, as a browser would) through the JSON API, next to the
live sampler's real-time factor in the same run (not a timed test).

    python benchmarks/live_control.py ckpt=PATH [scene=synthetic:91] [clicks=20] [threads=1] [seed=0] [steps=25]

A "click" is what the page does when the user clicks the floor with the body idle, or
shift-clicks while it walks (either way the body must change where it heads): POST /api/goals
(with "replace": true for every second click, 0.7 s after the body set off towards another
goal). Latency is the time from the request until playback reaches the first frame
generated for the new goal (the state's `changed_from`, once its `rev` has moved on): the frames
between the one playing when the request left and that one, at the playback rate, plus any
stall in between. It is read off the server's clock rather than by polling fast, which would
take the CPU the server needs (the client polls every 0.1 s, as the page does). Stalls: seconds
the playback clock waited for frames, per minute of motion played. Goals are random points of
the scene 1.5-4 m from the body that the server accepts.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.error
import urllib.request

import numpy as np

from motiongen.cli import parse_key_values

SPEC = {"ckpt": (str, None), "scene": (str, "synthetic:91"), "clicks": (int, 20), "threads": (int, 1),
        "seed": (int, 0), "steps": (int, 25)}
POLL_S = 0.1


def api(url: str, method: str = "GET", body=None):
    req = urllib.request.Request(url, None if body is None else json.dumps(body).encode(), method=method)
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


def state(url: str) -> dict:
    return api(url + "/api/state")[1]


def wait(url: str, pred, timeout: float = 60.0) -> dict:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        st = state(url)
        if pred(st):
            return st
        time.sleep(POLL_S)
    raise TimeoutError("the server's state never satisfied the condition")


def click(url: str, rng: np.random.Generator, bounds, replace: bool) -> float:
    """One click: POST a goal at a random point 1.5-4 m from the body that the server accepts;
    returns the latency of the accepted request in seconds."""
    (x0, z0), (x1, z1) = bounds
    for _ in range(500):
        here = np.array(state(url)["hips"])[[0, 2]]
        p = rng.uniform([x0, z0], [x1, z1])
        if not 1.5 <= np.linalg.norm(p - here) <= 4.0:
            continue
        t_asked = time.monotonic()
        before = state(url)
        t0 = time.monotonic()
        status, _ = api(url + "/api/goals", "POST", {"goals": [{"x": float(p[0]), "z": float(p[1])}],
                                                    "replace": replace})
        if status != 200:
            continue                        # off the floor, say: the server changed nothing
        # The frame playing when the request left: the state was read half-way through its own
        # request, and playback went on until this one was sent.
        playing = before["time_played"] + (t0 - (t_asked + t0) / 2)
        st = wait(url, lambda s: s["rev"] > before["rev"])
        after = wait(url, lambda s: s["frame_played"] >= st["changed_from"])
        return st["changed_from"] / st["fps"] - playing + (after["stall_s"] - before["stall_s"])
    raise RuntimeError("no accepted goal 1.5-4 m from the body")


def start_server(args) -> tuple[subprocess.Popen, str]:
    cmd = [sys.executable, "-m", "motiongen.commands", "serve", f"ckpt={args['ckpt']}", f"scene={args['scene']}",
           "port=0", f"threads={args['threads']}", f"seed={args['seed']}", f"steps={args['steps']}"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    for line in proc.stdout:
        if line.startswith("serving on "):
            return proc, line.split()[2].rstrip("/")
    raise RuntimeError(f"the server did not start: {' '.join(cmd)}")


def main(argv=None) -> None:
    args = parse_key_values(sys.argv[1:] if argv is None else argv, SPEC, required=("ckpt",))
    proc, url = start_server(args)
    rng, lat = np.random.default_rng(args["seed"]), []
    try:
        bounds = api(url + "/api/info")[1]["bounds"]
        for i in range(args["clicks"]):
            walking = i % 2 == 1
            if walking:                     # set off towards one goal, then change course
                click(url, rng, bounds, replace=False)
                time.sleep(0.7)
            lat.append(click(url, rng, bounds, replace=walking))
            wait(url, lambda s: s["goals"] == [])
        st = state(url)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    lat = np.array(lat)
    minutes = st["time_played"] / 60
    print(f"{args['ckpt']} in {args['scene']}, DDIM-{args['steps']}, server on {args['threads']} threads, "
          f"{len(lat)} clicks over {st['time_played']:.0f} s of motion played")
    print(f"click-to-motion latency: median {np.median(lat):.3f} s, 95th percentile {np.percentile(lat, 95):.3f} s, "
          f"max {lat.max():.3f} s")
    print(f"playback stalls: {st['stall_s']:.2f} s in all, {st['stall_s'] / max(minutes, 1e-9):.2f} s per minute of motion")
    print(f"live sampler: real-time factor {st['real_time_factor']:.1f} (seconds of motion per second of "
          f"generation), {st['episode_s'] * 1000:.0f} ms per episode (running mean)")


if __name__ == "__main__":
    main()
