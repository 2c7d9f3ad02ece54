"""Where motiongen keeps generated data and caches (never a hard-coded path)."""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir() -> Path:
    """``$MOTIONGEN_CACHE``, else ``$XDG_CACHE_HOME/motiongen``, else ``~/.cache/motiongen``."""
    env = os.environ.get("MOTIONGEN_CACHE")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg).expanduser() if xdg else Path.home() / ".cache") / "motiongen"
