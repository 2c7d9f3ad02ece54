"""Training data of the LEMO motion priors: marker sequences (T, 81, 3) of a motiongen dataset.

    data = "synthetic"   the embedded synthetic dataset (`open_dataset(DataConfig())`, generated
                         into the cache on first use)
    data = PATH          a motiongen dataset directory (`motiongen import-bvh`, `import-amass`, ...)

A split is the dataset's own (`MotionDataset.split_sequences`: the sequences whose scene id is in
meta.json's split lists). A dataset with SMPL-X parameters (`has_smplx`) gives its markers
directly (`markers.params_markers`, β = the sequence's mean); a joints-only one is fitted to the
body model first (`motiongen.body.fit.fit_joints`, about 1 s per 1000 frames). The result is
cached as an .npz per split under `cache_dir()/motion_prior`, keyed by the dataset root, its
meta.json stamp (mtime and size), the body model, the marker placement, the fit's initialiser
and `VERSION`, written atomically.
"""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from motiongen.body.fit import default_mlp, fit_joints
from motiongen.body.model import BodyModel, BodyParams, load_body_model
from motiongen.capture.markers import MARKER_NAMES, MIRROR, marker_vertices, params_markers
from motiongen.data.format import MotionDataset
from motiongen.errors import ConfigError, DataError
from motiongen.forked import forked_map
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.paths import cache_dir

VERSION = 1          # bump when what is cached changes meaning
PARALLEL_FRAMES = 20000   # joints-only splits this long are fitted in 2 processes (2+ cores)


@dataclass
class MarkerSplit:
    """The marker sequences of one split: frames (N, 81, 3) float32 concatenated, `lengths` (S,)
    and `names` (S,) of its sequences."""

    frames: np.ndarray
    lengths: np.ndarray
    names: list[str]
    fps: float

    def sequences(self) -> list[np.ndarray]:
        ends = np.cumsum(self.lengths)
        return [self.frames[e - n:e] for n, e in zip(self.lengths, ends)]

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])


def open_prior_dataset(data: str, verbose: bool = True) -> MotionDataset:
    """`data`: "synthetic" (the embedded synthetic dataset, generated on first use) or the path
    of a motiongen dataset directory."""
    if data in (None, ""):
        raise ConfigError("data: expected synthetic or the path of a motiongen dataset directory, got nothing")
    if data == "synthetic":
        return open_dataset(DataConfig(), verbose=verbose)
    root = Path(str(data)).expanduser()
    if not root.exists():
        raise DataError(root, None, "dataset directory does not exist (data= takes synthetic or a motiongen "
                                    "dataset directory)")
    return MotionDataset.open(root)


def mirror_pairs() -> tuple[list[int], list[int]]:
    """(left, right) marker indices of the markers' mirror pairs (`markers.MIRROR`; the left one's
    name starts with L)."""
    left = [i for i, n in enumerate(MARKER_NAMES) if int(MIRROR[i]) != i and n.startswith("L")]
    return left, [int(MIRROR[i]) for i in left]


def _model_key(bm: BodyModel) -> str:
    h = hashlib.sha1()
    h.update(bm.J_template.detach().cpu().numpy().tobytes())
    h.update(bm.J_dirs.detach().cpu().numpy().tobytes())
    h.update(np.asarray(marker_vertices(bm)).tobytes())
    h.update(",".join(MARKER_NAMES).encode())
    return h.hexdigest()[:16]


def cache_path(ds: MotionDataset, split: str | None, bm: BodyModel, fit_mlp: str = "auto") -> Path:
    """The cache file of a split's markers: keyed by the dataset root, its meta.json stamp, the
    body model and marker placement, the fit's initialiser (joints-only data) and VERSION."""
    meta = Path(ds.root) / "meta.json"
    st = meta.stat()
    init = "" if ds.smplx is not None else str(fit_mlp)
    key = "|".join([str(Path(ds.root).resolve()), f"{st.st_mtime_ns}:{st.st_size}", _model_key(bm), init,
                    repr(sorted((k, sorted(v)) for k, v in ds.splits.items())), str(split), f"v{VERSION}"])
    h = hashlib.sha1(key.encode()).hexdigest()[:20]
    return cache_dir() / "motion_prior" / f"{Path(ds.root).name}_{split or 'all'}_{h}.npz"


def _sequence_markers(ds: MotionDataset, s, bm: BodyModel, fit_mlp) -> np.ndarray:
    sl = slice(s.start, s.end)
    if ds.smplx is not None:
        b = np.asarray(ds.smplx["betas"][sl], np.float32).mean(0)
        nb = bm.num_betas
        betas = np.pad(b[:nb], (0, max(0, nb - len(b[:nb]))))
        params = BodyParams(global_orient=np.array(ds.smplx["global_orient"][sl], np.float32),
                            body_pose=np.array(ds.smplx["body_pose"][sl], np.float32),
                            transl=np.array(ds.smplx["transl"][sl], np.float32), betas=betas)
    else:
        joints = np.asarray(ds.joints[sl][:, :22], np.float32)
        params = fit_joints(joints, bm, mlp=fit_mlp, fps=ds.fps)
    return np.asarray(params_markers(bm, params), np.float32)


def split_markers(ds: MotionDataset, split: str | None, bm: BodyModel, fit_mlp: str | None = "auto",
                  cache: bool = True, verbose: bool = True, progress_every: int = 10,
                  workers: int | None = None) -> MarkerSplit:
    """The markers of the sequences of `split` (None: all), computed once and cached. Joints-only
    data is fitted in `workers` processes (None: 2 on a machine with 2+ cores for splits of
    PARALLEL_FRAMES frames or more, else 1); the result does not depend on it."""
    seqs = ds.split_sequences(split)
    if not seqs:
        raise DataError(Path(ds.root) / "meta.json", "splits", f"no sequences in split {split!r}")
    mlp = None if fit_mlp in (None, "", "none") else fit_mlp
    path = cache_path(ds, split, bm, "none" if mlp is None else str(mlp))
    if cache and path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                out = MarkerSplit(z["frames"], z["lengths"], [str(n) for n in z["names"]], float(z["fps"]))
            if verbose:
                print(f"markers ({split}): {len(out.lengths)} sequences, {out.num_frames} frames from {path}", flush=True)
            return out
        except (OSError, ValueError, KeyError):
            pass                                                 # unreadable: computed again
    total = sum(s.num_frames for s in seqs)
    how = "SMPL-X parameters" if ds.smplx is not None else f"fitted joints (mlp={mlp or 'none'})"
    if verbose:
        print(f"markers ({split}): {len(seqs)} sequences, {total} frames from {how} of {ds.root}", flush=True)
    if workers is None:            # fitting is single-threaded: one process per core pays off on big splits
        workers = min(2, os.cpu_count() or 1) if ds.smplx is None and total >= PARALLEL_FRAMES else 1
    if ds.smplx is None and mlp == "auto":
        mlp = default_mlp(bm)        # trained (once, cached) here, not in each worker
    t0, done, parts = time.time(), 0, []
    # Forked workers inherit the dataset and the body model; only sequence indices cross over.
    markers = forked_map(lambda k: _sequence_markers(ds, seqs[k], bm, mlp), range(len(seqs)), workers)
    for i, (s, m) in enumerate(zip(seqs, markers), 1):
        parts.append(m)
        done += s.num_frames
        if verbose and (i % max(1, progress_every) == 0 or i == len(seqs)):
            print(f"  {split}: {i}/{len(seqs)} sequences, {done}/{total} frames ({time.time() - t0:.0f} s)", flush=True)
    out = MarkerSplit(np.concatenate(parts).astype(np.float32), np.array([len(p) for p in parts], np.int64),
                      [s.name for s in seqs], ds.fps)
    if cache:
        _save_atomic(path, out)
    return out


def _save_atomic(path: Path, m: MarkerSplit) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            np.savez(f, frames=m.frames, lengths=m.lengths, names=np.array(m.names, dtype=str), fps=np.float64(m.fps))
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def prior_data(data: str = "synthetic", splits=("train", "val"), body_model: str | None = None,
               fit_mlp: str | None = "auto", cache: bool = True, verbose: bool = True,
               bm: BodyModel | None = None) -> tuple[dict[str, MarkerSplit], MotionDataset, BodyModel]:
    """{split: MarkerSplit} of the dataset `data` (see `open_prior_dataset`), the dataset and
    the body model (`body_model`: an SMPL-X .npz; None: $MOTIONGEN_SMPLX_MODEL, else the
    procedural one). A split the dataset does not have or that is empty is left out, except
    the first one asked for (then DataError)."""
    ds = open_prior_dataset(data, verbose=verbose)
    bm = bm if bm is not None else load_body_model(body_model)
    out = {}
    for i, split in enumerate(splits):
        if i > 0 and (split not in ds.splits or not ds.split_sequences(split)):
            if verbose:
                print(f"markers: the dataset has no {split!r} sequences", flush=True)
            continue
        out[split] = split_markers(ds, split, bm, fit_mlp, cache=cache, verbose=verbose)
    return out, ds, bm
