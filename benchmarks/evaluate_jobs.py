"""`evaluate` in one process and in worker processes (`jobs=N`), timed in one run on this host
(not a timed test): the wall time of each, their ratio, each run's CPU time over its wall time
(how many cores it kept busy), and whether the two reports carry the same figures.

    python benchmarks/evaluate_jobs.py ckpt=PATH|[PATH,PATH,...] [jobs=2] [scenes=[71,72]] [split=val] [pairs=1] [k=2]
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from motiongen.cli import parse_key_values, tool_main

ROOT = Path(__file__).resolve().parents[1]
SPEC = {"ckpt": (list, None), "jobs": (int, 2), "scenes": (list, ["71", "72"]), "split": (str, "val"),
        "pairs": (int, 1), "k": (int, 2)}
TIMINGS = ("seconds", "seconds_per_pair", "wall_s", "jobs", "torch_threads")


def timeless(x):
    """A report without its timings and thread counts, the only things the two runs may differ in."""
    if isinstance(x, dict):
        return {k: timeless(v) for k, v in x.items() if k not in TIMINGS}
    return [timeless(v) for v in x] if isinstance(x, list) else x


def timed(args: list[str], out: Path) -> tuple[float, float, dict]:
    """(wall s, CPU s of the process and its children, report) of one evaluate run."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, str(ROOT / "evaluate.py"), *args, f"out={out}"], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode:
        sys.exit(r.stderr.strip().splitlines()[-1] if r.stderr.strip() else f"evaluate exited {r.returncode}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, json.loads((out / "report.json").read_text())


def run(argv: list[str]) -> None:
    o = parse_key_values(argv, SPEC, required=("ckpt",), usage=__doc__.splitlines()[-2].strip())
    common = [f"ckpt=[{','.join(o['ckpt'])}]", f"split={o['split']}", f"scenes=[{','.join(o['scenes'])}]", f"pairs={o['pairs']}",
              f"k={o['k']}", "ablation_pairs=0", "plots=false", "progress=false"]
    with tempfile.TemporaryDirectory() as tmp:
        one = timed([*common, "jobs=1"], Path(tmp) / "one")
        many = timed([*common, f"jobs={o['jobs']}"], Path(tmp) / "many")
    for name, (wall, cpu, _) in (("jobs=1 (torch's default threads)", one), (f"jobs={o['jobs']}", many)):
        print(f"{name:34s} wall {wall:7.1f} s   CPU {cpu:7.1f} s   cores busy {cpu / wall:.2f}")
    # Equal figures are promised at the same `threads` only; jobs=1 runs on torch's default here.
    print(f"speed-up {one[0] / many[0]:.2f}x; the same figures: {timeless(one[2]) == timeless(many[2])}")


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
