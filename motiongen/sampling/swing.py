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
training data's own swings of that length (`data/swing_rise.py`: measured by `motiongen train`
and saved in the checkpoint). Where the network lifts a foot higher, its height is kept.
"""

from __future__ import annotations

import numpy as np

from motiongen.data.swing_rise import EMBEDDED, KINDS, SwingRise
from motiongen.spans import swings

_KIND = {j: kind for kind, joints in KINDS.items() for j in joints}


def lift_swings(joints: np.ndarray, planted: np.ndarray, contact_joints, table: SwingRise | None = None) -> np.ndarray:
    """joints (S, T, J, 3), planted (S, T, C) bool flags of `contact_joints` -> a copy whose
    ankle and toe heights on every swing are at least the data's arc (module docstring), with
    the rise of `table` (None: the embedded dataset's). Other contact joints are left as they are."""
    table = table if table is not None else EMBEDDED
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
                arc = base + table.at(kind, np.linalg.norm(p[1, [0, 2]] - p[0, [0, 2]])) * np.sin(np.pi * frac)
                out[s, a + 1:b, j, 1] = np.maximum(out[s, a + 1:b, j, 1], arc)
    return out
