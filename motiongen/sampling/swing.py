"""Swing lift: a foot that travels between two plants rises at least as high as the training
data's feet rise on a swing of that length.

The network draws a slow walk as a shuffle: its feet slide at 0.1-0.3 m/s, 1.5-2 cm above their
plants. The foot lock holds them still on their plants, so each swing must then cover the slide
it missed in a third of the time, at 0.6-1.5 m/s, and the final solve's swing clearance keeps it
only as high as the network's shuffle. That is a foot gliding over the floor.

`lift_swings` raises each swing of an ankle or toe joint, between the last frame of one plant
and the first of the next, to at least the line between those two frames' heights plus
rise(d)·sin(π·s), s going 0 -> 1 over the swing, d the swing's horizontal length; the final solve
then follows the raised heights (its data and clearance terms). rise(d) is the median of the
training data's own swings of that length (`benchmarks/swing_rise.py` measures it: the embedded
synthetic dataset's swings between plants found by the sampler's own rules). Where the network
lifts a foot higher, its height is kept.
"""

from __future__ import annotations

import numpy as np

from motiongen.skeleton import LEFT_FOOT_JOINTS, RIGHT_FOOT_JOINTS
from motiongen.spans import true_runs

# Swing length (m, the middle of each measured bin) -> median rise (m) above the line between
# the plants, for the ankle and the toe ("foot") joints of the embedded dataset's train split
# (5 929 swings of the four joints; benchmarks/swing_rise.py). Lengths outside the table take
# its end values. Real mocap lifts the toe less on short steps (CMU clips: ~3 cm under 0.4 m).
SWING_LENGTH = np.array([0.075, 0.15, 0.25, 0.35, 0.45, 0.6, 0.85, 1.2])
SWING_RISE = {
    "ankle": np.array([0.043, 0.050, 0.055, 0.063, 0.081, 0.089, 0.094, 0.109]),
    "toe": np.array([0.044, 0.045, 0.050, 0.053, 0.070, 0.087, 0.094, 0.106]),
}
_KIND = {LEFT_FOOT_JOINTS[0]: "ankle", RIGHT_FOOT_JOINTS[0]: "ankle",
         LEFT_FOOT_JOINTS[1]: "toe", RIGHT_FOOT_JOINTS[1]: "toe"}


def swing_rise(kind: str, length) -> np.ndarray:
    """The data's median rise (m) of an ankle or toe swing of horizontal `length` (m)."""
    return np.interp(length, SWING_LENGTH, SWING_RISE[kind])


def swings(planted: np.ndarray) -> list[tuple[int, int]]:
    """[(a, b)]: the unplanted runs of one joint's (T,) flags that have a plant on both sides,
    as the plants' last frame a and the next plant's first frame b (frames a+1..b-1 swing)."""
    runs = true_runs(~np.asarray(planted, bool))
    return [(s - 1, e) for s, e in runs if s > 0 and e < len(planted)]


def lift_swings(joints: np.ndarray, planted: np.ndarray, contact_joints) -> np.ndarray:
    """joints (S, T, J, 3), planted (S, T, C) bool flags of `contact_joints` -> a copy whose
    ankle and toe heights on every swing are at least the data's arc (module docstring).
    Other contact joints are left as they are."""
    out = np.array(joints, dtype=np.float64, copy=True)
    for s in range(out.shape[0]):
        for c, j in enumerate(contact_joints):
            kind = _KIND.get(int(j))
            if kind is None:
                continue
            for a, b in swings(planted[s, :, c]):
                p = out[s, [a, b], j]                                                   # (2, 3)
                frac = np.arange(1, b - a) / (b - a)                                    # (b-a-1,) in (0, 1)
                base = p[0, 1] + frac * (p[1, 1] - p[0, 1])
                arc = base + swing_rise(kind, np.linalg.norm(p[1, [0, 2]] - p[0, [0, 2]])) * np.sin(np.pi * frac)
                out[s, a + 1:b, j, 1] = np.maximum(out[s, a + 1:b, j, 1], arc)
    return out
