"""LEMO's motion priors (motiongen/capture/motion_prior.py) and their training command
(`motiongen train-motion-prior`): shapes, the smoothness term, infilling, checkpoints, resume.
Tiny channel widths and windows keep the whole file well under a minute on 2 cores."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch

from motiongen.capture.motion_prior import (MotionPrior, PriorNetConfig, canonical_frame, from_canonical, infill,
                                            load_prior, save_prior, smoothness_term, to_canonical)
from motiongen.errors import DataError
from tests.run_inprocess import run_command

TINY = [4, 8]


def pairs(M: int) -> tuple[list[int], list[int]]:
    """Mirror pairs of a plain marker set: marker 2k (left) and 2k+1 (right)."""
    return list(range(0, M - 1, 2)), list(range(1, M, 2))


def prior(kind: str, M: int = 81, channels=TINY, window: int = 32, seed: int = 0) -> MotionPrior:
    torch.manual_seed(seed)
    return MotionPrior(PriorNetConfig(kind, channels), M, *pairs(M), window=window).eval()


def walking_markers(T: int, M: int, seed: int = 0, facing: float = 0.3) -> torch.Tensor:
    """(T, M, 3) a rigid-ish marker cloud (left markers at +x) walking along `facing` at 1 m/s
    with a smooth sway: clean motion."""
    g = torch.Generator().manual_seed(seed)
    body = torch.rand(M, 3, generator=g) * torch.tensor([0.2, 1.7, 0.2])
    left, right = pairs(M)
    body[left, 0] += 0.15
    body[right, 0] -= 0.15
    t = torch.arange(T, dtype=torch.float32)[:, None] / 30.0
    c, s = np.cos(facing), np.sin(facing)
    R = torch.tensor([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=torch.float32)
    local = body[None] + 0.05 * torch.sin(2 * np.pi * t[..., None] + body[None, :, 1:2])   # sway
    walk = torch.cat([torch.zeros(T, 2), t], 1)[:, None]                                  # +z at 1 m/s
    return (local + walk) @ R.T + torch.tensor([1.0, 0.0, -2.0])


# ---- networks ---------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["smooth", "infill"])
@pytest.mark.parametrize("M", [67, 81])
def test_output_shapes_for_odd_sizes(kind, M):
    p = prior(kind, M)
    x = walking_markers(37, M)[None].repeat(2, 1, 1, 1)
    canon, origin, rot = p.canonicalise(x)
    if kind == "smooth":
        out, z = p.reconstruct(canon)
        assert out.shape == (2, 37, M, 3)
        assert z.shape == (2, TINY[-1], 37, M) and p.encode(canon).shape == z.shape   # full T x M latent
    else:
        obs = torch.rand(2, 37, M) > 0.3
        assert p.net(p.infill_input(canon, obs)).shape == (2, 3, 37, M)
        assert p.predict(canon, obs).shape == (2, 37, M, 3)


def test_paper_channels_by_default():
    assert PriorNetConfig("smooth").resolved_channels() == [32, 64, 64, 64, 64]
    assert PriorNetConfig("infill").resolved_channels() == [32, 64, 128, 256, 256]


def test_canonical_frame_faces_plus_z_on_the_floor():
    x = walking_markers(10, 20, facing=1.1)
    origin, rot = canonical_frame(x, *pairs(20))
    assert origin[1] == 0 and torch.allclose(origin[[0, 2]], x[0].mean(0)[[0, 2]])
    c = to_canonical(x, origin, rot)
    assert torch.allclose(c[..., 1], x[..., 1])                                # heights kept
    left, right = pairs(20)
    lr = (c[0, left] - c[0, right]).mean(0)
    assert lr[0] > 0 and abs(lr[2]) < 1e-5                                     # left at +x: facing +z
    assert (c[-1, :, 2].mean() - c[0, :, 2].mean()) > 0.25                      # walks forward
    assert torch.allclose(from_canonical(c, origin, rot), x, atol=1e-5)


# ---- the smoothness term --------------------------------------------------------------------

def test_smoothness_term_zero_for_constant_and_larger_for_jitter():
    M = 81
    p = prior("smooth", M, window=24)
    still = walking_markers(1, M).expand(50, M, 3).clone()
    assert smoothness_term(p, still).item() == pytest.approx(0.0, abs=1e-7)
    clean = walking_markers(50, M)
    noisy = clean + 0.02 * torch.randn(clean.shape, generator=torch.Generator().manual_seed(1))
    e_clean, e_noisy = smoothness_term(p, clean).item(), smoothness_term(p, noisy).item()
    assert 0 < e_clean < e_noisy
    x = noisy.clone().requires_grad_(True)
    smoothness_term(p, x).backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
    assert smoothness_term(p, clean[:1]).item() == 0.0                        # one frame: no change


# ---- infilling -----------------------------------------------------------------------------

@pytest.mark.parametrize("T", [1, 37, 100])
def test_infill_keeps_observed_entries_and_handles_nan(T):
    M = 67
    p = prior("infill", M, window=32)
    x = walking_markers(T, M)
    obs = torch.rand(T, M, generator=torch.Generator().manual_seed(T)) > 0.4
    obs[:, 40:] = False                                                      # a block of markers missing
    given = x.clone()
    given[~obs] = float("nan")
    out = infill(p, given, obs)
    assert out.shape == (T, M, 3) and torch.isfinite(out).all()
    assert torch.equal(out[obs], given[obs])                                 # exactly as given
    nothing = infill(p, torch.full((T, M, 3), float("nan")), torch.zeros(T, M, dtype=torch.bool))
    assert torch.isfinite(nothing).all()


def test_interpolation_under_the_infill_network():
    from motiongen.capture.motion_prior import interpolate_missing

    x = torch.arange(6.0)[None, :, None, None].expand(1, 6, 2, 3).clone()
    obs = torch.tensor([[0, 1, 0, 0, 1, 0], [0, 0, 0, 0, 0, 0]], dtype=torch.bool).T[None]
    x[~obs] = float("nan")
    out = interpolate_missing(x, obs, torch.full((2, 3), -1.0))[0, :, :, 0]
    assert out[:, 0].tolist() == [1, 1, 2, 3, 4, 4]                           # held, linear, held
    # Never observed: the fill, placed at the horizontal centre of the observed markers.
    assert out[:, 1].tolist() == [1, 1, 2, 3, 4, 4]
    assert interpolate_missing(x, obs, torch.full((2, 3), -1.0))[0, :, 1, 1].tolist() == [-1] * 6
    # Hidden markers travel with the visible ones (offsets from their centre, interpolated).
    walk = torch.zeros(1, 8, 3, 3)
    walk[..., 2] = torch.arange(8.0)[None, :, None] + torch.tensor([0.0, 0.5, 1.0])   # all move +z
    obs = torch.ones(1, 8, 3, dtype=torch.bool)
    obs[0, :5, 2] = False                                                      # marker 2 hidden at first
    out = interpolate_missing(walk, obs, torch.zeros(3, 3), reference=torch.tensor([True, True, False]))
    assert torch.allclose(out, walk)


def test_training_reduces_reconstruction_loss():
    from motiongen.capture.train_motion_prior import Batch, TrainPriorConfig, losses

    M, T = 20, 16
    for kind in ("smooth", "infill"):
        cfg = TrainPriorConfig(kind=kind, net=PriorNetConfig(kind, TINY), steps=30, batch_size=4, window=T,
                               lr=3e-3, w_smooth=0.1)
        p = prior(kind, M, window=T).train()
        x = torch.stack([walking_markers(T, M, seed=s) for s in range(4)])
        obs = torch.ones(4, T, M, dtype=torch.bool)
        obs[:, 4:12, 10:] = False
        canon, _, _ = p.canonicalise(x, obs if kind == "infill" else None)
        p.set_normalisation(canon.mean((0, 1)), canon.std((0, 1)))
        b = Batch(canon, obs if kind == "infill" else None)
        opt = torch.optim.Adam(p.parameters(), lr=3e-3)
        first = losses(p, cfg, b)["loss"].item()
        for _ in range(30):
            loss = losses(p, cfg, b)["loss"]
            opt.zero_grad()
            loss.backward()
            opt.step()
        assert losses(p, cfg, b)["loss"].item() < 0.7 * first, kind


# ---- checkpoints -----------------------------------------------------------------------------

def test_save_load_round_trip_and_refusals(tmp_path):
    for kind in ("smooth", "infill"):
        p = prior(kind, 30)
        p.set_normalisation(torch.rand(30, 3), torch.rand(30, 3) + 0.5)
        path = save_prior(tmp_path / f"{kind}.pt", p, {"steps": 3, "note": tmp_path})
        q = load_prior(path)
        assert q.kind == kind and q.num_markers == 30 and q.window == p.window and q.meta["steps"] == 3
        x = walking_markers(20, 30)
        if kind == "smooth":
            assert torch.equal(smoothness_term(p, x), smoothness_term(q, x))
        else:
            obs = torch.rand(20, 30) > 0.5
            assert torch.equal(infill(p, x, obs), infill(q, x, obs))
    assert not list(tmp_path.glob(".*.tmp"))
    with pytest.raises(DataError, match="not found"):
        load_prior(tmp_path / "missing.pt")
    torch.save({"kind": "motion_model", "state_dict": {}}, tmp_path / "model.pt")
    with pytest.raises(DataError, match="not a motion-prior checkpoint"):
        load_prior(tmp_path / "model.pt")
    torch.save({"cfg": PriorNetConfig()}, tmp_path / "objects.pt")            # Python objects: refused unread
    with pytest.raises(DataError, match="not a motion-prior checkpoint"):
        load_prior(tmp_path / "objects.pt")
    (tmp_path / "text.pt").write_text("hello")
    with pytest.raises(DataError, match="not a motion-prior checkpoint") as e:
        load_prior(tmp_path / "text.pt")
    assert "\n" not in str(e.value)


# ---- the command -----------------------------------------------------------------------------

def smplx_dataset(root, T: int = 40):
    """A dataset with SMPL-X parameters of the procedural body: 2 sequences in each of the
    train, val and test scenes (1, 71, 91)."""
    from motiongen.body.model import load_body_model
    from motiongen.body.random_motion import sample_motion
    from motiongen.data.dataset_writer import DatasetWriter
    from motiongen.skeleton import BODY

    bm = load_body_model()
    w = DatasetWriter(root, BODY, ["walk"], 30.0, has_smplx=True)
    rng = np.random.default_rng(0)
    for sid in (1, 71, 91):
        w.add_scene(sid)
        for k in range(2):
            m = sample_motion(T, 30.0, rng, num_betas=10)
            with torch.no_grad():
                j = bm.joints(*(torch.as_tensor(m[f]) for f in ("global_orient", "body_pose", "transl", "betas")))
            w.add_sequence(f"s{sid}_{k}", sid, j.numpy(), np.ones((T, 1), bool), np.zeros((T, 22), bool), smplx=m)
    return w.finish(splits={"train": [1], "val": [71], "test": [91]}, source="test")


TINY_ARGS = ["net.channels=[4,8]", "window=16", "batch_size=2", "val_windows=2", "norm_windows=8", "log_every=1",
             "val_every=2", "threads=1"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return smplx_dataset(tmp_path_factory.mktemp("prior_data") / "ds")


@pytest.mark.parametrize("kind", ["smooth", "infill"])
def test_command_end_to_end_and_bitwise_resume(kind, dataset, tmp_path, capsys, in_process):
    common = [f"kind={kind}", f"data={dataset}", *TINY_ARGS]
    r = run_command("train-motion-prior", [*common, f"out={tmp_path / 'a'}", "steps=4"], capsys)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "a" / "prior.pt").is_file() and list((tmp_path / "a" / "tb").glob("events.*"))
    assert (tmp_path / "a" / "checkpoints" / "last.pt").is_file()
    p = load_prior(tmp_path / "a" / "prior.pt")
    assert p.kind == kind and p.num_markers == 81 and p.window == 16
    assert p.meta["final_val"] and np.isfinite(p.meta["final_val"]["loss"])
    # Half the steps, then resume to the same end: bitwise the same weights.
    r = run_command("train-motion-prior", [*common, f"out={tmp_path / 'b'}", "steps=2", "ckpt_every=1"], capsys)
    assert r.returncode == 0, r.stderr
    r = run_command("train-motion-prior", [*common, f"out={tmp_path / 'b'}", "steps=4"], capsys)
    assert r.returncode == 0 and "resuming" in r.stdout, r.stderr
    q = load_prior(tmp_path / "b" / "prior.pt")
    a, b = p.state_dict(), q.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_marker_data_from_joints_only_dataset_is_fitted_and_cached(tmp_path, capsys):
    from motiongen.capture.prior_data import prior_data
    from tests.helpers import make_dataset

    root = make_dataset(tmp_path / "ds", scenes=(1,), seqs_per_scene=1, T=12, obstacle=False)
    data, _, _ = prior_data(str(root), ("train", "val"), fit_mlp="none")
    assert set(data) == {"train"} and data["train"].frames.shape == (12, 81, 3)
    assert np.isfinite(data["train"].frames).all()
    again, _, _ = prior_data(str(root), ("train",), fit_mlp="none")
    assert "from " in capsys.readouterr().out.splitlines()[-1]                # read from the cache
    assert np.array_equal(again["train"].frames, data["train"].frames)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers fork on Linux only (motiongen.forked)")
def test_marker_fitting_in_forked_workers_equals_one_process(tmp_path):
    """Joints-only sequences fitted in two forked workers give the markers one process gives,
    in sequence order (the workers return in any order)."""
    from motiongen.body.model import load_body_model
    from motiongen.capture.prior_data import split_markers
    from motiongen.data.format import MotionDataset
    from tests.helpers import make_dataset

    ds = MotionDataset.open(make_dataset(tmp_path / "ds", scenes=(1,), seqs_per_scene=3, T=10, obstacle=False))
    bm = load_body_model(None)
    one = split_markers(ds, "train", bm, fit_mlp="none", cache=False, verbose=False, workers=1)
    two = split_markers(ds, "train", bm, fit_mlp="none", cache=False, verbose=False, workers=2)
    assert len(one.lengths) == 3
    assert one.names == two.names and np.array_equal(one.lengths, two.lengths)
    assert np.array_equal(one.frames, two.frames)


@pytest.mark.parametrize("args,message", [
    (["bogus=1"], "unknown key"),
    (["kind=walk"], "kind: expected one of smooth, infill"),
    (["steps=0"], "steps: expected an integer >= 1"),
    (["net.channels=[0]"], "net.channels: expected an integer >= 1"),
    (["lr=-1"], "lr: expected a number > 0"),
    (["resume=maybe"], "resume: expected auto, true or false"),
    (["data={tmp}/none"], "dataset directory does not exist"),
    (["resume=true"], "resume=true: no checkpoint"),
    (["window=abc"], "window: expected an integer"),
    (["window=1"], "window: expected an integer >= 2"),
])
def test_bad_values_are_one_line_and_exit_2(args, message, tmp_path, capsys, in_process):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in args] + [f"out={tmp_path / 'o'}"]
    r = run_command("train-motion-prior", argv, capsys)
    assert r.returncode == 2, (r.stdout, r.stderr)
    err = r.stderr.strip()
    assert err.startswith("error: ") and "\n" not in err and message in err, err
    assert not (tmp_path / "o" / "prior.pt").exists()
