"""A distilled student against its teacher, window by window (not a timed test).

    python benchmarks/distill.py teacher=PATH students=PATH[,PATH...] [windows=256] [batches=1,8]
                                 [threads=1] [split=val] [seed=0]

On `windows` windows of the teacher's `split` (validation by default), each with the sampler's
known entries (the first `mask.max_transition` frames pinned, the goal pelvis x, z given, as
`motiongen sample` gives them), every model draws from the same x_T:

* fidelity: the RMS (normalised units, over the entries the model predicts) and the mean
  pelvis distance at the window's last frame (metres) between its output and the teacher's
  guided DDIM-`teacher_steps` output, the student's target; the teacher's own DDIM at the
  student's step count is the row to beat (what the same budget gives without distillation);
* speed: seconds per window of the denoising alone (encoders included), at each batch size,
  each row timed after one untimed call, all in this run on the host of the moment.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import torch

from motiongen.data.windows import WindowDataset
from motiongen.diffusion import sample
from motiongen.diffusion.masks import replace_mask
from motiongen.importers.sources import open_dataset
from motiongen.loading.build import data_config, fixed_known_mask, load_model
from motiongen.models import Condition
from motiongen.skeleton import PELVIS


def _args(argv):
    out = {"teacher": None, "students": "", "windows": "256", "batches": "1,8", "threads": "1", "split": "val",
           "seed": "0"}
    for a in argv:
        k, _, v = a.partition("=")
        if k not in out:
            sys.exit(f"unknown key {k!r}; expected one of {', '.join(out)}")
        out[k] = v
    if not out["teacher"]:
        sys.exit("teacher=PATH is required")
    return out


def _windows(teacher, split: str, n: int, seed: int) -> dict:
    """n windows of `split` with the sampler's known entries: motion (n, L, D), cond, mask."""
    ws = WindowDataset(open_dataset(data_config(teacher.config), verbose=False), split, teacher.window, teacher.stats)
    idx = torch.randperm(len(ws), generator=torch.Generator().manual_seed(seed))[:n]
    items = [ws[int(i)] for i in idx]
    batch = {k: torch.stack([it[k] for it in items]) for k in items[0]}
    mask = fixed_known_mask(batch["motion"].shape, int(teacher.mask.max_transition), True, "cpu")
    return {"motion": batch["motion"], "scene": batch.get("scene"), "actions": batch["actions"], "mask": mask}


def _run(loaded, w: dict, rows: slice, steps: int, guidance: float, seed: int) -> torch.Tensor:
    x0, mask = w["motion"][rows], w["mask"][rows]
    cond = Condition(scene=None if w["scene"] is None else w["scene"][rows], actions=w["actions"][rows])
    return sample(loaded.diffusion, loaded.model, tuple(x0.shape), cond, known=x0, known_mask=mask, steps=steps,
                  guidance_scale=guidance, generator=torch.Generator().manual_seed(seed),
                  replace_mask=replace_mask(mask, loaded.predict_goal))


def _all(loaded, w: dict, steps: int, guidance: float, seed: int, chunk: int = 64) -> torch.Tensor:
    n = w["motion"].shape[0]
    return torch.cat([_run(loaded, w, slice(b, b + chunk), steps, guidance, seed + b) for b in range(0, n, chunk)])


def _fidelity(loaded, out: torch.Tensor, ref: torch.Tensor, mask: torch.Tensor) -> tuple[float, float]:
    """(RMS over the predicted entries, mean last-frame pelvis distance in metres)."""
    free = ~replace_mask(mask, loaded.predict_goal)
    rms = float(((out - ref)[free] ** 2).mean().sqrt())
    a = loaded.layout.decode(loaded.stats.denormalize(out.numpy()).astype(np.float64))[0]
    b = loaded.layout.decode(loaded.stats.denormalize(ref.numpy()).astype(np.float64))[0]
    return rms, float(np.linalg.norm(a[:, -1, PELVIS] - b[:, -1, PELVIS], axis=-1).mean())


def _seconds_per_window(loaded, w: dict, steps: int, guidance: float, batch: int, repeats: int = 8) -> float:
    _run(loaded, w, slice(0, batch), steps, guidance, 0)                     # untimed: first-call set-up
    t = time.perf_counter()
    for r in range(repeats):
        _run(loaded, w, slice(r * batch, (r + 1) * batch), steps, guidance, r)
    return (time.perf_counter() - t) / (repeats * batch)


def main(argv):
    a = _args(argv)
    torch.set_num_threads(int(a["threads"]))
    teacher = load_model(a["teacher"])
    students = [load_model(p) for p in filter(None, a["students"].split(","))]
    info = [s.distill for s in students]
    if any(i is None for i in info):
        sys.exit("students: every checkpoint must be a distilled student")
    t_steps = info[0]["teacher_steps"] if info else 25
    guidance = info[0]["guidance_scale"] if info else 1.0
    w = _windows(teacher, a["split"], int(a["windows"]), int(a["seed"]))
    seed = int(a["seed"])
    ref = _all(teacher, w, t_steps, guidance, seed)
    rows = [(f"teacher DDIM-{t_steps}", teacher, t_steps, guidance)]
    for s, i in zip(students, info):
        rows += [(f"teacher DDIM-{i['steps']}", teacher, i["steps"], guidance),
                 (f"student {i['steps']}-step (step {s.step})", s, i["steps"], 1.0)]
    batches = [int(b) for b in a["batches"].split(",") if b]
    print(f"{len(w['motion'])} {a['split']} windows, {torch.get_num_threads()} threads; reference: teacher "
          f"DDIM-{t_steps}, guidance {guidance:g}")
    print(f"{'model':<34} {'RMS':>7} {'pelvis m':>9} " + " ".join(f"{f's/window b{b}':>13}" for b in batches))
    for name, loaded, steps, g in rows:
        rms, pelvis = _fidelity(loaded, _all(loaded, w, steps, g, seed), ref, w["mask"])
        speed = [_seconds_per_window(loaded, w, steps, g, b) for b in batches]
        print(f"{name:<34} {rms:7.4f} {pelvis:9.4f} " + " ".join(f"{v:13.5f}" for v in speed), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
