"""Atomic checkpoints: write to a temp file, fsync, rename; keep the last K and the best.

A kill at any instant leaves `checkpoints/last.pt` pointing at the newest *complete* file.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import torch

from motiongen.errors import MotiongenError

STEP_RE = re.compile(r"step_(\d+)\.pt$")


def _atomic_torch_save(obj, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with open(tmp, "wb") as f:
        torch.save(obj, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _atomic_link(src: Path, dst: Path) -> None:
    """Make dst a hard link to src (a copy where links are unsupported), atomically."""
    tmp = dst.with_name(f".{dst.name}.tmp{os.getpid()}")
    if tmp.exists():
        tmp.unlink()
    try:
        os.link(src, tmp)
    except OSError:
        shutil.copyfile(src, tmp)
    os.replace(tmp, dst)


def save_checkpoint(state: dict, ckpt_dir: Path, step: int, keep_last: int, best: bool = False) -> Path:
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    path = ckpt_dir / f"step_{step:08d}.pt"
    _atomic_torch_save(state, path)
    _atomic_link(path, ckpt_dir / "last.pt")
    if best:
        _atomic_link(path, ckpt_dir / "best.pt")
    steps = sorted((int(m.group(1)), p) for p in ckpt_dir.glob("step_*.pt") if (m := STEP_RE.search(p.name)))
    for _, p in steps[:-keep_last] if keep_last > 0 else []:
        p.unlink(missing_ok=True)   # last.pt / best.pt are separate links and survive
    return path


def load_checkpoint(path: str | Path, map_location="cpu") -> dict:
    """Load a motiongen checkpoint; a missing, truncated or foreign file is a user error."""
    path = Path(path)
    if not path.is_file():
        raise MotiongenError(f"{path}: checkpoint file not found")
    try:
        state = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as e:  # torch raises many types for corrupt zips/pickles
        raise MotiongenError(f"{path}: not a readable checkpoint ({type(e).__name__}: {e})") from None
    if not isinstance(state, dict) or state.get("format") != "motiongen-checkpoint":
        raise MotiongenError(f"{path}: not a motiongen checkpoint (no 'format: motiongen-checkpoint' entry)")
    return state


def find_resume(run_dir: Path) -> Path | None:
    last = run_dir / "checkpoints" / "last.pt"
    return last if last.is_file() else None
