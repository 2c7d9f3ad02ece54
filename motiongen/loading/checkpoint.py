"""Atomic checkpoints: write to a temp file, fsync, rename; keep the last K and the best.

A kill at any instant leaves `checkpoints/last.pt` pointing at the newest *complete* file; the
temp file a SIGKILL leaves (`.NAME.tmp<pid>`) is removed by the next run there
(`remove_orphan_temps`), an error or Ctrl-C removes its own at once.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import torch

from motiongen.errors import MotiongenError
from motiongen.output_lock import _pid_alive

STEP_RE = re.compile(r"step_(\d+)\.pt$")
TMP_RE = re.compile(r"\..+\.tmp(\d+)$")          # what _atomic_torch_save / _atomic_link write first


def _temp_name(path: Path) -> Path:
    return path.with_name(f".{path.name}.tmp{os.getpid()}")


def _atomic_torch_save(obj, path: Path) -> None:
    tmp = _temp_name(path)
    try:
        with open(tmp, "wb") as f:
            torch.save(obj, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:                    # an error or Ctrl-C mid-write: no half file left
        tmp.unlink(missing_ok=True)
        if isinstance(e.__context__, KeyboardInterrupt) and not isinstance(e, KeyboardInterrupt):
            # Ctrl-C inside torch.save: its zip writer then fails to close the half file
            # ("unexpected pos ..."), and that error would hide the interrupt from the CLI.
            raise e.__context__ from None
        raise


def save_atomic(obj, path: Path) -> Path:
    """`obj` saved with torch.save at `path` through a temp file and a rename: a kill at any
    instant leaves the previous file or the new one, never half of one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _atomic_torch_save(obj, path)
    return path


def _atomic_link(src: Path, dst: Path) -> None:
    """Make dst a hard link to src (a copy where links are unsupported), atomically."""
    tmp = _temp_name(dst)
    if tmp.exists():
        tmp.unlink()
    try:
        try:
            os.link(src, tmp)
        except OSError:
            shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def remove_orphan_temps(ckpt_dir: Path) -> list[Path]:
    """Remove the temp files in `ckpt_dir` whose writer is dead (a run killed mid-checkpoint
    leaves `.step_*.pt.tmp<pid>` for good otherwise); a live process's are left alone. Returns
    the files removed."""
    removed = []
    for p in Path(ckpt_dir).glob(".*.tmp*"):
        m = TMP_RE.fullmatch(p.name)
        if m and int(m.group(1)) > 0 and not _pid_alive(int(m.group(1))):
            p.unlink(missing_ok=True)
            removed.append(p)
    return removed


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


def student_info(path: str | Path) -> dict:
    """The `distill` entry of a distilled student's checkpoint (motiongen.training.distill:
    method, steps, timesteps, the teacher's path, step, guidance and step count); a model
    trained by `motiongen train` is a user error."""
    state = load_checkpoint(path)
    info = state.get("distill")
    if not isinstance(info, dict):
        raise MotiongenError(f"{path}: not a distilled student (no 'distill' entry; `motiongen distill` makes one)")
    return info
