"""Training-window throughput with occupancy queries, and peak memory vs dataset size.

    python benchmarks/data.py [--windows 3000] [--workers 0]

Generates (or reuses from the cache) the synthetic `default` dataset and writes a `double` one
holding every sequence twice (exactly 2x the frames, same scenes), then in a fresh process per dataset: opens it, computes the train-split
statistics, and reads random windows (canonicalised joints, local 32^3 occupancy with objects,
actions). Prints windows/s and peak RSS; memory must not grow with the dataset (ratio ~1).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def measure(root: str, n: int, workers: int) -> dict:
    import numpy as np
    import torch

    from motiongen.data.format import MotionDataset
    from motiongen.data.windows import WindowConfig, WindowDataset

    torch.set_num_threads(1)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    ds = MotionDataset.open(root)
    t0 = time.perf_counter()
    wd = WindowDataset(ds, "train", WindowConfig())
    t_stats = time.perf_counter() - t0
    idx = np.random.default_rng(0).choice(len(wd), size=min(n, len(wd)), replace=False)
    loader = torch.utils.data.DataLoader(torch.utils.data.Subset(wd, idx.tolist()), batch_size=64,
                                         num_workers=workers)
    t0 = time.perf_counter()
    count = 0
    for batch in loader:
        count += batch["motion"].shape[0]
    dt = time.perf_counter() - t0
    return {"frames": ds.num_frames, "train_windows": len(wd), "stats_s": t_stats, "windows_per_s": count / dt,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "baseline_rss_mb": rss0 / 1024}


def double_of(ds):
    """The dataset with every sequence written twice (cached beside it)."""
    import numpy as np

    from motiongen.data.format import MotionDataset
    from motiongen.data.dataset_writer import DatasetWriter
    from motiongen.scene.occupancy import OccupancyGrid

    root = ds.root.with_name(ds.root.name + "-x2")
    if (root / "meta.json").is_file():
        return MotionDataset.open(root)
    w = DatasetWriter(root, ds.joint_set, ds.action_names, ds.fps, num_object_slots=ds.meta["num_object_slots"],
                      overwrite=root.exists())
    for sid, entry in ds.scenes.items():
        w.add_scene(sid, grid=OccupancyGrid.load(ds.root / entry["grid"]) if entry.get("grid") else None)
    for oid, entry in ds.objects.items():
        w.add_object(oid, entry["name"], entry["type"], ds.object_mesh(oid))
    for copy in range(2):
        for s in ds.sequences:
            sl = slice(s.start, s.end)
            w.add_sequence(f"{s.name}#{copy}", s.scene, ds.joints[sl], ds.actions[sl], ds.contact[sl],
                           object_poses=None if ds.object_poses is None else np.asarray(ds.object_poses[sl]),
                           object_ids=None if ds.object_ids is None else np.asarray(ds.object_ids[sl]))
    w.finish(splits=ds.splits, source="benchmark-x2")
    return MotionDataset.open(root)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--windows", type=int, default=3000)
    ap.add_argument("--workers", type=int, default=0)
    ap.add_argument("--measure", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.measure:
        print(json.dumps(measure(a.measure, a.windows, a.workers)))
        return
    from motiongen.importers.sources import DataConfig, open_dataset
    results = {}
    default = open_dataset(DataConfig(source="synthetic", size="default"))
    datasets = {"default": default, "double": double_of(default)}
    for size, ds in datasets.items():
        print(f"{size}: {ds.num_frames} frames ({ds.num_frames / ds.fps / 60:.1f} min) at {ds.root}", flush=True)
        out = subprocess.run([sys.executable, __file__, "--measure", str(ds.root), "--windows", str(a.windows),
                              "--workers", str(a.workers)], capture_output=True, text=True, check=True)
        results[size] = json.loads(out.stdout.strip().splitlines()[-1])
    for size, r in results.items():
        print(f"{size:8s} frames {r['frames']:7d}  train windows {r['train_windows']:7d}  stats {r['stats_s']:.1f} s  "
              f"{r['windows_per_s']:.0f} windows/s  peak RSS {r['peak_rss_mb']:.0f} MB (after imports {r['baseline_rss_mb']:.0f} MB)")
    ratio = results["double"]["peak_rss_mb"] / results["default"]["peak_rss_mb"]
    print(f"peak RSS double / default = {ratio:.2f} (dataset ratio "
          f"{results['double']['frames'] / results['default']['frames']:.2f}); target: ~1, memory flat in dataset size")


if __name__ == "__main__":
    main()
