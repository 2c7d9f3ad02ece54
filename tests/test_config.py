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


def test_app_keys_come_from_the_dataclasses():
    """sample and evaluate are built from the dataclasses the code uses (each default written
    once): their values are typed, and `to_object` gives the dataclasses back."""
    from dataclasses import asdict

    from omegaconf import OmegaConf

    from motiongen.eval.evaluate_config import EvaluateConfig, protocol_config
    from motiongen.eval.pairs import ProtocolConfig
    from motiongen.sampling.settings import LoopConfig, SamplerSettings

    sample = OmegaConf.to_object(_compose("sample", ["ckpt=x.pt", "loop.smooth=1", "steps=8"]))
    lists = lambda d: {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(d).items()}   # noqa: E731
    assert lists(sample.loop) == lists(LoopConfig(smooth=1.0)) and isinstance(sample.loop.smooth, float)
    assert SamplerSettings.of(sample) == SamplerSettings(steps=8)
    ev = OmegaConf.to_object(_compose("evaluate", ["ckpt=x.pt", "data=small", "loop.smooth=0"]))
    assert isinstance(ev, EvaluateConfig) and ev.data.size == "small" and ev.steps is None   # EVALUATE_STEPS, or a student's
    pc = protocol_config(ev)
    assert asdict(pc) == {**asdict(ProtocolConfig()), "static_actions": ["sit", "lie down"], "loop": {"smooth": 0.0},
                          "ablate": list(ProtocolConfig().ablate)}


def test_window_group_is_the_window_config():
    from omegaconf import OmegaConf

    from motiongen.data.windows import WindowConfig

    reference = window_config(_compose(overrides=["window=reference"]))
    assert reference == WindowConfig(contact_joints=(), length=24, stride=2)      # the demo's length and stride
    stored = OmegaConf.create({"window": {"grid_res": [16, 16, 16]}})              # as a checkpoint holds it
    assert window_config(stored).grid_res == (16, 16, 16)


def test_bad_values_are_config_errors_naming_the_key():
    from omegaconf import OmegaConf

    from motiongen.errors import ConfigError
    from motiongen.eval.evaluate_config import loop_overrides

    assert loop_overrides({"project": "false", "smooth": 2}) == {"project": False, "smooth": 2.0}
    assert loop_overrides({"hand_goal_on_arrival": "false"}) == {"hand_goal_on_arrival": False}
    assert loop_overrides({"reach_fraction": 1}) == {"reach_fraction": 1.0}
    for values, message in (({"smooth": -1}, "loop.smooth: expected a number >= 0, got -1"),
                            ({"reach_fraction": 0}, r"loop.reach_fraction: expected a number > 0 and <= 10, got 0.0"),
                            ({"reach_fraction": 12}, r"loop.reach_fraction: expected a number > 0 and <= 10, got 12.0"),
                            ({"foot_lock": "maybe"}, "loop.foot_lock: expected true or false, got 'maybe'"),
                            ({"foot_height": "floor"}, "loop.foot_height: expected one of network, body, free, got 'floor'"),
                            ({"warmup": 3}, "loop.warmup: not a key here")):
        with pytest.raises(ConfigError, match=message):
            loop_overrides(values)
    with pytest.raises(ConfigError, match="steps must be >= 1, got 0"):      # checked once, in SamplerSettings
        OmegaConf.to_object(_compose("sample", ["steps=0"]))


# Every app's keys, refused where the config is built (before any model, scene or data is read):
# (app, overrides, the start of the one-line message). The train group is built as set_up does.
OUT_OF_RANGE = [
    ("train", ["train.ema_decay=1.5"], "train.ema_decay: expected a number >= 0 and < 1, got 1.5"),
    ("train", ["train.ema_decay=1"], "train.ema_decay: expected a number >= 0 and < 1"),
    ("train", ["train.hand_goal_weight=-1"], "train.hand_goal_weight: expected a number >= 0, got -1.0"),
    ("train", ["train.lr_schedule=cosin"], "train.lr_schedule: expected one of constant, cosine, got 'cosin'"),
    ("train", ["train.geometry_weighting=high"], "train.geometry_weighting: expected one of uniform, signal, got 'high'"),
    ("train", ["train.batch_size=0"], "train.batch_size: expected an integer >= 1, got 0"),
    ("train", ["train.log_every=0"], "train.log_every: expected an integer >= 1"),
    ("train", ["train.lr=-1"], "train.lr: expected a number > 0, got -1.0"),
    ("train", ["train.lr=nan"], "train.lr: expected a number > 0"),
    ("train", ["train.lr=inf"], "train.lr: expected a number > 0"),
    ("train", ["train.num_workers=-1"], "train.num_workers: expected an integer >= 0"),
    ("train", ["train.cond_drop_scene=2"], "train.cond_drop_scene: expected a number >= 0 and <= 1"),
    ("train", ["train.amp=fp8"], "train.amp: expected one of auto, bf16, none"),
    ("sample", ["scene_up=x"], "scene_up: expected one of y, z, got 'x'"),
    ("sample", ["scene_unit=km"], "scene_unit: expected one of m, cm, mm"),
    ("sample", ["voxel_size=0"], "voxel_size: expected a number >= 0.005 and <= 0.5, got 0.0"),
    ("sample", ["voxel_size=1e9"], "voxel_size: expected a number >= 0.005"),
    ("sample", ["num_samples=1000000"], "num_samples: expected an integer >= 1 and <= 1024"),
    ("sample", ["num_samples=0"], "num_samples: expected an integer >= 1"),
    ("sample", ["steps=0"], "steps must be >= 1, got 0"),
    ("sample", ["steps=100000"], "steps: expected an integer >= 1 and <= 10000"),
    ("sample", ["start_yaw=inf"], "start_yaw: expected a number, got inf"),
    ("sample", ["body_height=[1.7,0.1]"], "body_height[1]: expected a number > 1.7"),
    ("sample", ["approach=-1"], "approach: expected a number >= 0 and <= 100, got -1.0"),
    ("serve", ["approach=nan"], "approach: expected a number >= 0"),
    ("sample", ["loop.max_episodes=0"], "loop.max_episodes: expected an integer >= 1"),
    ("sample", ["loop.tolerance=-1"], "loop.tolerance: expected a number > 0"),
    ("sample", ["loop.settle=-1"], "loop.settle: expected an integer >= 0"),
    ("sample", ["loop.out_fps=1e9"], "loop.out_fps: expected a number > 0 and <= 1000"),
    ("sample", ["video_fps=0"], "video_fps: expected a number > 0"),
    ("evaluate", ["max_episodes=0"], "max_episodes: expected an integer >= 1 and <= 100000, got 0"),
    ("evaluate", ["min_distance=-1"], "min_distance: expected a number >= 0 and <= 1000, got -1.0"),
    ("evaluate", ["k=0"], "k: expected an integer >= 1"),
    ("evaluate", ["k=5000"], "k: expected an integer >= 1 and <= 1024"),
    ("evaluate", ["pairs=0"], "pairs: expected an integer >= 1"),
    ("evaluate", ["approach=-0.5"], "approach: expected a number >= 0 and <= 100, got -0.5"),
    ("evaluate", ["mocap=/no/such/clips"], "mocap: /no/such/clips does not exist"),
    ("evaluate", ["mocap=[/tmp,/no/such.bvh]"], "mocap: "),
    ("train_body_mlp", ["lr=-1"], "lr: expected a number > 0, got -1.0"),
    ("train_body_mlp", ["lr=0"], "lr: expected a number > 0"),
    ("train_body_mlp", ["device=tpu"], "device: expected cpu, cuda, cuda:N or mps, got 'tpu'"),
    ("train_body_mlp", ["data.fps=1e9"], "data.fps: expected a number > 0 and <= 1000"),
    ("train_body_mlp", ["batch_size=0"], "batch_size: expected an integer >= 1"),
]


def _build(app, overrides):
    """The app's config as its command builds it, before any work."""
    from omegaconf import OmegaConf

    from motiongen.training.train_config import TrainConfig

    extra = ["ckpt=x.pt"] if app in ("sample", "evaluate") else []
    cfg = _compose(app, [*extra, *overrides])
    if app == "train":
        return TrainConfig(**OmegaConf.to_container(cfg.train, resolve=True))
    return OmegaConf.to_object(cfg)


@pytest.mark.parametrize("app, overrides, message", OUT_OF_RANGE, ids=lambda v: v if isinstance(v, str) else None)
def test_out_of_range_keys_are_one_config_error(app, overrides, message):
    from motiongen.errors import ConfigError

    with pytest.raises(ConfigError) as e:
        _build(app, overrides)
    assert "\n" not in str(e.value) and str(e.value).startswith(message), str(e.value)


def test_valid_defaults_and_experiments_pass_the_range_checks():
    for name in ("demo", "paper", "quality"):
        _build("train", [f"experiment={name}"])
    _build("sample", ["steps=8", "num_samples=1024", "loop.transition=2", "start_yaw=0.5"])
    _build("evaluate", ["k=1", "min_distance=0"])
    _build("train_body_mlp", [])
