import os

import pytest
import torch

from tests.run_inprocess import process_state_kept

# Tests run on 2 shared cores; more threads only adds contention.
torch.set_num_threads(min(2, os.cpu_count() or 1))


@pytest.fixture(autouse=True)
def _isolated_cache(tmp_path_factory, monkeypatch):
    """Keep generated data/grids out of the user's cache, shared within the session."""
    monkeypatch.setenv("MOTIONGEN_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


@pytest.fixture
def in_process(monkeypatch, tmp_path):
    """A command run in this process: the working directory is tmp_path (where Hydra would make
    ./outputs or runs/), and what the command changes for the whole process comes back."""
    monkeypatch.chdir(tmp_path)
    with process_state_kept():
        yield
