import os

import pytest
import torch

from motiongen.body.model import BodyModel
from motiongen.body.procedural import ensure_procedural_model
from tests.run_inprocess import process_state_kept

# Tests run on 2 shared cores; more threads only adds contention. Under pytest-xdist (scripts/test.sh
# runs two workers) each worker takes one.
torch.set_num_threads(1 if os.environ.get("PYTEST_XDIST_WORKER") else min(2, os.cpu_count() or 1))


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


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    """The procedural SMPL-X file (motiongen/body/procedural.py) in a fresh folder, once per module."""
    return ensure_procedural_model(tmp_path_factory.mktemp("body") / "SMPLX_NEUTRAL.npz")


@pytest.fixture(scope="module")
def bm(model_path):
    """The body model of `model_path`, once per module (a test may not change it)."""
    return BodyModel(model_path)
