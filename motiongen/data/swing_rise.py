"""How high a dataset's feet rise on a swing of a given length: the table the sampler's swing
lift raises the output's swings to (`sampling/swing.py`).

Plants are found by the sampler's own rules: the stance labels the network is trained on
(`representation.stance_labels`), then `spans.clean_plants`. Each swing between two plants of an
ankle or toe joint gives its horizontal length and its largest rise above the line between the
heights of the plant's last frame and the next plant's first. The table is the median rise per
length bin. `motiongen train` measures it on its training split and saves it in the checkpoint
(`swing_rise`); a checkpoint without one takes EMBEDDED, the embedded synthetic dataset's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from motiongen.data.format import release
from motiongen.data.representation import stance_labels
from motiongen.skeleton import FOOT_JOINTS, LEFT_FOOT_JOINTS, RIGHT_FOOT_JOINTS
from motiongen.spans import clean_plants, swings

# Length bins (m) of the swings measured; a bin's point in the table is its swings' median
# length and median rise.
EDGES = np.array([0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.7, 1.0, 3.0])
KINDS = {"ankle": (LEFT_FOOT_JOINTS[0], RIGHT_FOOT_JOINTS[0]), "toe": (LEFT_FOOT_JOINTS[1], RIGHT_FOOT_JOINTS[1])}
MIN_SWINGS = 5          # a bin with fewer swings of a kind is left out of that kind's table


@dataclass
class SwingRise:
    """Median rise (m) of the ankle and toe swings by swing length (m): at(kind, d) reads it
    linearly between the lengths, and takes its end values beyond them."""

    length: dict            # kind -> (B,) swing lengths, ascending
    rise: dict              # kind -> (B,) median rise at those lengths
    swings: int = 0         # swings measured

    def at(self, kind: str, d) -> np.ndarray:
        return np.interp(d, self.length[kind], self.rise[kind])

    def state_dict(self) -> dict:
        return {"length": {k: np.asarray(v).tolist() for k, v in self.length.items()},
                "rise": {k: np.asarray(v).tolist() for k, v in self.rise.items()}, "swings": int(self.swings)}

    @classmethod
    def from_state_dict(cls, d: dict) -> "SwingRise":
        return cls({k: np.asarray(v, np.float64) for k, v in d["length"].items()},
                   {k: np.asarray(v, np.float64) for k, v in d["rise"].items()}, int(d.get("swings", 0)))


# The embedded synthetic dataset's train split (5 929 swings; `benchmarks/swing_rise.py`). Real
# mocap lifts the toe less on short steps (CMU clips: ~3 cm under 0.4 m).
EMBEDDED = SwingRise({"ankle": np.array([0.076, 0.157, 0.251, 0.344, 0.433, 0.606, 0.879, 1.143]),
                      "toe": np.array([0.075, 0.152, 0.260, 0.329, 0.440, 0.606, 0.873, 1.132])},
                     {"ankle": np.array([0.043, 0.050, 0.055, 0.063, 0.081, 0.089, 0.094, 0.109]),
                      "toe": np.array([0.044, 0.045, 0.051, 0.053, 0.070, 0.088, 0.094, 0.106])}, 5929)


def swing_rows(joints: np.ndarray, planted: np.ndarray) -> list[tuple[int, float, float]]:
    """[(joint, length m, rise m)] of every swing of the FOOT_JOINTS: joints (T, J, 3), planted
    (T, 4) plant flags of FOOT_JOINTS."""
    rows = []
    for c, j in enumerate(FOOT_JOINTS):
        for a, b in swings(planted[:, c]):
            y = joints[a:b + 1, j, 1]
            rise = (y - np.linspace(y[0], y[-1], len(y))).max()
            rows.append((j, float(np.linalg.norm(joints[b, j, [0, 2]] - joints[a, j, [0, 2]])), float(rise)))
    return rows


def sequence_rows(joints: np.ndarray, contact: np.ndarray, fps: float, stance_speed: float = 0.2) -> list:
    """swing_rows of one sequence, joints (T, J, 3), contact (T, J) labels, at fps; plants from
    the stance labels at `stance_speed` (the window config's, as the network learns them)."""
    j = np.asarray(joints, np.float64)
    planted = clean_plants(stance_labels(j, contact, FOOT_JOINTS, fps, stance_speed), j[:, list(FOOT_JOINTS)])
    return swing_rows(j, planted)


def dataset_rows(ds, split: str | None = "train", stance_speed: float = 0.2) -> list:
    """sequence_rows of every sequence of a `MotionDataset`'s split (its joints' resident pages
    dropped after, as `windows.compute_stats` does)."""
    rows = []
    for seq in ds.split_sequences(split):
        rows += sequence_rows(np.asarray(ds.joints[seq.start:seq.end]), np.asarray(ds.contact[seq.start:seq.end]),
                              ds.fps, stance_speed)
    release(ds.joints)
    return rows


def table(rows: Iterable[tuple[int, float, float]]) -> SwingRise | None:
    """The median rise per length bin of swing rows; None when some kind has no bin with
    MIN_SWINGS swings (the data has no walk to learn a swing from)."""
    r = np.asarray(list(rows), np.float64).reshape(-1, 3)
    length, rise = {}, {}
    for kind, joints in KINDS.items():
        ours = r[np.isin(r[:, 0], joints)]
        kept = [(np.median(ours[m, 1]), np.median(ours[m, 2])) for lo, hi in zip(EDGES[:-1], EDGES[1:])
                if (m := (ours[:, 1] >= lo) & (ours[:, 1] < hi)).sum() >= MIN_SWINGS]
        if not kept:
            return None
        length[kind], rise[kind] = (np.array(v) for v in zip(*kept))
    return SwingRise(length, rise, len(r))


def measure(ds, split: str | None = "train", stance_speed: float = 0.2) -> SwingRise | None:
    """The swing table of a `MotionDataset`'s split, from its joints and contact labels (None:
    see `table`)."""
    return table(dataset_rows(ds, split, stance_speed))
