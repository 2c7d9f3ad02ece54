"""How close the network's wrist comes to the hand goal the sampler gives it, in the sampler's
own pick-up episodes (not a timed test).

    python benchmarks/hand_goal_episodes.py ckpt=[PATH] split=val "scenes=[71,73,75,77,79]" pairs=1 k=2 ...

Any `motiongen evaluate` keys: the evaluation runs as usual (its report goes to `out`), with the
sampler's `run_episode` wrapped so that every episode given a hand goal
(`loop.hand_goal`, checkpoints trained with `mask.p_hand` or `mask.p_hand_action`) records, per
sample, the distance from the network's own wrist (before the body) to the goal at the window's
last frame (where the goal is given), its closest approach over the window, the same after
the body projection, and at the window's first frame. Prints their medians and quartiles; where
the goal lies in the body's own frame and how far the body turns over the window; and how far
off its direction of travel the network's walking body faces (`hand_goal.py` prints the last
two for the data).
`benchmarks/hand_goal.py` measures the same on validation windows instead of sampled episodes.
"""

from __future__ import annotations

import sys

import numpy as np

from hand_goal import print_goal_geometry, quartiles

from motiongen.commands import evaluate_command
from motiongen.metrics import heading_off_travel_angles
from motiongen.sampling import autoregressive

RECORDS: list[tuple[float, float, float, float]] = []
GEOMETRY: list[tuple[np.ndarray, int, np.ndarray]] = []   # (network's joints (L, J, 3), wrist, goal (3,))
WALKING: list[np.ndarray] = []                             # facing off travel (degrees), walking episodes


def _recording(run_episode):
    def run(spec, loaded, query, body_model, state, t, *args, **kw):
        run_episode(spec, loaded, query, body_model, state, t, *args, **kw)
        if t.kind == "walk":
            WALKING.extend(heading_off_travel_angles(raw, spec.model_fps) for raw in state.episodes[-1].raw)
        hand = getattr(t, "hand", None)
        if hand is None:
            return
        ep = state.episodes[-1]
        for s in np.flatnonzero(hand >= 0):
            goal = t.hand_point[s]                                                          # (3,) world
            raw = np.linalg.norm(ep.raw[s, :, hand[s]] - goal, axis=-1)                      # (L,)
            body = np.linalg.norm(ep.window[s, :, hand[s]] - goal, axis=-1)                  # (L,)
            RECORDS.append((raw[-1], raw.min(), body[-1], raw[0]))
            GEOMETRY.append((ep.raw[s], int(hand[s]), goal))
    return run


def main(argv) -> None:
    autoregressive.run_episode = _recording(autoregressive.run_episode)
    sys.argv = ["evaluate", *argv]
    try:
        evaluate_command.main()
    except SystemExit as e:                 # Hydra's main exits; the figures come after
        if e.code not in (0, None):
            raise
    a = np.asarray(RECORDS).reshape(-1, 4)
    print(f"episodes x samples with a hand goal: {len(a)}")
    if not len(a):
        return
    for i, name in enumerate(("network's wrist at the goal frame", "closest over the window",
                              "on the body at the goal frame", "at the window's first frame")):
        q = np.percentile(a[:, i], [25, 50, 75])
        print(f"{name:>34}: median {q[1]:.3f} m (quartiles {q[0]:.3f}, {q[2]:.3f})")
    joints, wrist, goal = (np.stack(x) for x in zip(*GEOMETRY))
    print_goal_geometry("the network", joints, wrist, goal)
    print(f"  the network, walking, faces {quartiles(np.concatenate(WALKING), '°')} off its direction of travel")


if __name__ == "__main__":
    main(sys.argv[1:])
