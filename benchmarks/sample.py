"""Sampling speed and goal-reaching quality per sampler setting (not a timed test).

    python benchmarks/sample.py [ckpt=PATH] [threads=2] [preset=paper] [episodes=6] [project=true]
                                [stride=3] [length=16] [samplers=ddpm-100,ddim-50,ddim-25,ddim-10] [batches=1,8]
                                [precisions=fp32,bf16]

Speed: the `paper` preset with random-init weights (speed does not depend on training) on the
CPU, DDPM-100 vs DDIM-50/25/10, batch 1 and 8: real-time factor = seconds of motion produced
(all samples) per second of compute, over a straight 10 m walk in an empty scene. The time
includes everything `sample.py` does to a motion: the per-episode projection onto one body and
the final body solve (foot lock); `project=false` measures the network alone. `stride=2
length=24` gives the model 15 fps windows of the same 1.6 s (the demo's and quality recipe's
rate), which also sets the rate-dependent clean-up (seam blend, the solve's smoothness weight).
Each setting runs once per precision (`precision=` of sample.py: bf16 holds the denoiser's
transformer layers in bfloat16), one after the other in this run, so their ratio is measured
on the host of the moment.
Quality: with `ckpt=` (a trained checkpoint, e.g. the demo), the goal-reaching error at the
same step counts on a fixed goal route: pelvis and hips-midpoint error on arrival (both the
body's own: goals are predicted, not pinned), plus how many goals were reached.
"""

from __future__ import annotations

import copy
import sys
import time
import types
import warnings

import numpy as np
import torch

from motiongen.data.representation import Layout
from motiongen.data.windows import NormStats, WindowConfig
from motiongen.diffusion import DiffusionConfig, GaussianDiffusion, MaskConfig
from motiongen.diffusion.masks import predicts_goal
from motiongen.loading.build import PRECISIONS, load_model, resolve_precision
from motiongen.models import build_model, model_config
from motiongen.sampling import Goal, LoopConfig, SamplerSettings, generate, plan_scene_route
from motiongen.skeleton import BODY


SETTINGS = [("ddpm", 100), ("ddim", 50), ("ddim", 25), ("ddim", 10)]


def _args(argv):
    out = {"ckpt": None, "threads": "2", "preset": "paper", "episodes": "6", "project": "true",
           "stride": "3", "length": "16", "samplers": ",".join(f"{s}-{n}" for s, n in SETTINGS), "batches": "1,8",
           "precisions": "fp32,bf16"}
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
                                 mask=mask, device=torch.device("cpu"))


def _samplers(spec: str) -> list[tuple[str, int]]:
    """'ddim-25,ddpm-100' -> [('ddim', 25), ('ddpm', 100)]."""
    out = []
    for item in filter(None, spec.split(",")):
        name, _, steps = item.partition("-")
        if name not in ("ddpm", "ddim") or not steps.isdigit():
            sys.exit(f"samplers: expected items like ddim-25 or ddpm-100, got {item!r}")
        out.append((name, int(steps)))
    return out


def main(argv):
    a = _args(argv)
    torch.set_num_threads(int(a["threads"]))
    loaded = _random_loaded(a["preset"], int(a["stride"]), int(a["length"]))
    episodes, project = int(a["episodes"]), a["project"] == "true"
    print(f"speed: preset={a['preset']}, {loaded.fps / int(a['stride']):g} fps windows of {a['length']} frames, "
          f"{torch.get_num_threads()} threads, {episodes} episodes per run, "
          f"body projection + solve {'on' if project else 'off'}")
    # one untimed short run first: loading the body model and the first calls' set-up are not
    # sampling speed (the first run reads far slower than the same run after others)
    walk, _ = plan_scene_route((0, 0), [Goal([0, 100.0])], loaded.action_names, path="straight")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        generate(loaded, route=walk, sampler=SamplerSettings("ddim", 2),
                 loop=LoopConfig(warmup=1, max_episodes=1, project=project))
    models = {}
    for prec in filter(None, a["precisions"].split(",")):
        if prec not in PRECISIONS:
            sys.exit(f"precisions: expected some of {', '.join(PRECISIONS)}, got {prec!r}")
        models[prec] = copy.deepcopy(loaded.model).blocks_to(PRECISIONS[prec])
    # what precision=auto (sample.py's default) picks for this preset
    auto = resolve_precision(loaded.model, "auto")
    print(f"precision=auto (the default) uses {auto} for this model")
    print(f"{'sampler':>10} {'batch':>5} {'precision':>9} {'motion s':>9} {'wall s':>7} {'RTF':>6}")
    for sampler, steps in _samplers(a["samplers"]):
        for batch in map(int, filter(None, a["batches"].split(","))):
            for prec, model in models.items():
                loaded.model = model
                loop = LoopConfig(warmup=1, max_episodes=episodes - 1, project=project)
                t = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    m = generate(loaded, route=walk, num_samples=batch,
                                 sampler=SamplerSettings(sampler, steps), generator=torch.Generator().manual_seed(0),
                                 loop=loop)
                wall = time.perf_counter() - t
                print(f"{sampler + '-' + str(steps):>10} {batch:>5} {prec:>9} {batch * m.duration:9.1f} {wall:7.2f} "
                      f"{batch * m.duration / wall:6.2f}", flush=True)
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
