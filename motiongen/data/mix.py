"""Training on a dataset together with augmented sequences made from it (`data.augmented`).

`motiongen.annotation.augment` writes the augmented sequences as a dataset of their own (same scenes,
edited objects as new objects). `mixed_dataset` writes the source dataset plus the augmented
sequences of its *train* scenes into one dataset (cached: built once per combination), so every
reader (windows, statistics, validation, evaluation) sees one ordinary dataset. Augmented
sequences of scenes outside the train split are left out, so validation and test data stay the
source's own. Per-vertex contact labels are not carried over (training does not read them).
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

from motiongen.data.format import SMPLX_FIELDS, MotionDataset
from motiongen.data.dataset_writer import DatasetWriter
from motiongen.errors import ConfigError

_STANDARD = {"format", "version", "source", "fps", "units", "up", "num_frames", "joint_set", "joint_names",
             "actions", "num_object_slots", "has_smplx", "splits"}


def _fingerprint(root: Path) -> dict:
    meta = root / "meta.json"
    st = meta.stat()
    return {"root": str(root.resolve()), "meta_mtime_ns": st.st_mtime_ns, "meta_size": st.st_size}


def mixed_root(base: Path, augmented: list[Path], splits: dict | None, cache: Path) -> Path:
    """Cache folder of one combination: keyed by the datasets (path and meta.json stamp) and the
    split override, so a regenerated input makes a new mix."""
    key = json.dumps({"base": _fingerprint(base), "augmented": [_fingerprint(a) for a in augmented],
                      "splits": splits}, sort_keys=True)
    return cache / f"mixed-{base.name}-{hashlib.sha1(key.encode()).hexdigest()[:12]}"


def _check_compatible(base: MotionDataset, aug: MotionDataset) -> None:
    for what, a, b in (("joint set", base.meta["joint_names"], aug.meta["joint_names"]),
                       ("actions", base.meta["actions"], aug.meta["actions"]), ("fps", base.fps, aug.fps),
                       ("object slots", base.meta["num_object_slots"], aug.meta["num_object_slots"])):
        if a != b:
            raise ConfigError(f"data.augmented: {aug.root} has another {what} than {base.root} ({b!r} vs {a!r})")
    for sid, entry in aug.scenes.items():
        mine = base.scenes.get(sid)
        if mine is None or mine.get("name") != entry.get("name"):
            raise ConfigError(f"data.augmented: scene {sid} of {aug.root} is not scene {sid} of {base.root}: "
                              f"was it augmented from this dataset?")


def write_mixed(base: MotionDataset, augmented: list[MotionDataset], out: Path, splits: dict | None = None,
                verbose: bool = True) -> Path:
    """Write `base` plus the train-scene sequences of `augmented` into a new dataset at `out`."""
    splits = splits or base.splits
    train = set(splits.get("train", []))
    for aug in augmented:
        _check_compatible(base, aug)
    smplx = base.smplx is not None and all(a.smplx is not None for a in augmented)
    w = DatasetWriter(out, base.joint_set, base.action_names, base.fps, base.meta["num_object_slots"],
                      has_smplx=smplx, overwrite=out.exists())
    try:
        names = set()
        for sid, entry in base.scenes.items():
            w.add_scene(sid, grid=base.grid(sid) if entry.get("grid") else None, mesh=base.scene_mesh(sid),
                        name=entry.get("name"))
        next_id = max(base.objects, default=-1) + 1
        for oid, entry in base.objects.items():
            w.add_object(oid, entry["name"], entry.get("type", ""), mesh=base.object_mesh(oid))
        object_names = {e["name"] for e in base.objects.values()}
        for seq in base.sequences:
            _copy(w, base, seq, seq.name, None, smplx)
            names.add(seq.name)
        added, dropped = [], 0
        for aug in augmented:
            remap = {}
            for oid, entry in aug.objects.items():
                same = base.objects.get(oid)
                if same is not None and same["name"] == entry["name"]:
                    remap[oid] = oid                       # the source's own object
                    continue
                name = entry["name"]
                while name in object_names:
                    name += "+"
                object_names.add(name)
                remap[oid] = next_id
                w.add_object(next_id, name, entry.get("type", ""), mesh=aug.object_mesh(oid))
                next_id += 1
            for seq in aug.sequences:
                if seq.scene not in train:
                    dropped += 1
                    continue
                name = seq.name
                while name in names:
                    name += "+"
                names.add(name)
                _copy(w, aug, seq, name, remap, smplx)
                added.append(name)
        extra = {k: v for k, v in base.meta.items() if k not in _STANDARD}
        extra["mixed"] = {"base": str(base.root.resolve()), "augmented": [str(a.root.resolve()) for a in augmented],
                          "added_sequences": len(added), "dropped_outside_train": dropped}
        path = w.finish(splits=splits, source=base.meta.get("source", "unknown"), extra=extra)
    except BaseException:
        w.abort()
        raise
    if verbose:
        print(f"data.augmented: {len(added)} augmented sequences added to the train split "
              f"({dropped} of scenes outside it left out) -> {path}", file=sys.stderr, flush=True)
    return path


def _copy(w: DatasetWriter, ds: MotionDataset, seq, name: str, remap: dict | None, smplx: bool) -> None:
    s, e = seq.start, seq.end
    ids = poses = None
    if ds.object_ids is not None:
        ids = np.asarray(ds.object_ids[s:e])
        if remap:
            keys = np.array(sorted(remap), np.int64)
            vals = np.array([remap[k] for k in keys], np.int32)
            pos = np.clip(np.searchsorted(keys, ids), 0, len(keys) - 1)
            ids = np.where((ids >= 0) & (keys[pos] == ids), vals[pos], ids).astype(np.int32)
        poses = np.asarray(ds.object_poses[s:e])
    params = {k: np.asarray(ds.smplx[k][s:e]) for k in SMPLX_FIELDS} if smplx else None
    w.add_sequence(name, seq.scene, np.asarray(ds.joints[s:e]), np.asarray(ds.actions[s:e]),
                   np.asarray(ds.contact[s:e]), poses, ids, params)


def open_mixed(base: MotionDataset, augmented: list, splits: dict | None, cache: Path,
               verbose: bool = True) -> MotionDataset:
    """The mix of `base` and the datasets at `augmented` (paths), built into `cache` on first use."""
    paths = [Path(a).expanduser() for a in augmented]
    augs = [MotionDataset.open(p) for p in paths]
    root = mixed_root(base.root, paths, splits, cache)
    if not (root / "meta.json").is_file():
        root.parent.mkdir(parents=True, exist_ok=True)
        with open(root.parent / f".{root.name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not (root / "meta.json").is_file():
                write_mixed(base, augs, root, splits, verbose)
    return MotionDataset.open(root, splits=splits)
