"""Resolve the `data=` config group to an opened MotionDataset (generating/converting on demand)."""

from __future__ import annotations

import fcntl
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from motiongen.data.format import MotionDataset
from motiongen.data.mix import open_mixed
from motiongen.errors import ConfigError
from motiongen.importers.trumans import convert_trumans
from motiongen.paths import cache_dir
from motiongen.synthetic import GENERATOR_VERSION, generate


@dataclass
class DataConfig:
    source: str = "synthetic"        # synthetic | trumans | dataset (our format at `root`)
    root: str | None = None          # dataset dir; None = cache dir for synthetic/trumans
    release: str | None = None       # TRUMANS Data_release/ dir (source=trumans)
    size: str = "default"            # synthetic size: default | small
    seed: int = 0                    # synthetic generator seed
    splits: dict | None = None       # override {train: [...], val: [...], test: [...]} scene ids
    augmented: Any = None            # dataset dir or list of dirs of augmented sequences (motiongen.annotation.augment)
                                     # whose train-scene sequences are mixed into the training data


def dataset_root(cfg: DataConfig) -> Path:
    if cfg.root:
        return Path(cfg.root).expanduser()
    if cfg.source == "synthetic":
        return cache_dir() / "datasets" / f"synthetic-{cfg.size}-seed{cfg.seed}-v{GENERATOR_VERSION}"
    if cfg.source == "trumans":
        if not cfg.release:
            raise ConfigError("data.source=trumans needs data.release=PATH to the Data_release/ folder")
        return cache_dir() / "datasets" / f"trumans-{Path(cfg.release).resolve().name}"
    raise ConfigError(f"data.source={cfg.source!r} needs data.root=PATH (or use synthetic|trumans)")


def open_dataset(cfg: DataConfig, verbose: bool = True) -> MotionDataset:
    """Open the configured dataset, generating the synthetic one or converting a TRUMANS release
    into the cache the first time. A file lock keeps concurrent processes (DDP ranks) from
    building it twice."""
    if cfg.source not in ("synthetic", "trumans", "dataset"):
        raise ConfigError(f"data.source must be synthetic, trumans or dataset, got {cfg.source!r}")
    root = dataset_root(cfg)
    if not (root / "meta.json").is_file() and cfg.source in ("synthetic", "trumans"):
        root.parent.mkdir(parents=True, exist_ok=True)
        with open(root.parent / f".{root.name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not (root / "meta.json").is_file():
                if cfg.source == "synthetic":
                    if verbose:
                        print(f"generating synthetic dataset ({cfg.size}, seed {cfg.seed}) -> {root}", flush=True)
                    generate(root, size=cfg.size, seed=cfg.seed, overwrite=root.exists())
                else:
                    if verbose:
                        print(f"converting TRUMANS release {cfg.release} -> {root}", flush=True)
                    convert_trumans(cfg.release, root, overwrite=root.exists())
    splits = dict(cfg.splits) if cfg.splits else None
    ds = MotionDataset.open(root, splits=splits)
    if cfg.augmented:
        paths = [cfg.augmented] if isinstance(cfg.augmented, str) else list(cfg.augmented)
        ds = open_mixed(ds, paths, splits, cache_dir() / "datasets", verbose)
    return ds
