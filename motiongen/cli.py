"""Shared CLI plumbing: user errors become one line on stderr and exit status 2."""

from __future__ import annotations

import functools
import sys
from typing import Callable, TypeVar

from motiongen.errors import MotiongenError

F = TypeVar("F", bound=Callable)


def user_errors_exit_2(fn: F) -> F:
    """Wrap a CLI entry point so a `MotiongenError` prints `error: <message>` and exits 2.

    Hydra catches exceptions raised inside a `@hydra.main` function and prints its own
    traceback, so apply this *inside* (below) `@hydra.main`: the function exits before Hydra
    sees anything.
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except MotiongenError as e:
            print(f"error: {e}", file=sys.stderr, flush=True)
            sys.exit(2)

    return wrapper  # type: ignore[return-value]
