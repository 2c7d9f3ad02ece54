"""Fitting with missing joints and LEMO's motion priors (`motiongen/capture/prior_fit.py`, the
`motion_prior.*` keys of `motiongen fit` and `motiongen fit-multiview`)."""

import json

import numpy as np
import pytest
import torch

from motiongen.body.fit import RefineConfig, fit_joints, refine
from motiongen.body.random_motion import sample_motion
from motiongen.capture.prior_fit import MotionPriorConfig, fill_linear, fit_observed
from motiongen.commands.fit_command import main as fit_main
from motiongen.errors import ConfigError
from tests.helpers import user_error

LEGS = [1, 2, 4, 5, 7, 8, 10, 11]


@pytest.fixture(scope="module")
def clean(bm):
    m = {k: torch.as_tensor(v) for k, v in sample_motion(40, 30.0, np.random.default_rng(3)).items()}
    with torch.no_grad():
        return bm.joints(m["global_orient"], m["body_pose"], m["transl"], m["betas"]).numpy()   # (40, 22, 3)


def test_fill_linear_is_linear_between_observations_and_held_at_the_ends():
    X = np.zeros((6, 22, 3), np.float32)
    X[:, :, 0] = np.arange(6)[:, None]                          # x = frame index for every joint
    X[[0, 2, 3, 5], 4] = np.nan                                 # left knee seen at frames 1 and 4 only
    filled, observed = fill_linear(X)
    assert observed.sum() == 22 * 6 - 4 and not observed[[0, 2, 3, 5], 4].any()
    np.testing.assert_allclose(filled[:, 4, 0], [1, 1, 2, 3, 4, 4])     # held, interpolated, held
    np.testing.assert_array_equal(filled[:, 3], X[:, 3])        # observed joints untouched
    X[:, 9] = np.nan
    with pytest.raises(ConfigError, match="spine3 is missing"):
        fill_linear(X)


def test_refine_ignores_targets_of_zero_weight(bm, clean):
    """A target entry of weight 0 has no effect: any value there (NaN too) gives the same fit."""
    X = torch.as_tensor(clean)
    w = torch.ones(X.shape[:2])
    w[10:20, LEGS] = 0
    R0 = torch.eye(3).expand(X.shape[0], 22, 3, 3).clone()
    b0 = torch.zeros(bm.num_betas)
    cfg = RefineConfig(max_steps=5)
    wrong = X.clone()
    wrong[10:20, LEGS] += 0.5
    nan = X.clone()
    nan[10:20, LEGS] = float("nan")
    out = [refine(bm, t, R0, b0, cfg, transl_init=X[:, 0].clone(), target_weights=w) for t in (wrong, nan)]
    assert torch.isfinite(out[0][0]).all()
    torch.testing.assert_close(out[0][0], out[1][0])
    torch.testing.assert_close(out[0][1], out[1][1])


def test_fit_observed_without_priors_fits_the_interpolated_gaps(bm, clean):
    occluded = clean.copy()
    occluded[12:24][:, LEGS] = np.nan
    fit = fit_observed(occluded, bm, None, config=RefineConfig(max_steps=20))
    assert np.isfinite(fit.joints).all()
    ref = fit_joints(fill_linear(occluded)[0], bm, None, config=RefineConfig(max_steps=20))
    np.testing.assert_allclose(fit.joints, ref.joints)          # the gaps filled linearly, then today's fit
    # MPJPE counts the observed joints only, so it is the fit's error there, not at the gaps
    d = np.linalg.norm(fit.joints - clean, axis=-1)
    seen = np.isfinite(occluded).all(-1)
    assert fit.mpjpe == pytest.approx(d[seen].mean(), rel=1e-5)
    # the legs at the gaps came from interpolation: off the true motion, but within a limb
    assert 0.0 < d[12:24][:, LEGS].mean() < 0.3


def test_fit_cli_with_missing_joints_writes_a_finite_fit(tmp_path, bm, clean):
    occluded = clean.copy()
    occluded[5:15][:, LEGS] = np.nan
    src = tmp_path / "occluded.npz"
    np.savez(src, joints=occluded, fps=30.0)
    fit_main([f"input={src}", f"out={tmp_path / 'o'}", "mlp=none", "mesh=false", f"body.model_path={bm.path}"])
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["missing_joints"] == 10 * len(LEGS)
    with np.load(tmp_path / "o" / "params.npz") as z:
        assert np.isfinite(z["joints"]).all() and np.isfinite(z["poses"]).all()
    assert np.isfinite(report["samples"][0]["mpjpe_cm"])


def test_fit_cli_refuses_bad_prior_keys(tmp_path, capsys, clean, bm):
    src = tmp_path / "in.npz"
    np.savez(src, joints=clean)
    base = [f"input={src}", f"out={tmp_path / 'o'}", "mlp=none", f"body.model_path={bm.path}"]
    assert "motion_prior.w_smooth" in user_error(capsys, fit_main, base + ["motion_prior.w_smooth=-1"])
    assert "prior_missing.pt" in user_error(capsys, fit_main, base + [f"motion_prior.smooth={tmp_path / 'prior_missing.pt'}"])
    assert "unknown key" in user_error(capsys, fit_main, base + ["motion_prior.bogus=1"])
    assert not (tmp_path / "o").exists()


def test_motion_prior_config_checks():
    with pytest.raises(ConfigError):
        MotionPriorConfig(steps=-1).check()
    assert not MotionPriorConfig().any and MotionPriorConfig(infill="x").any


def _tiny_prior(path, kind: str, num_markers: int, seed: int = 0):
    """An untrained prior with tiny channels, saved like `train-motion-prior` saves one."""
    from motiongen.capture.markers import MIRROR
    from motiongen.capture.motion_prior import MotionPrior, PriorNetConfig, save_prior

    torch.manual_seed(seed)
    pairs = [(m, int(MIRROR[m])) for m in range(num_markers) if MIRROR[m] > m]
    left, right = [a for a, _ in pairs], [b for _, b in pairs]
    prior = MotionPrior(PriorNetConfig(kind=kind, channels=[4, 8] if kind == "smooth" else [4, 8, 8, 8, 8]),
                        num_markers, left, right, window=16)
    return save_prior(path, prior)


@pytest.fixture(scope="module")
def priors(tmp_path_factory):
    d = tmp_path_factory.mktemp("priors")
    return _tiny_prior(d / "smooth.pt", "smooth", 81), _tiny_prior(d / "infill.pt", "infill", 67)


def test_smoothness_prior_stage_keeps_the_fit_and_lowers_the_latent_term(bm, clean, priors):
    """Stage 2 starts from today's fit and minimises joint error + w · latent change: its
    latent term ends no higher than where it started, and the joints stay near the target."""
    from motiongen.capture.prior_fit import PriorTerms, _rotmats

    noisy = clean + np.random.default_rng(0).normal(0, 0.02, clean.shape).astype(np.float32)
    cfg = RefineConfig(max_steps=15)
    base = fit_observed(noisy, bm, None, config=cfg)
    mp = MotionPriorConfig(smooth=str(priors[0]), w_smooth=1e-2, steps=15)
    terms = PriorTerms(bm, mp)
    fit = fit_observed(noisy, bm, None, config=cfg, priors=mp, terms=terms)
    term = terms.smooth_term()

    def value(f):
        with torch.no_grad():
            return float(term(_rotmats(f, torch.float32, "cpu"), torch.as_tensor(f.transl), torch.as_tensor(f.betas)))
    assert value(fit) < value(base)
    assert np.isfinite(fit.joints).all() and fit.mpjpe < 0.05
    assert fit.steps > base.steps


def test_infilling_stage_fills_only_missing_joints_and_never_reads_nan(bm, clean, priors):
    occluded = clean.copy()
    occluded[10:30][:, LEGS] = np.nan
    mp = MotionPriorConfig(smooth=str(priors[0]), infill=str(priors[1]), steps=5)
    fit = fit_observed(occluded, bm, None, config=RefineConfig(max_steps=10), priors=mp)
    assert np.isfinite(fit.joints).all() and np.isfinite(fit.body_pose).all()
    seen = np.isfinite(occluded).all(-1)
    assert np.linalg.norm(fit.joints - clean, axis=-1)[seen].mean() < 0.05   # observed joints still fitted


def test_infill_targets_keep_observed_markers(bm, clean, priors):
    from motiongen.capture.prior_fit import PriorTerms, _rotmats

    terms = PriorTerms(bm, MotionPriorConfig(infill=str(priors[1])))
    f = fit_joints(clean, bm, None, config=RefineConfig(max_steps=5))
    R = _rotmats(f, torch.float32, "cpu")
    obs = torch.ones(clean.shape[:2], dtype=torch.bool)
    obs[5:15, LEGS] = False
    target, missing = terms.infill_targets(R, torch.as_tensor(f.transl), torch.as_tensor(f.betas), obs)
    posed = terms.markers(R, torch.as_tensor(f.transl), torch.as_tensor(f.betas), 67)
    assert missing[5:15].any() and not missing[:5].any() and not missing[15:].any()
    torch.testing.assert_close(target[~missing], posed[~missing])           # observed markers given back as they are
    assert torch.isfinite(target).all()


def test_fit_cli_uses_the_priors_and_refuses_the_wrong_kind(tmp_path, capsys, bm, clean, priors):
    occluded = clean.copy()
    occluded[8:20][:, LEGS] = np.nan
    src = tmp_path / "occ.npz"
    np.savez(src, joints=occluded)
    base = [f"input={src}", "mlp=none", "mesh=false", f"body.model_path={bm.path}", "steps=5", "motion_prior.steps=3"]
    fit_main(base + [f"out={tmp_path / 'o'}", f"motion_prior.smooth={priors[0]}", f"motion_prior.infill={priors[1]}"])
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["motion_prior"]["infill"] == str(priors[1]) and report["missing_joints"] == 12 * len(LEGS)
    err = user_error(capsys, fit_main, base + [f"out={tmp_path / 'x'}", f"motion_prior.smooth={priors[1]}"])
    assert "a prior of kind infill, expected kind smooth" in err
    assert not (tmp_path / "x").exists()


def test_fit_multiview_with_motion_priors(tmp_path, priors):
    """`fit-multiview motion_prior.*=...`: the smoothness prior's term in stages 2 and 3 and the
    infilling prior's in stage 3, logged; the joints still fit the cameras' 2D keypoints."""
    from capture_rig import make_rig                   # tests/ is on sys.path under pytest
    from test_capture_multiview import write_rig
    from motiongen.body.model import load_body_model
    from motiongen.capture.fit_multiview import main as mv_main

    bm = load_body_model()
    rig = make_rig(bm, T=20, cameras=4, noise_px=1.0, drop=0.1, seed=5)
    cams, kp = write_rig(tmp_path, rig, "smplx22")
    out = tmp_path / "fit"
    mv_main([f"cameras={cams}", f"keypoints2d={kp}", f"out={out}", "steps1=20", "steps2=10", "steps3=10",
             f"motion_prior.smooth={priors[0]}", f"motion_prior.infill={priors[1]}", "tensorboard=false"])
    report = json.loads((out / "report.json").read_text())
    losses = report["stage_losses"]
    assert "Lprior" not in losses["stage1"] and losses["stage2"]["Lprior"] >= 0
    assert "Linfill" in losses["stage3"] and "Linfill" not in losses["stage2"]
    assert report["config"]["motion_prior.smooth"] == str(priors[0])
    err = np.linalg.norm(np.load(out / "params.npz")["joints"] - rig.joints, axis=-1)
    assert err.mean() < 0.05
