"""Work mapped over forked worker processes: the sampler's batch of final solves, the motion
priors' marker data, and (its initialiser and platform rule) the video's frames.

Forked children inherit the function and everything it holds (a body model, a dataset, a
figure), so only the items and the results cross between processes. Each child runs torch on
one thread: the work is many small tensors, and the parent's cores are shared out among them.
"""

from __future__ import annotations

import multiprocessing as mp
import sys
from concurrent.futures import ProcessPoolExecutor
from typing import Callable, Iterable, Iterator

import torch

# Fork only on Linux: macOS offers it, but system frameworks may crash in a forked child.
FORK_OK = sys.platform.startswith("linux")
_JOB: dict = {}


def one_thread() -> None:
    """A worker's initialiser: torch on one thread."""
    torch.set_num_threads(1)


def forked_map(fn: Callable, items: Iterable, workers: int) -> Iterator:
    """fn(item) for each of items, in order: in `workers` forked processes where forking is
    safe (`FORK_OK`) and there are at least two workers and two items; in this process
    otherwise."""
    items = list(items)
    if workers < 2 or len(items) < 2 or not FORK_OK:
        yield from map(fn, items)
        return
    _JOB["fn"] = fn
    try:
        with ProcessPoolExecutor(min(workers, len(items)), mp_context=mp.get_context("fork"),
                                 initializer=one_thread) as pool:
            yield from pool.map(_call, items)
    finally:
        _JOB.clear()


def _call(item):
    return _JOB["fn"](item)
