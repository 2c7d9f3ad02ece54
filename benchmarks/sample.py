"""Sampling speed and goal-reaching quality per sampler setting (not a timed test).

    python benchmarks/sample.py [ckpt=PATH] [threads=2] [preset=paper] [episodes=6] [project=true]
                                [stride=3] [length=16] [samplers=ddpm-100,ddim-50,ddim-25,ddim-10] [batches=1,8]
                                [precisions=fp32,bf16,int8-encoders,int8] [solves=refined] [memos=on] [workers=0]
                                [rounds=1]

Speed: the `paper` preset with random-init weights (speed does not depend on training) on the
CPU, one row per sampler x batch x precision x final-solve method (`loop.solve`), each run in a
fresh child process (so each row's peak resident memory is its own), one after the other in
this run, so their ratios are measured on the host of the moment. A row is a straight 10 m
walk in an empty scene: real-time factor (seconds of motion produced, all samples, per second
of compute), frames per second of output (30 fps frames, all samples), the ratio of its
real-time factor to the first row's, the share of the time spent putting the motion on the
body (the per-episode projection and the final solve) and the child's peak resident memory.
`memos=off,on` adds rows with the action encoder run on every window instead of once per
distinct label window (`Denoiser.memoise_actions`).
`rounds=N` runs every row N times, round after round (the shared host's speed moves within
minutes), and prints each row's run of median wall time with every round's real-time factor.
`workers=N` sets `loop.solve_workers` (0, the default: a batch of 8 or more samples is solved
in one forked process per torch thread, `threads`; 1: one sample after another here). `project=false` measures
the network alone. A distilled student with n steps costs exactly
what `ddim-n` costs here (the same network, guidance folded in, n evaluations per window), so
the issue-27 figure is

    python benchmarks/sample.py samplers=ddim-25,ddim-2,ddim-1 batches=1,64 precisions=fp32,int8-encoders,int8 solves=refined,joint-space

`stride=2 length=24` gives the model 15 fps windows of the same 1.6 s (the demo's and quality
recipe's rate), which also sets the rate-dependent clean-up (seam blend, the solve's weights).
Ceiling: before the rows, what the network's linear layers alone allow on this host at batch
1, in fp32 and as `precision=int8-encoders` and `int8` hold them (`_ceiling`): their
multiply-adds for one window (counted by forward hooks on a one-step run: the scene encoder
once, the denoiser once per step, the action encoder as memoised), timed back to back at the
window's own shapes, against the seconds of motion a window adds. No
sampler with that many steps can be faster than that bound, whatever else it saves; a
row's real-time factor over it says how much of the time the rest (attention, norms, the
body) takes.
Quality: with `ckpt=` (a trained checkpoint, e.g. the demo), the goal-reaching error at the
same step counts on a fixed goal route: pelvis and hips-midpoint error on arrival (both the
body's own: goals are predicted, not pinned), plus how many goals were reached.
"""

from __future__ import annotations

import functools
import multiprocessing
import resource
import sys
import time
import types
import warnings

import numpy as np
import torch

from motiongen.body.model import load_body_model
from motiongen.data.representation import Layout
from motiongen.data.windows import NormStats, WindowConfig
from motiongen.diffusion import DiffusionConfig, GaussianDiffusion, MaskConfig
from motiongen.diffusion.masks import predicts_goal
from motiongen.loading.build import PRECISIONS, load_model, resolve_precision, set_precision
from motiongen.models import build_model, model_config
from motiongen.sampling import Goal, LoopConfig, SamplerSettings, autoregressive, cleanup, generate, plan_scene_route
from motiongen.sampling.assemble import SOLVE_METHODS
from motiongen.skeleton import BODY


SETTINGS = [("ddpm", 100), ("ddim", 50), ("ddim", 25), ("ddim", 10)]


def _args(argv):
    out = {"ckpt": None, "threads": "2", "preset": "paper", "episodes": "6", "project": "true",
           "stride": "3", "length": "16", "samplers": ",".join(f"{s}-{n}" for s, n in SETTINGS), "batches": "1,8",
           "precisions": "fp32,bf16,int8-encoders,int8", "solves": "refined", "memos": "on", "workers": "0",
           "rounds": "1"}
    for a in argv:
        k, _, v = a.partition("=")
        out[k] = v
    return out


def _random_loaded(preset: str, stride: int, length: int):
    """A paper-size denoiser with random weights in today's layout (absolute joints + stance
    channels, goal predicted): speed does not depend on training."""
    window, diffusion = WindowConfig(stride=stride, length=length), DiffusionConfig()
    mask = MaskConfig(max_transition=max(1, round(0.2 * 30 / stride)))      # 0.2 s pinned, as the recipes
    layout = Layout.for_window(window, BODY)
    model = build_model(model_config(preset), 22, 10, window.length, channels=layout.channels)
    center = np.zeros(layout.channels, np.float32)
    center[1:layout.pose_channels:3] = 0.6                      # joints around hip height
    half = np.full(layout.channels, 1.5, np.float32)
    half[layout.pose_channels:] = 1.0                             # stance channels are +-1 labels
    return types.SimpleNamespace(model=model.eval().requires_grad_(False), diffusion=GaussianDiffusion(diffusion),
                                 stats=NormStats(center, half), joint_set=BODY, layout=layout,
                                 predict_goal=predicts_goal(mask, diffusion.prediction), fps=30.0,
                                 model_fps=30.0 / window.stride,
                                 action_names=[f"a{i}" for i in range(10)], window=window,
                                 mask=mask, device=torch.device("cpu"),
                                 swing_rise=None)                 # the embedded dataset's swing table


def _samplers(spec: str) -> list[tuple[str, int]]:
    """'ddim-25,ddpm-100' -> [('ddim', 25), ('ddpm', 100)]."""
    out = []
    for item in filter(None, spec.split(",")):
        name, _, steps = item.partition("-")
        if name not in ("ddpm", "ddim") or not steps.isdigit():
            sys.exit(f"samplers: expected items like ddim-25 or ddpm-100, got {item!r}")
        out.append((name, int(steps)))
    return out


def _speed_row(a: dict, sampler: str, steps: int, batch: int, prec: str, solve: str, memo: str, out) -> None:
    """One speed row in this (child) process: the same run at batch 1 untimed first (the first
    calls' set-up is not sampling speed: a one-episode warm-up left the timed run's body work
    at 2-3x its later cost), then the timed one. Puts (motion s, frames, wall s, body s, peak
    RSS MiB) on `out`."""
    torch.set_num_threads(int(a["threads"]))
    torch.manual_seed(0)
    loaded = _random_loaded(a["preset"], int(a["stride"]), int(a["length"]))
    loaded.model = set_precision(loaded.model, prec)
    loaded.model.memoise_actions = memo == "on"
    project = a["project"] == "true"
    walk, _ = plan_scene_route((0, 0), [Goal([0, 100.0])], loaded.action_names, path="straight")
    bm = load_body_model()                         # loaded once, as `sample` and `evaluate` do
    body_s = _time_body()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loop = LoopConfig(warmup=1, max_episodes=int(a["episodes"]) - 1, project=project, solve=solve,
                          solve_workers=int(a["workers"]))
        generate(loaded, route=walk, sampler=SamplerSettings(sampler, steps), body_model=bm, loop=loop,
                 generator=torch.Generator().manual_seed(1))
        body_s[0] = 0.0
        loaded.model.eval()                        # an empty action memo: the timed run fills its own
        t = time.perf_counter()
        m = generate(loaded, route=walk, num_samples=batch, sampler=SamplerSettings(sampler, steps),
                     generator=torch.Generator().manual_seed(0), loop=loop, body_model=bm)
        wall = time.perf_counter() - t
    out.put((batch * m.duration, batch * m.joints.shape[1], wall, body_s[0],
             resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024))


def _ceiling(a: dict, steps: list[int]) -> None:
    """Print the real-time factor the network's linear layers alone allow at batch 1, in fp32
    and with int8 layers (the encoders', then all), for each step count: a one-step run of the
    rows' walk (`episodes` windows, no body) counts each layer's multiply-adds and input shape
    per window (forward hooks), then those layers are timed back to back. Run in a child process (spawned: the linear layers' copies would
    otherwise raise the peak memory the rows' children inherit)."""
    torch.set_num_threads(int(a["threads"]))
    loaded, episodes = _random_loaded(a["preset"], int(a["stride"]), int(a["length"])), int(a["episodes"])
    calls = []                                                   # (name, rows M of the input, weight (N, K))

    def hook(mod, inputs, _, name):
        calls.append((name, inputs[0].numel() // mod.in_features, mod.weight))

    hooks = [mod.register_forward_hook(functools.partial(hook, name=name))
             for name, mod in loaded.model.named_modules() if isinstance(mod, torch.nn.Linear)]
    walk, _ = plan_scene_route((0, 0), [Goal([0, 100.0])], loaded.action_names, path="straight")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = generate(loaded, route=walk, sampler=SamplerSettings("ddim", 1), body_model=None,
                     loop=LoopConfig(warmup=1, max_episodes=episodes - 1, project=False, solve="joint-space"),
                     generator=torch.Generator().manual_seed(0))
    for h in hooks:
        h.remove()
    windows = len(m.episode_starts)
    encoders = [c[0].startswith(("scene_encoder.", "action_encoder.")) for c in calls]
    once = [c for c, e in zip(calls, encoders) if e]
    per_step = [c for c, e in zip(calls, encoders) if not e]

    def seconds(cs, int8):                                       # the layers back to back, best of 5
        layers = torch.nn.ModuleDict()                           # each layer once, under its weight's id
        for _, _, w in cs:
            if str(id(w)) not in layers:
                layers[str(id(w))] = torch.nn.Linear(w.shape[1], w.shape[0])
                with torch.no_grad():
                    layers[str(id(w))].weight.copy_(w.float())
        if int8:                                                 # as Denoiser.quantize_layers
            layers = torch.ao.quantization.quantize_dynamic(
                layers, {torch.nn.Linear: torch.ao.quantization.per_channel_dynamic_qconfig}, dtype=torch.qint8)
        xs = [(layers[str(id(w))], torch.randn(M, w.shape[1])) for _, M, w in cs]
        best = float("inf")
        for _ in range(5):
            t = time.perf_counter()
            with torch.inference_mode():
                for layer, x in xs:
                    layer(x)
            best = min(best, time.perf_counter() - t)
        return best / windows

    flops = [sum(2 * M * w.numel() for _, M, w in cs) / windows for cs in (once, per_step)]
    motion = m.duration / windows
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                          # torch's eager quantization API is marked deprecated
        t = {(part, int8): seconds(cs, int8) for part, cs in (("once", once), ("step", per_step)) for int8 in (0, 1)}
    for prec, (t_once, t_step) in (("fp32", (t["once", 0], t["step", 0])),
                                   ("int8-encoders", (t["once", 1], t["step", 0])),
                                   ("int8", (t["once", 1], t["step", 1]))):
        print(f"ceiling at batch 1, {prec}, linear layers only: {motion:.2f} s of motion per window; encoders "
              f"{flops[0] / 1e9:.2f} GFLOP in {1e3 * t_once:.1f} ms, each denoising step {flops[1] / 1e9:.2f} "
              f"GFLOP in {1e3 * t_step:.1f} ms ({(flops[0] + flops[1]) / (t_once + t_step) / 1e9:.0f} GFLOP/s)")
        print("  at most " + ", ".join(f"{motion / (t_once + n * t_step):.1f}x real time for {n} step{'s' * (n > 1)}"
                                       for n in steps))


def _time_body() -> list:
    """Seconds spent in the per-episode projection and the final solve, summed into the
    returned one-element list (the two functions wrapped where the sampler looks them up)."""
    total = [0.0]
    for module, name in ((autoregressive, "project_window"), (cleanup, "solve_bodies")):
        fn = getattr(module, name)

        def timed(*args, _fn=fn, **kw):
            t = time.perf_counter()
            try:
                return _fn(*args, **kw)
            finally:
                total[0] += time.perf_counter() - t

        setattr(module, name, timed)
    return total


def main(argv):
    a = _args(argv)
    precisions = [p for p in a["precisions"].split(",") if p]
    for prec in precisions:
        if prec not in PRECISIONS:
            sys.exit(f"precisions: expected some of {', '.join(PRECISIONS)}, got {prec!r}")
    solves = [s for s in a["solves"].split(",") if s]
    for solve in solves:
        if solve not in SOLVE_METHODS:
            sys.exit(f"solves: expected some of {', '.join(SOLVE_METHODS)}, got {solve!r}")
    memos = [m for m in a["memos"].split(",") if m]
    if not memos or set(memos) - {"on", "off"}:
        sys.exit(f"memos: expected on, off or both, got {a['memos']!r}")
    print(f"speed: preset={a['preset']}, {30.0 / int(a['stride']):g} fps windows of {a['length']} frames, "
          f"{a['threads']} threads, {a['episodes']} episodes per run, "
          f"body projection + solve {'on' if a['project'] == 'true' else 'off'} (solve workers {a['workers']}), "
          f"one child process per row")
    torch.set_num_threads(int(a["threads"]))
    loaded = _random_loaded(a["preset"], int(a["stride"]), int(a["length"]))
    print(f"precision=auto (the default) uses {resolve_precision(loaded.model, 'auto')} for this model")
    ctx = multiprocessing.get_context("spawn")
    p = ctx.Process(target=_ceiling, args=(a, [n for _, n in _samplers(a["samplers"])]))
    p.start()                                  # a child of its own: its layer copies stay out of the rows' peak memory
    p.join()
    rows = [(sampler, steps, batch, prec, solve, memo) for sampler, steps in _samplers(a["samplers"])
            for batch in map(int, filter(None, a["batches"].split(","))) for prec in precisions
            for solve in solves for memo in memos]
    rounds = int(a["rounds"])
    readings = {row: [] for row in rows}       # (motion s, frames, wall s, body s, peak MiB) per round
    for r in range(rounds):                    # round after round: every row sees the host of each round
        for row in rows:
            q = ctx.Queue()
            p = ctx.Process(target=_speed_row, args=(a, *row, q))
            p.start()
            readings[row].append(q.get())
            p.join()
        if rounds > 1:
            print(f"round {r + 1} of {rounds} done", flush=True)
    print(f"{'sampler':>10} {'batch':>5} {'precision':>13} {'solve':>11} {'memo':>4} {'motion s':>9} {'wall s':>7} "
          f"{'RTF':>6} {'frames/s':>8} {'x first':>7} {'body %':>6} {'peak MiB':>8}" + ("  RTF each round" * (rounds > 1)))
    first = {}
    for row in rows:
        sampler, steps, batch, prec, solve, memo = row
        runs = sorted(readings[row], key=lambda x: x[2])
        motion_s, frames, wall, body, rss = runs[len(runs) // 2]               # the median wall time's run
        rtf = motion_s / wall
        ref = first.setdefault(batch, rtf)
        each = "  " + ", ".join(f"{m / w:.2f}" for m, _, w, _, _ in readings[row]) if rounds > 1 else ""
        print(f"{sampler + '-' + str(steps):>10} {batch:>5} {prec:>13} {solve:>11} {memo:>4} {motion_s:9.1f} "
              f"{wall:7.2f} {rtf:6.2f} {frames / wall:8.0f} {rtf / ref:7.2f} {100 * body / wall:6.1f} "
              f"{max(x[4] for x in runs):8.0f}" + each, flush=True)
    if not a["ckpt"]:
        print("quality: pass ckpt=PATH (a trained checkpoint) for goal-reaching errors")
        return
    ld = load_model(a["ckpt"], precision="auto")
    goals = [Goal([1.5, 2.0]), Goal([-1.0, 4.0]), Goal([0.5, 6.0])]
    route, _ = plan_scene_route((0, 0), goals, ld.action_names)
    print(f"quality: {a['ckpt']} (step {ld.step}), 3 goals over ~7 m in an empty scene, 4 samples")
    print(f"{'sampler':>10} {'reached':>8} {'pelvis m':>9} {'hips m':>7} {'RTF':>6}")
    for sampler, steps in SETTINGS:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = generate(ld, route=route, num_samples=4, sampler=SamplerSettings(sampler, steps),
                         generator=torch.Generator().manual_seed(0), loop=LoopConfig(max_episodes=40))
        r = np.isfinite(m.arrival_error)
        print(f"{sampler + '-' + str(steps):>10} {r.sum():>4}/{r.size:<3} {np.nanmean(m.arrival_error):9.3f} "
              f"{np.nanmean(m.arrival_error_body):7.3f} {m.real_time_factor:6.2f}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
