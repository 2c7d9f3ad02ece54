"""Distilled few-step students (`motiongen distill`, diffusion/trajectory.py, training/distill.py):
the teacher's trajectory recorded on the student's grid, the training step, a closed-form
teacher whose 1-step student must reproduce its DDIM-25 output, the command end to end with
`sample`, exact resume, and every bad key one line and exit 2."""

import copy
import json
import os
from dataclasses import asdict
from types import SimpleNamespace

import pytest
import torch
from omegaconf import OmegaConf

from motiongen.data.windows import WindowConfig, WindowDataset
from motiongen.diffusion import DiffusionConfig, GaussianDiffusion, MaskConfig, sample, spaced_timesteps
from motiongen.diffusion.trajectory import distill_loss, student_states, teacher_trajectory
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.loading.build import build_from_config
from motiongen.models import Condition, build_model, model_config
from motiongen.sampling.settings import SamplerSettings, resolve_sampler
from motiongen.skeleton import BODY
from tests.helpers import make_dataset
from tests.run_inprocess import run_command

TINY = dict(width=32, layers=1, heads=2, ff=64, dropout=0.0, action_width=32, action_layers=1, action_heads=2,
            action_ff=64, action_dropout=0.0, use_scene=False)


def _cond(B: int, L: int, seed: int = 0) -> Condition:
    g = torch.Generator().manual_seed(seed)
    return Condition(actions=(torch.rand(B, L, 2, generator=g) > 0.5).float())


# -- the teacher's trajectory ---------------------------------------------------------------------

def test_trajectory_ends_where_sample_ends_and_passes_the_ddim_path_at_student_steps():
    """x0* is exactly `sample`'s DDIM result for the same noise; with a teacher whose x̂0 is a
    constant c, DDIM keeps ε fixed, so the state at any timestep s is √ᾱ_s·c + √(1-ᾱ_s)·ε in closed
    form — including a student timestep (49) that the teacher's 5-step grid (99, 79, 59, 39, 19)
    steps over."""
    d = GaussianDiffusion(DiffusionConfig(prediction="x0", clip_x0=None))
    c = torch.linspace(-0.5, 0.5, 2 * 3 * 4).reshape(2, 3, 4)
    model = lambda x, t, cond, known_mask=None: c.expand_as(x).clone()          # noqa: E731
    states, x0 = teacher_trajectory(d, model, (2, 3, 4), None, 2, teacher_steps=5,
                                    generator=torch.Generator().manual_seed(3))
    ref = sample(d, model, (2, 3, 4), None, steps=5, generator=torch.Generator().manual_seed(3))
    assert torch.equal(x0, ref) and states.shape == (2, 2, 3, 4)
    ab = d.alphas_cumprod
    eps = (states[:, 0] - ab[99].sqrt() * c) / (1 - ab[99]).sqrt()
    expected = ab[49].sqrt() * c + (1 - ab[49]).sqrt() * eps
    assert spaced_timesteps(100, 2).tolist() == [99, 49]
    assert torch.allclose(states[:, 1], expected, atol=1e-5)


def test_student_states_follow_the_students_own_ddim_steps():
    """upto = 0 gives x_T back; upto = 1 one DDIM step of the student from it (known entries kept)."""
    d = GaussianDiffusion(DiffusionConfig(prediction="x0", clip_x0=None))
    x_T = torch.randn(2, 3, 4, generator=torch.Generator().manual_seed(0))
    c = torch.full((2, 3, 4), 0.3)
    model = lambda x, t, cond, known_mask=None: c.clone()                       # noqa: E731
    got = student_states(d, model, x_T, torch.tensor([0, 1]), 2, None)
    ab = d.alphas_cumprod
    eps = (x_T[1] - ab[99].sqrt() * 0.3) / (1 - ab[99]).sqrt()
    assert torch.equal(got[0], x_T[0])
    assert torch.allclose(got[1], ab[49].sqrt() * 0.3 + (1 - ab[49]).sqrt() * eps, atol=1e-5)


# -- the training step ----------------------------------------------------------------------------

def test_training_step_reduces_the_distillation_loss_on_a_fixed_batch():
    """A tiny denoiser distilled from its own guided (scale 3) DDIM-10 run: the student starts as
    the teacher, so its 2-step x0 misses the guided output, and 25 Adam steps on the loss must at
    least halve it (measured: to 7%; a loss that carried no gradient, or the wrong target, would
    not)."""
    torch.manual_seed(0)
    L, D, B = 16, 70, 8
    teacher = build_model(model_config("tiny", **TINY), 22, 2, L, channels=D).eval()
    d = GaussianDiffusion(DiffusionConfig())
    cond, gen = _cond(B, L), torch.Generator().manual_seed(1)
    known = torch.randn(B, L, D, generator=gen).clamp(-1, 1)
    mask = torch.zeros(B, L, D, dtype=torch.bool)
    mask[:, :2] = True
    states, target = teacher_trajectory(d, teacher, (B, L, D), cond, 2, known=known, known_mask=mask,
                                        teacher_steps=10, guidance_scale=3.0, generator=gen)
    student = copy.deepcopy(teacher).train().requires_grad_(True)
    opt = torch.optim.Adam(student.parameters(), lr=2e-3)
    i = torch.arange(B) % 2
    t = spaced_timesteps(100, 2)[i]
    x_t = states[torch.arange(B), i]

    def loss():
        return distill_loss(d, student, x_t, t, cond, target, known, mask)

    first = float(loss().detach())
    for _ in range(25):
        opt.zero_grad()
        loss().backward()
        opt.step()
    last = float(loss().detach())
    assert first > 1e-4 and last < 0.5 * first, (first, last)


# -- a closed-form teacher ------------------------------------------------------------------------

class GaussianTeacher:
    """The exact x0-predictor of data N(μ, Σ) (12 dims, as (3, 4) windows): E[x0 | x_t] =
    μ + √ᾱ·Σ(ᾱΣ + (1-ᾱ)I)⁻¹(x_t - √ᾱ·μ), affine in x_t, with μ = μ_c under the condition and μ_u
    when it is dropped. Guided DDIM with known entries written in is then an affine map of x_T
    and the known values, and so is a linear student of its input: least squares has an exact
    solution, and distillation must find it."""

    def __init__(self, d: GaussianDiffusion):
        g = torch.Generator().manual_seed(5)
        A = torch.randn(12, 12, generator=g) * 0.4
        self.sigma = A @ A.T + 0.05 * torch.eye(12)
        self.mu_c, self.mu_u = torch.randn(12, generator=g) * 0.5, torch.randn(12, generator=g) * 0.5
        self.ab = d.alphas_cumprod

    def __call__(self, x, t, cond, known_mask=None):
        B = x.shape[0]
        dropped = cond.drop_actions if cond.drop_actions is not None else torch.zeros(B, dtype=torch.bool)
        mu = torch.where(dropped[:, None], self.mu_u, self.mu_c)                     # (B, 12)
        ab = self.ab[t][:, None, None].double()                                       # (B, 1, 1)
        gain = ab.sqrt() * self.sigma.double() @ torch.linalg.inv(ab * self.sigma.double()
                                                                  + (1 - ab) * torch.eye(12).double())
        x0 = mu.double() + (gain @ (x.reshape(B, 12, 1).double() - ab.sqrt() * mu[..., None].double()))[..., 0]
        return x0.reshape(x.shape).to(x.dtype)


class LinearStudent(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.lin = torch.nn.Linear(12, 12)

    def forward(self, x, t, cond, known_mask=None):
        return self.lin(x.reshape(x.shape[0], 12)).reshape(x.shape)


def test_one_step_student_of_a_closed_form_teacher_reproduces_its_guided_ddim25_output():
    """Distil the Gaussian teacher's guided (scale 2) DDIM-25 into a 1-step linear student on
    256 teacher runs, then sample fresh noise and known values: the student's one DDIM step
    must land on the teacher's 25-step output within 1e-3 (0.1% of the data's unit scale; the
    exact least-squares solution has zero error, so what is left is the optimiser's residual,
    measured at 7e-5), where the teacher's own single step misses it by far more (> 0.3, measured
    5.3: the test can tell a student that learnt nothing)."""
    d = GaussianDiffusion(DiffusionConfig(prediction="x0", clip_x0=None))
    teacher = GaussianTeacher(d)

    def runs(n, seed):
        g = torch.Generator().manual_seed(seed)
        known = torch.randn(n, 3, 4, generator=g)
        mask = torch.zeros(n, 3, 4, dtype=torch.bool)
        mask[:, 0, :2] = True                                          # two entries given, as a goal is
        cond = Condition(actions=torch.ones(n, 1, 1))
        return cond, known, mask, g

    cond, known, mask, g = runs(256, 0)
    states, target = teacher_trajectory(d, teacher, (256, 3, 4), cond, 1, known=known, known_mask=mask,
                                        guidance_scale=2.0, generator=g)
    torch.manual_seed(0)
    student = LinearStudent()
    opt = torch.optim.Adam(student.parameters(), lr=0.05)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, 300)
    t = torch.full((256,), 99)
    for _ in range(300):
        opt.zero_grad()
        distill_loss(d, student, states[:, 0], t, cond, target, known, mask).backward()
        opt.step()
        sched.step()
    cond, known, mask, _ = runs(64, 1)
    kw = dict(known=known, known_mask=mask)
    want = sample(d, teacher, (64, 3, 4), cond, steps=25, guidance_scale=2.0, generator=torch.Generator().manual_seed(9), **kw)
    with torch.no_grad():
        got = sample(d, student, (64, 3, 4), cond, steps=1, generator=torch.Generator().manual_seed(9), **kw)
    one = sample(d, teacher, (64, 3, 4), cond, steps=1, guidance_scale=2.0, generator=torch.Generator().manual_seed(9), **kw)
    free = ~mask
    assert (got - want)[free].abs().max() < 1e-3, float((got - want)[free].abs().max())
    assert (one - want)[free].abs().max() > 0.3


# -- the command ------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def teacher(tmp_path_factory):
    """A random-init tiny teacher in train.py's format on a small dataset of its own (the bank
    draws training windows from the teacher's data config)."""
    d = tmp_path_factory.mktemp("distill")
    root = d / "data"
    make_dataset(root, scenes=(1, 71, 91), seqs_per_scene=1, T=90, obstacle=False)
    cfg = OmegaConf.create({"model": asdict(model_config("tiny", **{**TINY, "use_scene": False})),
                            "diffusion": asdict(DiffusionConfig()), "window": asdict(WindowConfig(scene=False)),
                            "mask": asdict(MaskConfig()), "data": asdict(DataConfig(source="dataset", root=str(root)))})
    ds = open_dataset(DataConfig(source="dataset", root=str(root)))
    torch.manual_seed(0)
    model, _, meta = build_from_config(cfg, BODY, ds.action_names)
    stats = WindowDataset(ds, "train", WindowConfig(scene=False)).stats
    state = {"format": "motiongen-checkpoint", "config": OmegaConf.to_container(cfg), "step": 7, "fps": 30.0,
             "stats": stats.state_dict(), "ema": model.state_dict(), "model": model.state_dict(), **meta}
    (d / "run" / "checkpoints").mkdir(parents=True)
    path = d / "run" / "checkpoints" / "last.pt"
    torch.save(state, path)
    student = dict(state, distill={"method": "trajectory", "steps": 2, "teacher": str(path)})
    torch.save(student, d / "student.pt")
    return {"ckpt": path, "dir": d, "student": d / "student.pt"}


def _distill_args(teacher, out, *extra):
    return [f"ckpt={teacher['ckpt']}", f"out={out}", "bank_size=16", "bank_batch=8", "batch_size=8", "teacher_steps=5",
            "max_steps=4", "ckpt_every=2", "log_every=1", "threads=1", "progress=false", *extra]


def test_distill_then_sample_end_to_end(teacher, tmp_path, capsys):
    out = tmp_path / "student"
    r = run_command("distill", _distill_args(teacher, out, "steps=2", "guidance_scale=2"), capsys)
    assert r.returncode == 0, r.stderr[-1500:]
    last = out / "checkpoints" / "last.pt"
    assert (out / "bank.pt").is_file() and any((out / "tb").iterdir()) and (out / "distill_config.yaml").is_file()
    info = torch.load(last, weights_only=False)["distill"]
    assert info["steps"] == 2 and info["timesteps"] == [99, 49] and info["guidance_scale"] == 2.0
    assert info["teacher_steps"] == 5 and info["teacher"] == str(teacher["ckpt"].resolve())
    r = run_command("distill", [f"info={last}"], capsys)
    assert r.returncode == 0 and "steps: 2" in r.stdout and "method: trajectory" in r.stdout
    so = tmp_path / "sample"
    r = run_command("sample", [f"ckpt={last}", "goals=[[1.0,1.0]]", "start=[0,0]", f"out={so}", "video=false",
                               "plot=false", "loop.max_episodes=3", "loop.warmup=1", "threads=1"], capsys)
    assert r.returncode in (0, 3), r.stderr[-1500:]                   # 3: the random model reached no goal
    summary = json.loads((so / "summary.json").read_text())
    assert summary["sampler"]["steps"] == 2 and summary["sampler"]["guidance_scale"] == 1.0


def test_a_resumed_distillation_ends_bitwise_equal_to_one_that_ran_through(teacher, tmp_path, capsys):
    """Killed after its step-2 checkpoint (emulated: the step-4 file removed, last.pt back on
    step 2) and run again: the bank is read back and the student ends where the uninterrupted
    run did, bit for bit."""
    a, b = tmp_path / "a", tmp_path / "b"
    for out in (a, b):
        assert run_command("distill", _distill_args(teacher, out, "steps=2"), capsys).returncode == 0
    ck = b / "checkpoints"
    (ck / "step_00000004.pt").unlink()
    (ck / "last.pt").unlink()
    os.link(ck / "step_00000002.pt", ck / "last.pt")
    r = run_command("distill", _distill_args(teacher, b, "steps=2"), capsys)
    assert r.returncode == 0 and "resumed from" in r.stdout and "read from" in r.stdout, r.stdout
    wa, wb = (torch.load(p / "checkpoints" / "last.pt", weights_only=False) for p in (a, b))
    assert wa["step"] == wb["step"] == 4
    assert all(torch.equal(wa["ema"][k], wb["ema"][k]) for k in wa["ema"])
    r = run_command("distill", _distill_args(teacher, b, "steps=1"), capsys)       # another student there: refused
    assert r.returncode == 2 and r.stderr.strip().endswith("give another out= or resume=null"), r.stderr[-1500:]
    assert "was distilled with other steps (steps=2)" in r.stderr


BAD = {
    "steps_3": (["steps=3"], "steps: expected one of 1, 2, 4, got 3"),
    "steps_0": (["steps=0"], "steps: expected one of 1, 2, 4, got 0"),
    "missing_ckpt": (["ckpt={dir}/none.pt"], "teacher checkpoint file does not exist"),
    "teacher_folder": (["out={dir}/run"], "that is the teacher's own folder"),
    "teacher_checkpoints": (["out={dir}/run/checkpoints"], "that is the teacher's own folder"),
    "student_as_teacher": (["ckpt={dir}/student.pt"], "is itself a distilled 2-step student"),
}


@pytest.mark.parametrize("name", list(BAD))
def test_bad_distill_keys_exit_2_with_one_line(teacher, tmp_path, capsys, name):
    extra, needle = BAD[name]
    args = _distill_args(teacher, tmp_path / name) + [a.format(dir=teacher["dir"]) for a in extra]
    r = run_command("distill", args, capsys)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: "), r.stderr[-1500:]
    assert needle in lines[0], lines[0]
    assert not (tmp_path / name).exists() or not any((tmp_path / name).iterdir())
    assert sorted(p.name for p in (teacher["dir"] / "run").rglob("*")) == ["checkpoints", "last.pt"]


@pytest.mark.parametrize("command,args,needle", [
    ("distill", ["info={ckpt}"], "not a distilled student (no 'distill' entry"),
    ("sample", ["ckpt={student}", "steps=3"], "steps=3: this checkpoint is a 2-step distilled student"),
    ("sample", ["ckpt={student}", "sampler=ddpm"], "a distilled student samples with deterministic DDIM"),
])
def test_a_student_is_told_apart_in_one_line(teacher, tmp_path, capsys, command, args, needle):
    if command == "sample":
        args = args + ["goals=[[1.0,1.0]]", "start=[0,0]", f"out={tmp_path / 'o'}", "video=false"]
    r = run_command(command, [a.format(ckpt=teacher["ckpt"], student=teacher["student"]) for a in args], capsys)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and needle in lines[0], r.stderr[-1500:]


def test_sampler_settings_take_a_students_defaults():
    student, teacher_ = SimpleNamespace(distill={"steps": 4}), SimpleNamespace(distill=None)
    assert resolve_sampler(SamplerSettings(), student) == SamplerSettings("ddim", 4, 0.0, 1.0)
    assert resolve_sampler(SamplerSettings(steps=4, guidance_scale=1.5), student).guidance_scale == 1.5
    assert resolve_sampler(SamplerSettings(), teacher_) == SamplerSettings("ddim", 25, 0.0, 1.0)
    assert resolve_sampler(SamplerSettings(), teacher_, default_steps=10).steps == 10
    assert resolve_sampler(SamplerSettings(steps=7), teacher_).steps == 7
