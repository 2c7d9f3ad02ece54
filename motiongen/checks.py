"""Range checks for configuration keys, shared by every command: a value out of its range is one
`ConfigError` naming the key ("key: expected ..., got ..."), raised where the config is read,
before any work. Each config validates its keys in one place (its `__post_init__`) with these."""

from __future__ import annotations

import math
import numbers
import tempfile
from pathlib import Path

from motiongen.errors import ConfigError

# Frames per second any importer or fitter may write: above this a typo (fps=1e9) asks for
# billions of frames (docs: every motion in the project runs at 10-120 fps).
MAX_FPS = 1000.0


def _describe(lo, hi, lo_open: bool, hi_open: bool, integer: bool) -> str:
    kind = "an integer" if integer else "a number"
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"{'<' if hi_open else '<='} {hi:g}")
    return kind + (" " + " and ".join(parts) if parts else "")


def require_range(key: str, value, lo: float | None = None, hi: float | None = None, *, integer: bool = False,
                  lo_open: bool = False, hi_open: bool = False, allow_none: bool = False):
    """`value` itself when it is a finite number (an integer with `integer`) in [lo, hi] (an open
    end with `lo_open` / `hi_open`); otherwise ConfigError "key: expected ..., got ...". None is
    refused unless `allow_none`."""
    if value is None and allow_none:
        return value
    want = _describe(lo, hi, lo_open, hi_open, integer)
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if ok and integer:
        ok = isinstance(value, numbers.Integral) or (math.isfinite(value) and float(value).is_integer())
    ok = ok and math.isfinite(value)
    if ok and lo is not None:
        ok = value > lo if lo_open else value >= lo
    if ok and hi is not None:
        ok = value < hi if hi_open else value <= hi
    if not ok:
        raise ConfigError(f"{key}: expected {want}, got {value!r}")
    return value


def require_choice(key: str, value, choices) -> object:
    """`value` when it is one of `choices`; otherwise ConfigError listing them."""
    if value not in tuple(choices):
        raise ConfigError(f"{key}: expected one of {', '.join(str(c) for c in choices)}, got {value!r}")
    return value


def require_fps(key: str, value, allow_none: bool = False):
    """A frame rate: a finite number > 0 and <= MAX_FPS."""
    return require_range(key, value, 0, MAX_FPS, lo_open=True, allow_none=allow_none)


def require_output_path(key: str, path, *, directory: bool) -> Path:
    """`path` as a Path when a command can write its output there (a directory with `directory`,
    else a file); otherwise ConfigError "key: ..." before any work: a file where a directory is
    expected or the reverse, a parent that is a file, or a place where nothing can be created
    (a read-only or virtual file system such as /proc). Nothing is left behind by the check."""
    p = Path(path).expanduser()
    want = "a directory" if directory else "a file"
    if p.exists() and p.is_dir() != directory:
        raise ConfigError(f"{key}: {p} exists and is not {want}")
    base = next(q for q in (p.parent, *p.parent.parents) if q.exists())
    if not base.is_dir():
        raise ConfigError(f"{key}: {base} is a file, not a directory, so {p} cannot be created")
    try:
        with tempfile.TemporaryFile(dir=base):          # made and removed at once: can we write here?
            pass
    except OSError as e:
        raise ConfigError(f"{key}: cannot write under {base} ({e.strerror})") from None
    return p
