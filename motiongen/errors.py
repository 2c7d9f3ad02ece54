"""Error classes for user mistakes.

A `MotiongenError` means the user gave us something wrong (a file, a field, a CLI value).
CLIs print its one-line message and exit with status 2; anything else is a bug and keeps
its traceback.
"""

from __future__ import annotations

from pathlib import Path


class MotiongenError(Exception):
    """A user-facing error with a one-line message."""


class DataError(MotiongenError):
    """A dataset file is missing, corrupt, or has the wrong shape, dtype or values."""

    def __init__(self, path: str | Path, field: str | None, problem: str):
        self.path = str(path)
        self.field = field
        self.problem = problem
        where = f"{self.path}" + (f" [{field}]" if field else "")
        super().__init__(f"{where}: {problem}")


class ConfigError(MotiongenError):
    """A configuration or command-line value is invalid."""
