"""Runs of flagged frames (contact, action labels) and the weights that ease a constraint in
and out over one: shared by sampling (foot locks, hand reach, seats), evaluation and the
data's swing heights; the rules that turn stance flags into plants a foot is held on."""

from __future__ import annotations

import numpy as np


def true_runs(mask) -> list[tuple[int, int]]:
    """[(start, end)) of the True runs of a 1-D bool array, in order."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def ramp_weights(n: int, ramp: int) -> np.ndarray:
    """(n,) weights rising linearly to 1 over the first `ramp` frames and falling over the last."""
    return np.minimum(1.0, np.minimum(np.arange(1, n + 1), np.arange(n, 0, -1)) / ramp)


def clean_plants(flags, feet, min_frames: int = 5, min_swing: int = 8, same_spot: float = 0.05) -> np.ndarray:
    """Plants to hold a foot on, (T, C) bool, from stance flags (T, C) of C foot joints and their
    positions feet (T, C, 3) at one frame rate:

    * spans shorter than `min_frames` go (flickers of the prediction, not steps);
    * two spans of one joint that hold it within `same_spot` m of each other, split by a short
      gap, are one plant (the prediction blinked);
    * a swing between two plants shorter than `min_swing` frames (0.27 s at 30 fps; real steps
      take twice that) is widened into the plants around it, so the foot has time to travel
      instead of popping from one spot to the next."""
    out = np.array(flags, dtype=bool, copy=True)
    feet = np.asarray(feet)
    for c in range(out.shape[1]):
        col = out[:, c]
        for a, b in true_runs(col):
            if b - a < min_frames:
                col[a:b] = False
        spans = true_runs(col)
        for (a0, b0), (a1, b1) in zip(spans[:-1], spans[1:]):
            gap = a1 - b0
            if gap >= min_swing:
                continue
            spot0, spot1 = feet[a0:b0, c].mean(0), feet[a1:b1, c].mean(0)
            if np.linalg.norm(spot1 - spot0) < same_spot:
                col[b0:a1] = True                                                       # one plant
            else:
                grow = min_swing - gap
                col[max(a0, b0 - (grow + 1) // 2):b0] = False                            # lift off earlier,
                col[a1:min(b1, a1 + grow // 2 + 1)] = False                             # land later
    return out


def swings(planted) -> list[tuple[int, int]]:
    """[(a, b)]: the unplanted runs of one joint's (T,) plant flags that have a plant on both
    sides, as the plant's last frame a and the next plant's first frame b (frames a+1..b-1 swing)."""
    flags = np.asarray(planted, bool)
    return [(s - 1, e) for s, e in true_runs(~flags) if s > 0 and e < len(flags)]
