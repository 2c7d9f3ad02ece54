"""Outputs written under temp names and renamed into place together, so a failed run leaves
nothing half-written in the output directory."""

from __future__ import annotations

import os
from pathlib import Path


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
