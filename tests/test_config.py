"""Hydra composition of every experiment, model and data option, from the dataclass defaults."""

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from motiongen.config import register_configs
from motiongen.models import PRESETS
from motiongen.loading.build import data_config, mask_config, window_config

CONFIGS = str(Path(__file__).resolve().parents[1] / "motiongen" / "configs")
register_configs()


def _compose(name="train", overrides=()):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(name, overrides=list(overrides))


def test_no_arguments_is_the_demo():
    assert _compose() == _compose(overrides=["experiment=demo"])
    c = _compose()
    assert c.model.name == "tiny" and c.data.source == "synthetic" and c.train.max_steps == 2000


def test_paper_experiment_matches_the_supplement():
    c = _compose(overrides=["experiment=paper"])
    assert (c.model.width, c.model.layers, c.model.heads, c.model.ff, c.model.dropout) == (512, 6, 16, 1024, 0.1)
    assert (c.train.lr, c.train.batch_size) == (1e-4, 512)
    assert (c.diffusion.schedule, c.diffusion.beta_start, c.diffusion.beta_end, c.diffusion.steps) == ("linear", 1e-4, 0.02, 100)
    assert (c.diffusion.prediction, c.diffusion.loss) == ("eps", "huber")


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_model_presets_compose_from_the_registry(preset):
    c = _compose(overrides=[f"model={preset}"])
    assert c.model.width == PRESETS[preset].width and c.model.layers == PRESETS[preset].layers


@pytest.mark.parametrize("data", ["synthetic", "small", "trumans", "dataset"])
def test_data_options(data):
    d = data_config(_compose(overrides=[f"data={data}"]))
    assert d.source in ("synthetic", "trumans", "dataset")
    paper = _compose(overrides=["experiment=paper"])        # the public code's 10 fps windows
    assert (window_config(paper).length, window_config(paper).stride, mask_config(paper).max_transition) == (16, 3, 2)
    demo = _compose()                                         # the demo's 15 fps windows, same 1.5 s
    assert (window_config(demo).length, window_config(demo).stride, mask_config(demo).max_transition) == (24, 2, 3)


def test_unknown_key_is_rejected():
    with pytest.raises(Exception, match="nope"):
        _compose(overrides=["train.nope=1"])


def test_sample_and_evaluate_configs_compose():
    assert _compose("sample", ["ckpt=x.pt"]).sampler == "ddim"
    assert _compose("evaluate", ["ckpt=x.pt"]).k == 5
