"""Runs of flagged frames (contact, action labels) and the weights that ease a constraint in
and out over one: shared by sampling (foot locks, hand reach, seats) and evaluation."""

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
