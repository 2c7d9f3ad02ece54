"""Outputs written under temp names and renamed into place together, so a failed run leaves
nothing half-written in the output directory; whole directories swapped in the same way."""

from __future__ import annotations

import os
import shutil
from pathlib import Path


def replace_dir(tmp: Path, final: Path) -> Path:
    """Move the finished directory `tmp` to `final`, replacing what is there: the old one is
    moved aside first and put back if the swap fails, so `final` is never left missing."""
    tmp, final = Path(tmp), Path(final)
    if final.exists():
        old = final.with_name(final.name + f".old-{os.getpid()}")
        os.replace(final, old)
        try:
            os.replace(tmp, final)
        except BaseException:
            os.replace(old, final)
            raise
        shutil.rmtree(old)
    else:
        os.replace(tmp, final)
    return final


class StagedOutputs:
    """`tmp(name)` gives a temp path in `out` for the final file `out/name`; `commit()` renames
    every staged file into place; `abort()` removes them."""

    def __init__(self, out: str | Path):
        self.out = Path(out)
        self.files: dict[Path, Path] = {}          # final path -> temp path

    def tmp(self, name: str) -> Path:
        final = self.out / name
        final.parent.mkdir(parents=True, exist_ok=True)
        t = final.with_name(f".tmp-{os.getpid()}-{final.name}")
        self.files[final] = t
        return t

    def add(self, written: Path, name: str) -> Path:
        """Stage a temp file a writer produced itself (e.g. under a changed suffix) as `out/name`."""
        final = self.out / name
        self.files = {f: t for f, t in self.files.items() if t != Path(written)}
        self.files[final] = Path(written)
        return final

    def commit(self) -> list[Path]:
        done = []
        for final, t in self.files.items():
            os.replace(t, final)
            done.append(final)
        self.files = {}
        return done

    def abort(self) -> None:
        for t in self.files.values():
            t.unlink(missing_ok=True)
        self.files = {}
        for p in self.out.glob(f".tmp-{os.getpid()}-*"):
            p.unlink(missing_ok=True)
