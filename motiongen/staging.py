"""Outputs written under temp names and renamed into place together, so a failed run leaves
nothing half-written in the output directory; whole directories swapped in the same way. A
command that writes a set of files into a directory records the set in a manifest
(`record_outputs`), so that its next run there replaces the whole set rather than leaving old
files beside new ones."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

MANIFEST = ".motiongen-outputs.json"   # hidden, like the lock: not one of the outputs


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


def _read_manifest(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def record_outputs(out: str | Path, command: str, written, keep=()) -> int:
    """After `command` has put the files `written` into `out`: remove the files its previous
    run there wrote (per the manifest `out/.motiongen-outputs.json`) that this run did not
    write again, and record the new set. Files the manifest does not list (a user's own) and `keep` (this run's inputs) are
    never touched. Prints one line when a previous set was replaced; returns the files removed."""
    out = Path(out)
    manifest = out / MANIFEST
    data = _read_manifest(manifest)
    names = sorted({Path(p).resolve().relative_to(out.resolve()).as_posix() for p in written})
    kept = {Path(k).resolve() for k in keep if k is not None}
    previous = data.get(command, {}).get("files", []) if isinstance(data.get(command), dict) else []
    removed = 0
    for old in sorted(set(previous) - set(names)):
        p = out / old
        if ".." in Path(old).parts or p.resolve() in kept or not p.is_file():
            continue
        p.unlink()
        removed += 1
        for d in p.parents:                               # directories the old set alone filled
            if d == out or not d.is_relative_to(out):
                break
            try:
                d.rmdir()
            except OSError:
                break
    data[command] = {"files": names, "finished": time.strftime("%Y-%m-%d %H:%M:%S")}
    tmp = manifest.with_name(f".tmp-{os.getpid()}-{MANIFEST}")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, manifest)
    if previous:
        print(f"replaced the previous {command} outputs in {out} ({removed} old files not written again "
              f"removed)", flush=True)
    return removed
