"""The sampler's body work, timed alone (not a timed test).

    python benchmarks/body_projection.py [threads=2] [rounds=5] [frames=214]

`MotionBody.project` on one 16-frame window (what every episode pays) at batch 1 and 64, the
joint-space final solve (`loop.solve=joint-space`) of one motion of `frames` output frames
(214: the 7.1 s walk of benchmarks/sample.py), and the L-BFGS stage of the default
`loop.solve=refined` (its REFINED_STEPS iterations from the joint-space result, both feet
planted in turn) on the same motion, once with the hand-written posing pass
(`body/posing.py`) and once with the autograd map it replaced, in this run. Each is the best
of `rounds` rounds (a round: 100, 10, 5, 2 and 2 calls): milliseconds per call. The body and
the joints are made up (the mean shape; its rest pose plus 2 cm of noise per joint), which is
all the cost depends on.

The host's speed moves by a third within minutes, so two versions of the code are compared
by running this in both checkouts in turn, a few times, and comparing the best readings
(`git worktree add /tmp/before REV`, then `cd /tmp/before && PYTHONPATH=. python
benchmarks/body_projection.py`).
"""

from __future__ import annotations

import sys
import time

from dataclasses import replace

import numpy as np
import torch

import motiongen.body.fit as fit
from motiongen.body.model import load_body_model
from motiongen.body.solve import SOLVE_CONFIG, MotionBody
from motiongen.sampling.assemble import REFINED_STEPS
from motiongen.skeleton import BODY, FOOT_JOINTS


def _args(argv):
    out = {"threads": "2", "rounds": "5", "frames": "214"}
    for a in argv:
        k, _, v = a.partition("=")
        if k not in out or not v.isdigit() or int(v) < 1:
            print(f"body_projection: expected threads=N rounds=N frames=N (positive integers), got {a!r}",
                  file=sys.stderr)
            sys.exit(2)
        out[k] = v
    return {k: int(v) for k, v in out.items()}


def _best_ms(fn, calls: int, rounds: int) -> float:
    """The best of `rounds` mean call times of fn (ms), after one untimed call."""
    fn()
    best = float("inf")
    for _ in range(rounds):
        t = time.perf_counter()
        for _ in range(calls):
            fn()
        best = min(best, (time.perf_counter() - t) / calls)
    return 1e3 * best


def main(argv):
    a = _args(argv)
    torch.set_num_threads(a["threads"])
    bm = load_body_model()
    rng = np.random.default_rng(0)
    row = []
    for batch, calls in ((1, 100), (64, 10)):
        body = MotionBody(bm, BODY, torch.zeros(batch, bm.num_betas))
        window = body.rest[:, None].double().numpy() + rng.normal(0, 0.02, (batch, 16, len(BODY.names), 3))
        hint = body.project(window)[1][:, -1]                                   # (S, 22, 3, 3): the last pose
        row.append(_best_ms(lambda: body.project(window, hint), calls, a["rounds"]))
    T = a["frames"]
    motion = body.rest[0].double().numpy() + rng.normal(0, 0.02, (T, len(BODY.names), 3))
    twist = hint[0].expand(T, *hint.shape[1:]).clone()                           # (T, 22, 3, 3)
    row.append(_best_ms(lambda: body.solve_joint_space(0, motion, twist), 5, a["rounds"]))
    print(f"project, one 16-frame window: batch 1 {row[0]:.2f} ms, batch 64 {row[1]:.2f} ms; "
          f"joint-space final solve, {T} frames: {row[2]:.2f} ms (best of {a['rounds']} rounds, "
          f"{a['threads']} threads)")
    planted = (np.arange(T)[:, None] // 15 + np.arange(len(FOOT_JOINTS))[None] // 2) % 2 == 0     # (T, 4) left, right in turn
    start = torch.as_tensor(body.solve_joint_space(0, motion, twist, planted, FOOT_JOINTS).rotmats)
    cfg = replace(SOLVE_CONFIG, max_steps=REFINED_STEPS)
    refined = lambda: body.solve(0, motion, start, planted, FOOT_JOINTS, cfg=cfg)                 # noqa: E731
    hand_written = _best_ms(refined, 2, a["rounds"])
    fit.FixedBodyPose = lambda rest, parents: None      # refine falls back to autograd through the same map
    autograd = _best_ms(refined, 2, a["rounds"])
    print(f"refined solve's L-BFGS stage, {T} frames, {REFINED_STEPS} iterations: {hand_written:.1f} ms "
          f"with the hand-written posing pass, {autograd:.1f} ms with autograd ({autograd / hand_written:.2f}x)")


if __name__ == "__main__":
    main(sys.argv[1:])
