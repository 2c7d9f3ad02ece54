"""How high does a foot rise on a swing of a given length? (not a timed test) What
`motiongen.data.swing_rise` measures for a checkpoint's swing table, in detail: on the split's
sequences, the feet's plants are found by the sampler's own rules (the stance labels the
network is trained on, then `spans.clean_plants`), and every swing between two plants is
measured: its horizontal length, and its largest rise above the line between the heights of
the plants' last and first frames. Prints the median and the 10th / 90th percentiles per
length bin, for ankles and toes, beside the embedded table (`swing_rise.EMBEDDED`, what a
checkpoint without its own takes). With `bvh=DIR` the same for real mocap clips, whose plants
are found from the feet alone (slower than 0.2 m/s and within 5 cm of the clip's lowest
heights).

    python benchmarks/swing_rise.py [split=train] [bvh=/usr/share/assimp/models/BVH]
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from motiongen.bvh.retarget import import_bvh
from motiongen.cli import parse_key_values, tool_main
from motiongen.data.swing_rise import EDGES, EMBEDDED, KINDS, dataset_rows, swing_rows
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.skeleton import FOOT_JOINTS
from motiongen.spans import clean_plants

SPEC = {"split": (str, "train"), "bvh": (str, None)}


def bvh_rows(folder: str, fps: float) -> list:
    rows = []
    for f in sorted(Path(folder).glob("*.bvh")):
        j = import_bvh(f, fps=fps).joints.astype(np.float64)                              # (T, J, 3)
        feet = j[:, list(FOOT_JOINTS)]                                                    # (T, 4, 3)
        speed = np.linalg.norm(np.gradient(feet, axis=0), axis=-1) * fps
        low = feet[..., 1] < np.percentile(feet[..., 1], 5, axis=0) + 0.05
        rows += swing_rows(j, clean_plants(low & (speed < 0.2), feet))
    return rows


def print_table(what: str, rows: list) -> None:
    r = np.array(rows).reshape(-1, 3)
    print(f"{what}: {len(r)} swings")
    for kind, joints in KINDS.items():
        m0 = np.isin(r[:, 0], joints)
        for lo, hi in zip(EDGES[:-1], EDGES[1:]):
            m = m0 & (r[:, 1] >= lo) & (r[:, 1] < hi)
            got = ("rise median %.3f m (p10 %.3f, p90 %.3f)" % (np.median(r[m, 2]), *np.percentile(r[m, 2], [10, 90]))
                   if m.any() else "no swings")
            print(f"  {kind:5s} {lo:.2f}-{hi:.2f} m: {int(m.sum()):5d} swings, {got}; "
                  f"embedded table there: {EMBEDDED.at(kind, np.median(r[m, 1])) if m.any() else float('nan'):.3f}")


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, usage=__doc__.splitlines()[-2].strip())
    ds = open_dataset(DataConfig(), verbose=False)
    print_table(f"data, split {opts['split']}", dataset_rows(ds, opts["split"]))
    if opts["bvh"]:
        print_table(f"real mocap, {opts['bvh']}", bvh_rows(opts["bvh"], ds.fps))


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
