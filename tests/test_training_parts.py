import itertools
from dataclasses import asdict

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from motiongen.data.representation import Layout
from motiongen.data.windows import NormStats, WindowConfig
from motiongen.diffusion import DiffusionConfig, MaskConfig
from motiongen.diffusion.masks import known_mask
from motiongen.errors import ConfigError, MotiongenError
from motiongen.geometry import yaw_matrix
from motiongen.loading.build import acting_hands, build_from_config, facing_goals, hand_goal_weights
from motiongen.loading.checkpoint import load_checkpoint, save_checkpoint
from motiongen.models import model_config
from motiongen.skeleton import BODY
from motiongen.training.data_order import ResumableBatchSampler
from motiongen.training.ema import EMA
from tests.helpers import REST


def _take(sampler, k):
    return list(itertools.islice(iter(sampler), k))


def test_batch_order_resumes_exactly():
    full = _take(ResumableBatchSampler(50, 8, seed=3), 20)          # crosses epochs (6 batches/epoch)
    resumed = _take(ResumableBatchSampler(50, 8, seed=3, position=7), 13)
    assert full[7:] == resumed
    epoch0 = [i for b in full[:6] for i in b]
    assert len(set(epoch0)) == 48                                     # no repeats within an epoch
    assert full[:6] != full[6:12]                                     # new permutation each epoch


def test_batch_order_splits_over_ranks():
    one = _take(ResumableBatchSampler(64, 8, seed=1), 5)
    ranks = [_take(ResumableBatchSampler(64, 8, seed=1, rank=r, world=2), 5) for r in range(2)]
    for s in range(5):
        assert ranks[0][s] + ranks[1][s] == one[s]
    with pytest.raises(ValueError):
        ResumableBatchSampler(64, 7, seed=0, world=2)


def test_checkpoint_keep_last_and_links(tmp_path):
    for step in range(1, 6):
        save_checkpoint({"format": "motiongen-checkpoint", "step": step}, tmp_path, step, keep_last=2, best=step == 2)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["best.pt", "last.pt", "step_00000004.pt", "step_00000005.pt"]
    assert load_checkpoint(tmp_path / "last.pt")["step"] == 5
    assert load_checkpoint(tmp_path / "best.pt")["step"] == 2         # survives pruning of step 2


def test_ctrl_c_inside_torch_save_stays_an_interrupt(tmp_path, monkeypatch):
    """Ctrl-C while torch.save writes: its zip writer then fails on closing the half file
    (RuntimeError "unexpected pos ...", the interrupt as its context). The save raises the
    interrupt itself (the CLI's one line and exit 130), leaves no temp file, and last.pt keeps
    the previous checkpoint."""
    save_checkpoint({"format": "motiongen-checkpoint", "step": 1}, tmp_path, 1, keep_last=3)

    def interrupted_save(obj, f):
        f.write(b"PK half a zip")
        try:
            raise KeyboardInterrupt
        finally:
            raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 1328448 vs 1328336")

    monkeypatch.setattr(torch, "save", interrupted_save)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint({"format": "motiongen-checkpoint", "step": 2}, tmp_path, 2, keep_last=3)
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.pt", "step_00000001.pt"]
    assert load_checkpoint(tmp_path / "last.pt")["step"] == 1


def test_checkpoint_errors(tmp_path):
    with pytest.raises(MotiongenError, match="not found"):
        load_checkpoint(tmp_path / "nope.pt")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"garbage")
    with pytest.raises(MotiongenError, match="not a readable checkpoint"):
        load_checkpoint(bad)
    torch.save({"weights": 1}, tmp_path / "foreign.pt")
    with pytest.raises(MotiongenError, match="not a motiongen checkpoint"):
        load_checkpoint(tmp_path / "foreign.pt")


def test_ema_is_exponential_average():
    m = torch.nn.Linear(2, 1, bias=False)
    torch.nn.init.zeros_(m.weight)
    ema = EMA(m, decay=0.9)
    with torch.no_grad():
        m.weight.fill_(1.0)
    ema.update(m)
    ema.update(m)
    assert torch.allclose(ema.model.weight, torch.full((1, 2), 1 - 0.9 ** 2))


def test_acting_hands_names_the_windows_that_end_in_a_hand_action_and_the_wrist_that_reached():
    L, names = 6, ["walk", "pick up"]
    joints = np.repeat(np.repeat(REST[None, None], L, 1), 2, 0).astype(np.float32)      # (2, L, 22, 3)
    joints[0, :, :] += np.linspace(0, 1, L)[:, None, None] * [0.0, 0.0, 1.0]           # walks 1 m: both wrists move with it
    joints[0, :, 20] += np.linspace(0, 1, L)[:, None] * [0.0, -0.4, 0.2]                # the left wrist reaches down
    joints[1, :, 21] += np.linspace(0, 1, L)[:, None] * [0.1, 0.0, 0.0]                 # the right wrist moves a little
    actions = np.zeros((2, L, 2), np.float32)
    actions[0, -1, 1] = 1.0                                                             # window 0 ends picking up
    actions[1, :, 0] = 1.0
    layout, stats = Layout(22), NormStats(np.zeros(66, np.float32), np.ones(66, np.float32))
    batch = {"motion": torch.from_numpy(joints.reshape(2, L, 66)), "actions": torch.from_numpy(actions)}
    acting, wrist = acting_hands(MaskConfig(p_hand_action=1.0, hand_joints=(20, 21)), batch, layout, stats, names)
    assert acting.tolist() == [True, False] and wrist.tolist() == [20, 21]
    assert acting_hands(MaskConfig(), batch, layout, stats, names) is None
    assert BODY.names[20] == "left_wrist"


def test_hand_goal_weight_falls_on_the_named_wrist_over_the_last_quarter():
    """Window 0 has a left-wrist goal, window 1 none, window 2 a right-wrist goal: the weight is on
    that wrist's x, y, z over the last 2 of 8 frames and nowhere else; weight 1 is the plain mean."""
    m = known_mask(3, 8, 22, 2, True, False, torch.tensor([True, False, True]), torch.tensor([20, 21, 21]))
    w = hand_goal_weights(m, (20, 21), 10.0)
    assert w.shape == m.shape
    assert (w == 10).nonzero().tolist() == [[0, f, c] for f in (6, 7) for c in (60, 61, 62)] + \
        [[2, f, c] for f in (6, 7) for c in (63, 64, 65)]
    assert ((w == 1) | (w == 10)).all() and hand_goal_weights(m, (20, 21), 1.0) is None



def test_resume_restores_rngs_and_reseeds_noise_from_another_device(capsys):
    """A checkpoint's RNG states come back exactly; a noise generator state written on another
    kind of device (a CUDA generator's 16 bytes on a CPU run) is reseeded from the step, with a
    warning, instead of stopping the resume with a traceback."""
    from motiongen.training.setup import set_rng_state, rng_state

    gen = torch.Generator().manual_seed(5)
    torch.randn(3, generator=gen)
    saved = rng_state(gen)
    expect = torch.randn(4, generator=gen)
    other = torch.Generator().manual_seed(99)
    set_rng_state(saved, other, step=10)
    torch.testing.assert_close(torch.randn(4, generator=other), expect)       # same device: exact
    foreign = {**saved, "noise": torch.zeros(16, dtype=torch.uint8)}          # a CUDA generator's state size
    a, b = torch.Generator().manual_seed(7), torch.Generator().manual_seed(7)
    set_rng_state(foreign, a, step=11000)
    set_rng_state(foreign, b, step=11000)
    assert "reseeded at step 11000" in capsys.readouterr().out
    torch.testing.assert_close(torch.randn(4, generator=a), torch.randn(4, generator=b))   # deterministic


def test_facing_goals_give_the_last_frames_yaw_and_draw_nothing_when_off():
    """Window 0 ends turned 90 degrees to its left (facing +x), window 1 as it began (+z): the
    facing goal is (sin, cos) of the last frame's yaw; with mask.p_facing 1 every window is
    given one, with 0 none is and the generator is left as it was."""
    L = 4
    joints = np.repeat(np.repeat(REST[None, None], L, 1), 2, 0).astype(np.float64)      # (2, L, 22, 3)
    joints[0, -1] = REST @ yaw_matrix(np.pi / 2).T                                      # the last frame turned to +x
    layout, stats = Layout(22), NormStats(np.zeros(66, np.float32), np.ones(66, np.float32))
    batch = {"motion": torch.from_numpy(joints.reshape(2, L, 66).astype(np.float32))}
    gen = torch.Generator().manual_seed(0)
    facing, given = facing_goals(MaskConfig(p_facing=1.0), batch, layout, stats, gen)
    assert torch.allclose(facing, torch.tensor([[1.0, 0.0], [0.0, 1.0]]), atol=1e-6) and given.all()
    state = gen.get_state()
    assert facing_goals(MaskConfig(), batch, layout, stats, gen) is None
    assert torch.equal(gen.get_state(), state)


def test_a_facing_goal_builds_its_input_and_a_bad_probability_is_one_line():
    def build(p):
        cfg = OmegaConf.create({"model": asdict(model_config("tiny", use_scene=False)), "diffusion": asdict(DiffusionConfig()),
                                "window": asdict(WindowConfig(scene=False)), "mask": asdict(MaskConfig(p_facing=p))})
        return build_from_config(cfg, BODY, ["walk", "pick up"])[0]
    assert build(0.5).facing_embed is not None and build(0.0).facing_embed is None
    with pytest.raises(ConfigError, match=r"mask\.p_facing: expected a probability in 0\.\.1, got 1\.5"):
        build(1.5)
