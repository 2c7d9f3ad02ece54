"""What keeps a run from destroying data: an output never placed over an input the run reads
(`refuse_output_over_input`), and an output directory used by one live run at a time
(`OutputLock`: the file `.motiongen.lock` in it, holding the owner's pid; a lock whose process
has died is stale and taken over). `claim_run_dir` gives a default run directory of its own to
each of several runs started in the same second."""

from __future__ import annotations

import json
import os
import socket
import sys
import time
from pathlib import Path

from motiongen.errors import ConfigError
from motiongen.staging import MANIFEST

LOCK_NAME = ".motiongen.lock"


def _overlap(a: Path, b: Path) -> bool:
    """`a` and `b` are the same path or one lies inside the other."""
    return a == b or a in b.parents or b in a.parents


def refuse_output_over_input(out, inputs, what: str = "out") -> None:
    """ConfigError when the output `out` is, contains or lies inside any of `inputs` (paths
    resolved, symlinks followed; None entries skipped): writing or replacing it could destroy
    what the run reads, whatever overwrite= says."""
    o = Path(out).expanduser().resolve()
    for inp in inputs:
        if inp is None or str(inp) == "":
            continue
        i = Path(inp).expanduser().resolve()
        if _overlap(o, i):
            where = "is" if o == i else ("lies inside" if i in o.parents else "contains")
            raise ConfigError(f"{what}={out}: the output {where} the input {inp}, which this run reads; "
                              f"choose another {what}= (overwrite= never replaces an input)")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:          # someone else's live process
        return True
    except (OverflowError, ValueError):
        return False
    return True


def _read_lock(path: Path) -> dict | None:
    """A lock file's {pid, host, command, started}; None when missing or unreadable (a lock
    half-written by a run that died)."""
    try:
        info = json.loads(path.read_text())
        return {"pid": int(info["pid"]), "host": str(info["host"]), "command": str(info.get("command")),
                "started": str(info.get("started"))}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def _owner_alive(info: dict) -> bool:
    # Another machine's process cannot be checked: count it as live.
    return info["host"] != socket.gethostname() or _pid_alive(info["pid"])


class OutputLock:
    """`with OutputLock(dir, "sample"):` holds `dir/.motiongen.lock` (created atomically, JSON
    {pid, host, command, started}) for the run; another live run's lock is a ConfigError naming
    that run, a dead one's lock (or an unreadable one) is stale and taken over. The lock is
    removed on exit, also on errors and Ctrl-C, and with it `dir` when the lock created it and
    nothing was written there."""

    def __init__(self, directory, command: str):
        self.dir = Path(directory)
        self.path = self.dir / LOCK_NAME
        self.command = command
        self.created_dir = False
        self.held = False

    def holder(self) -> dict | None:
        """The live run holding the lock, or None when there is none (or only a stale one)."""
        info = _read_lock(self.path)
        return info if info is not None and _owner_alive(info) else None

    def try_acquire(self) -> bool:
        """Take the lock; False when another live run holds it."""
        if self.held:
            return True
        if self.dir.exists() and not self.dir.is_dir():
            raise ConfigError(f"{self.dir}: exists and is not a directory; choose another output directory")
        if not self.dir.exists():
            try:
                self.dir.mkdir(parents=True)
            except FileExistsError:
                pass                                      # made by a run beside this one
            except OSError as e:
                raise ConfigError(f"{self.dir}: cannot create the output directory ({e.strerror})") from None
            else:
                self.created_dir = True
        info = {"pid": os.getpid(), "host": socket.gethostname(), "command": self.command,
                "started": time.strftime("%Y-%m-%d %H:%M:%S")}
        for _ in range(3):                                # a stale lock is removed, then raced for
            if self._create(info):
                self.held = True
                return True
            if self.holder() is not None:
                return False
            self._take_over_stale()
        return False

    def _create(self, info: dict) -> bool:
        """Create the lock file with its content in one step (written under a temp name, then
        hard-linked: no other run ever reads it empty); False when it exists."""
        tmp = self.path.with_name(f"{LOCK_NAME}.new-{os.getpid()}")
        try:
            tmp.write_text(json.dumps(info))
            try:
                os.link(tmp, self.path)
            except FileExistsError:
                return False
            except OSError:                               # no hard links here: exclusive create instead
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
                with os.fdopen(fd, "w") as f:
                    json.dump(info, f)
            return True
        except FileExistsError:
            return False
        except OSError as e:
            raise ConfigError(f"{self.dir}: cannot write here ({e.strerror})") from None
        finally:
            tmp.unlink(missing_ok=True)

    def _take_over_stale(self) -> None:
        """Remove a stale lock: moved aside first, so that a fresh lock another run made in the
        meantime is put back rather than deleted."""
        aside = self.path.with_name(f"{LOCK_NAME}.stale-{os.getpid()}")
        try:
            os.replace(self.path, aside)
        except FileNotFoundError:
            return                                        # another run cleared it first
        old = _read_lock(aside)
        if old is not None and _owner_alive(old):
            try:
                os.link(aside, self.path)
            except FileExistsError:
                pass
            aside.unlink(missing_ok=True)
            return
        who = "an unreadable lock" if old is None else f"{old['command']} (pid {old['pid']}, started {old['started']})"
        print(f"{self.dir}: taking over the stale lock of {who}, which is no longer running",
              file=sys.stderr, flush=True)
        aside.unlink(missing_ok=True)

    def busy_error(self) -> ConfigError:
        h = self.holder() or {}
        host = "" if h.get("host") == socket.gethostname() else f" on {h.get('host')}"
        return ConfigError(f"{self.dir}: in use by {h.get('command', 'another run')} (pid {h.get('pid')}{host}, "
                           f"started {h.get('started')}); wait for it or choose another out= "
                           f"(delete {self.path} only if that run is gone)")

    def release(self) -> None:
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False
            if self.created_dir:
                try:
                    self.dir.rmdir()                      # only when empty: a refused run leaves nothing
                except OSError:
                    pass

    def __enter__(self) -> "OutputLock":
        if not self.try_acquire():
            raise self.busy_error()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def claim_run_dir(default, command: str) -> OutputLock:
    """The lock (entered) of the default run directory `default`, or of `default-2`, `-3`, ...
    when another run started in the same second holds it or has already written its outputs
    there: runs that name no directory never share one."""
    base = Path(default)
    for n in range(1, 1000):
        lock = OutputLock(base if n == 1 else base.with_name(f"{base.name}-{n}"), command)
        if not lock.try_acquire():
            continue
        if (lock.dir / MANIFEST).exists():                # a finished run's outputs: not ours to replace
            lock.release()
            continue
        return lock
    raise ConfigError(f"{base}: no free run directory beside it (-2 to -999 are taken); give out=")
