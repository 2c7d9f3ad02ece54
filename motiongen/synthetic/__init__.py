"""The embedded synthetic human-scene-interaction dataset: procedural furnished rooms and
scripted motions (walk, stand, sit, lie down, pick up, carry) written in the motiongen format,
deterministic by seed, so training and evaluation run with no downloads.

    generate(root, size="default", seed=0)   # or: motiongen synthetic out=DIR
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from motiongen.data.format import DEFAULT_SPLITS
from motiongen.data.dataset_writer import DatasetWriter
from motiongen.synthetic.labels import ACTIONS
from motiongen.synthetic.routes import walkable_room
from motiongen.synthetic.scenes import MAX_OBJECTS, make_scene
from motiongen.synthetic.timeline import make_sequence
from motiongen.checks import require_range
from motiongen.errors import ConfigError
from motiongen.skeleton import BODY

__all__ = ["ACTIONS", "FPS", "GENERATOR_VERSION", "SIZES", "generate"]

GENERATOR_VERSION = 1  # bump when the output changes: cached datasets are keyed by it
FPS = 30.0
# Scene ids and the minimum frames of motion per scene: train scenes get more. Ids follow the
# TRUMANS split convention (train 1-70, val 71-80, test 91-100).
SIZES: dict[str, dict] = {
    "default": {"scenes": list(range(1, 101)), "train_frames": 700, "other_frames": 450, "seconds": (10.0, 36.0)},
    "small": {"scenes": [1, 2, 3, 4, 5, 6, 71, 72, 91, 92], "train_frames": 360, "other_frames": 300,
              "seconds": (8.0, 10.0)},
}


def _scene_job(args: tuple[int, int, int, tuple[float, float]]) -> dict:
    """Build one scene and its sequences (runs in a worker process)."""
    scene_id, seed, quota, seconds = args
    rng = np.random.default_rng([seed, scene_id])  # independent of worker scheduling
    scene = make_scene(scene_id, rng)
    floor = walkable_room(scene.boxes, scene.size)
    seqs, frames = [], 0
    while frames < quota:
        arrays, height = make_sequence(scene, floor, rng, FPS, rng.uniform(*seconds))
        seqs.append((f"scene{scene_id:03d}_seq{len(seqs):02d}", arrays, height))
        frames += len(arrays["joints"])
    items = [(scene_id * 10 + k, f"scene{scene_id:03d}_{it.type}{k}", it.type, it.mesh) for k, it in enumerate(scene.items)]
    return {"id": scene_id, "grid": scene.grid(), "mesh": scene.mesh(), "items": items, "sequences": seqs,
            "furniture": scene.furniture, "size": scene.size}


def generate(root: str | Path, size: str = "default", seed: int = 0, overwrite: bool = False,
             workers: int | None = None, verbose: bool = False) -> Path:
    """Generate the synthetic dataset into `root` and return it.

    size: "default" (100 scenes, >= 30 min of motion) or "small" (10 scenes, ~3 min, for tests).
    workers: processes to build scenes in (default: up to 2 for "default", 1 for "small").
    Raises ConfigError for a bad size/seed, DataError if `root` exists and not `overwrite`."""
    if size not in SIZES:
        raise ConfigError(f"synthetic size must be one of {sorted(SIZES)}, got {size!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"synthetic seed must be a non-negative integer, got {seed!r}")
    require_range("workers", workers, 1, 64, integer=True, allow_none=True)
    spec = SIZES[size]
    train = set(DEFAULT_SPLITS["train"])
    jobs = [(sid, int(seed), spec["train_frames"] if sid in train else spec["other_frames"], spec["seconds"])
            for sid in spec["scenes"]]
    if workers is None:
        workers = min(2, os.cpu_count() or 1) if size == "default" else 1
    t0 = time.perf_counter()
    writer = DatasetWriter(root, BODY, ACTIONS, FPS, num_object_slots=MAX_OBJECTS, overwrite=overwrite)
    heights: dict[str, float] = {}
    try:
        if workers > 1:
            with ProcessPoolExecutor(workers) as pool:
                results = pool.map(_scene_job, jobs, chunksize=2)
                _write(writer, results, heights)
        else:
            _write(writer, map(_scene_job, jobs), heights)
        extra = {"generator": {"name": "motiongen.synthetic", "version": GENERATOR_VERSION, "size": size,
                               "seed": int(seed)}, "body_heights": heights}
        out = writer.finish(splits=DEFAULT_SPLITS, source="synthetic", extra=extra)
    except BaseException:
        writer.abort()
        raise
    if verbose:
        print(f"generated {len(jobs)} scenes in {time.perf_counter() - t0:.1f} s", flush=True)
    return out


def _write(writer: DatasetWriter, results, heights: dict[str, float]) -> None:
    for r in results:  # in scene order whatever the workers did: output is deterministic
        writer.add_scene(r["id"], grid=r["grid"], mesh=r["mesh"], name=f"room{r['id']:03d}")
        for oid, name, kind, mesh in r["items"]:
            writer.add_object(oid, name=name, type=kind, mesh=mesh)
        for name, a, height in r["sequences"]:
            writer.add_sequence(name, r["id"], a["joints"], a["actions"], a["contact"], a["object_poses"], a["object_ids"])
            heights[name] = round(float(height), 4)
