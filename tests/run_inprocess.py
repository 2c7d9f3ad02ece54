"""Run a `motiongen` command inside the test process: a bad-input table row costs the command's
own checks, not a Python start-up and the torch import (seconds each)."""

from __future__ import annotations

import logging
import random
import sys
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import torch

from motiongen.commands import main as motiongen


@dataclass
class Result:
    returncode: int
    stdout: str
    stderr: str


@contextmanager
def process_state_kept():
    """Put back what a command may change for the whole process: sys.argv (Hydra apps set it),
    the root logger's handlers and level (Hydra's job logging), torch's thread count and
    deterministic mode and the RNGs (the trainer's set-up)."""
    argv, root = list(sys.argv), logging.getLogger()
    handlers, level = root.handlers[:], root.level
    threads, det = torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()
    warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    rngs = torch.get_rng_state(), np.random.get_state(), random.getstate()
    try:
        yield
    finally:
        sys.argv[:] = argv
        for h in root.handlers:
            if h not in handlers:
                h.close()
        root.handlers[:] = handlers
        root.setLevel(level)
        torch.set_num_threads(threads)
        torch.use_deterministic_algorithms(det, warn_only=warn_only)
        torch.set_rng_state(rngs[0]), np.random.set_state(rngs[1]), random.setstate(rngs[2])


def run_command(name: str, argv: list, capsys) -> Result:
    """`motiongen <name> *argv` in this process: its exit status, stdout and stderr (captured
    by pytest's `capsys`)."""
    capsys.readouterr()
    with process_state_kept():
        try:
            motiongen([name, *(str(a) for a in argv)])
            code = 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    out, err = capsys.readouterr()
    return Result(code, out, err)
