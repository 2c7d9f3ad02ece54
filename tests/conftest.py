import os

import pytest
import torch

# Tests run on 2 shared cores; more threads only adds contention.
torch.set_num_threads(min(2, os.cpu_count() or 1))


@pytest.fixture(autouse=True)
def _isolated_cache(tmp_path_factory, monkeypatch):
    """Keep generated data/grids out of the user's cache, shared within the session."""
    monkeypatch.setenv("MOTIONGEN_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))
