"""Training on the network's own transition frames (`train.rollout_p`, training/rollout.py):
the dataset's previous windows and the frame bookkeeping that hands the network's last frames
on, checked with 'networks' whose answer is known."""

import numpy as np
import torch
from omegaconf import OmegaConf
from torch import nn

from motiongen.data.format import MotionDataset
from motiongen.data.windows import WindowConfig, WindowDataset
from motiongen.diffusion import DiffusionConfig, GaussianDiffusion
from motiongen.diffusion.masks import known_mask
from motiongen.geometry import local_to_world, transform_points
from motiongen.training.rollout import own_transitions
from tests.helpers import make_dataset

OFFSET = 14        # a 16-frame window hands on its last 2 frames


class Answers(nn.Module):
    """An x0-predicting 'network' that answers `windows` (n, L, D) whatever it is asked."""

    def __init__(self, windows):
        super().__init__()
        self.windows = windows
        self.calls = 0

    def forward(self, x_t, t, cond, known_mask=None):
        self.calls += 1
        return self.windows.to(x_t.dtype)


def _windows(tmp_path, scene=False):
    ds = MotionDataset.open(make_dataset(tmp_path / "ds"))
    return WindowDataset(ds, "train", WindowConfig(scene=scene), previous=OFFSET)


def _batch(wd, idx):
    items = [wd[i] for i in idx]
    return {k: torch.stack([it[k] for it in items]) for k in items[0]}


def _joints(wd, x, to_world):
    """(B, L, D) normalised windows -> (B, L, J, 3) world joints."""
    local, _ = wd.layout.decode(wd.stats.denormalize(x.double()))
    return transform_points(to_world.double()[:, None], local)


def _run(wd, batch, answers, transition, p=1.0):
    B, L, D = batch["motion"].shape
    mask = known_mask(B, L, wd.layout.num_joints, torch.as_tensor(transition), True, channels=D)
    diffusion = GaussianDiffusion(DiffusionConfig(prediction="x0", clip_x0=1e6))
    cfg = OmegaConf.create({"mask": {}, "diffusion": {"prediction": "x0"}})
    gen = torch.Generator().manual_seed(0)
    return own_transitions(Answers(answers), diffusion, batch, batch["motion"], mask, OFFSET, wd.layout,
                           wd.stats, cfg, p, 2, gen)


def test_previous_window_is_the_one_the_loop_hands_on(tmp_path):
    wd = _windows(tmp_path, scene=True)
    starts = wd.starts
    for i in (0, 13, 14, 30, len(wd) - 1):
        it = wd[i]
        has = bool(it["has_prev"])
        seq_first = max(s.start for s in wd.ds.sequences if s.start <= starts[i])
        assert has == (starts[i] - OFFSET * 3 >= seq_first)
        assert it["prev_scene"].shape == it["scene"].shape
        if has:
            # its frames OFFSET.. are this window's 0..: the same world joints
            prev = _joints(wd, it["prev_motion"][None], it["prev_to_world"][None])[0]
            here = _joints(wd, it["motion"][None], it["to_world"][None])[0]
            assert torch.allclose(prev[OFFSET:], here[:16 - OFFSET], atol=1e-4)
            assert np.allclose(prev.numpy(), wd.ds.joints[wd.window_frames(i) - OFFSET * 3], atol=1e-4)
    assert not bool(wd[0]["has_prev"]) and bool(wd[OFFSET * 3]["has_prev"])


def test_the_data_answered_gives_the_data_back(tmp_path):
    wd = _windows(tmp_path)
    batch = _batch(wd, [50, 60, 70])
    out, n = _run(wd, batch, batch["prev_motion"], [2, 2, 1])
    assert n == 3
    assert torch.allclose(_joints(wd, out, batch["to_world"]), _joints(wd, batch["motion"], batch["to_world"]),
                          atol=1e-4)


def test_own_frames_are_moved_onto_the_data_first_pose(tmp_path):
    """The previous window moved rigidly (turned 0.5 rad, shifted) hands on the same frames;
    raised 5 cm it hands on frames 5 cm higher, the pinned ones only; windows without a
    previous one, or not drawn, keep the data's."""
    wd = _windows(tmp_path)
    batch = _batch(wd, [50, 2, 70, 60])                       # window 2 has no previous one
    assert batch["has_prev"].tolist() == [True, False, True, True]
    local, stance = wd.layout.decode(wd.stats.denormalize(batch["prev_motion"][[0, 2, 3]].double()))
    T = local_to_world(torch.tensor(0.5, dtype=torch.float64), torch.tensor([0.3, -0.2], dtype=torch.float64))
    moved = wd.stats.normalize(wd.layout.encode(transform_points(T, local), stance)).float()
    out, n = _run(wd, batch, moved, [2, 2, 1, 2])
    assert n == 3
    want = _joints(wd, batch["motion"], batch["to_world"])
    assert torch.allclose(_joints(wd, out, batch["to_world"]), want, atol=1e-4)

    raised = local.clone()
    raised[..., 1] += 0.05
    answers = wd.stats.normalize(wd.layout.encode(raised, stance)).float()
    out, _ = _run(wd, batch, answers, [2, 2, 1, 2])
    got = _joints(wd, out, batch["to_world"])
    lift = got[..., 1] - want[..., 1]                                          # (B, L, J)
    assert torch.allclose(lift[[0, 3], :2], torch.full_like(lift[[0, 3], :2], 0.05), atol=1e-4)
    assert torch.allclose(lift[2, :1], torch.full_like(lift[2, :1], 0.05), atol=1e-4)
    assert torch.allclose(got[:, 2:], want[:, 2:], atol=1e-5) and torch.allclose(got[2, 1:], want[2, 1:], atol=1e-5)
    assert torch.equal(out[1], batch["motion"][1])

    out, n = _run(wd, batch, answers[:0], [2, 2, 1, 2], p=0.0)
    assert n == 0 and out is batch["motion"]


def test_training_with_own_transitions_runs_logs_and_resumes_exactly(tmp_path, capsys):
    """train.py with `train.rollout_p=0.6` from step 2: the share shows in TensorBoard, and a run
    stopped at step 3 and resumed to 5 ends with the weights of one run to 5."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from tests.run_inprocess import run_command
    from tests.test_train_cli import _args

    ds = make_dataset(tmp_path / "ds", scenes=(1, 2, 71, 91), seqs_per_scene=2, T=150)
    over = {"train.rollout_p": 0.6, "train.rollout_start": 2, "train.rollout_steps": 2, "train.ckpt_every": 10}
    r = run_command("train", _args(ds, tmp_path / "a", 5, **over), capsys)
    assert r.returncode == 0, r.stderr[-2000:]
    share = [e.value for e in EventAccumulator(str(tmp_path / "a" / "tb")).Reload().Scalars("train/own_transitions")]
    assert 0.1 < share[-1] < 0.9, share           # of the windows with transition frames and a previous one
    r = run_command("train", _args(ds, tmp_path / "b", 3, **over), capsys)
    assert r.returncode == 0, r.stderr[-2000:]
    r = run_command("train", _args(ds, tmp_path / "b", 5, **over, **{"train.resume": "auto"}), capsys)
    assert r.returncode == 0, r.stderr[-2000:]
    a, b = (torch.load(tmp_path / d / "checkpoints" / "last.pt", map_location="cpu", weights_only=False)
            for d in ("a", "b"))
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])
    r = run_command("train", _args(ds, tmp_path / "c", 3, **{"train.rollout_p": 0.5, "mask.max_transition": 0}), capsys)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "error: train.rollout_p needs transition frames to hand on: mask.max_transition is 0"], r.stderr
