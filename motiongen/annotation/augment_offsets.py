"""Contact-preserving target offsets (TRUMANS supp. B.5, Eq. A1–A6 and the bound A13).

When an object a joint touches changes, the joint's target moves with its contact point:
l'_t = l_t + v_m'(t) - v_m(t) (A1–A2). The offset is eased in and out over a window of W frames
with linearly falling weight, v_{i,t} = (1 - |t - T_i| / W) v_i (A3), and where offsets of
several contacts overlap (one contact ending while the next begins) the joint gets their
norm-weighted mean, sum_i |v_{i,t}| v_{i,t} / sum_i |v_{i,t}| (A5–A6). Then, for constant offsets,

    |l'_{t+1} - l'_t| <= |l_{t+1} - l_t| + 4/W (|v_1| + |v_2|)          (A13)

A contact here lasts a span of frames [start, end) rather than the paper's single instant T_i:
inside the span the offset applies in full (it may vary per frame, e.g. for an object that is
carried), and the ramps start at the span's ends, so weights still change by at most 1/W per
frame and the bound holds as stated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class ContactEvent:
    """One contact of one joint: frames [start, end) and the offset (n, 3) or (3,) of its
    contact point at each of them, v'_m - v_m in world coordinates (Eq. A1–A2)."""

    start: int
    end: int
    offset: np.ndarray

    def offsets(self) -> np.ndarray:
        n = self.end - self.start
        return np.broadcast_to(np.asarray(self.offset, np.float64), (n, 3))


def ramp_weights_span(T: int, start: int, end: int, window: int) -> np.ndarray:
    """(T,) weights: 1 on [start, end), falling linearly to 0 over `window` frames on both
    sides: 1 - |t - T_i| / W with T_i the nearest frame of the span (Eq. A3)."""
    t = np.arange(T)
    gap = np.maximum(start - t, t - (end - 1)).clip(min=0)
    return np.clip(1.0 - gap / float(window), 0.0, 1.0)


def blended_offsets(T: int, events: list[ContactEvent], window: int) -> np.ndarray:
    """(T, 3) offset of one joint: each event's offset eased over `window` frames (A3, A6),
    overlapping ones combined by their norm-weighted mean (A5). Zero far from every contact."""
    if window < 1:
        raise ValueError(f"window must be >= 1 frame, got {window}")
    if not events:
        return np.zeros((T, 3))
    parts = []
    for e in events:
        full = np.zeros((T, 3))
        off = e.offsets()
        full[e.start:e.end] = off
        full[:e.start] = off[0]              # before the span: its first offset, eased in
        full[e.end:] = off[-1]               # after: its last offset, eased out
        parts.append(full * ramp_weights_span(T, e.start, e.end, window)[:, None])
    v = np.stack(parts)                                                              # (E, T, 3)
    norm = np.linalg.norm(v, axis=-1, keepdims=True)                                 # (E, T, 1)
    total = norm.sum(0)                                                              # (T, 1)
    return np.where(total > 0, (norm * v).sum(0) / np.maximum(total, 1e-300), 0.0)


def target_trajectory(joint: np.ndarray, events: list[ContactEvent], window: int) -> np.ndarray:
    """l'_t = l_t + offset_t for one joint's trajectory (T, 3)."""
    return np.asarray(joint, np.float64) + blended_offsets(len(joint), events, window)


def smoothness_bound(joint: np.ndarray, events: list[ContactEvent], window: int) -> np.ndarray:
    """(T-1,) right-hand side of Eq. A13 generalised to E constant offsets:
    |l_{t+1} - l_t| + 4/W * sum_i |v_i| (for E <= 2 exactly the paper's bound)."""
    step = np.linalg.norm(np.diff(np.asarray(joint, np.float64), axis=0), axis=-1)
    mags = sum(float(np.linalg.norm(e.offsets(), axis=-1).max()) for e in events)
    return step + 4.0 / window * mags
