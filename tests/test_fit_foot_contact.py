"""LEMO's foot-contact velocity term in joints -> SMPL-X fitting: closed-form values, what it
does to a sliding foot, and the fit CLI's keys."""

import json

import numpy as np
import pytest
import torch

from motiongen.body.fit import RefineConfig, fit_joints, refine
from motiongen.body.foot_velocity import foot_velocity_loss, foot_velocity_mask
from motiongen.body.random_motion import sample_motion
from motiongen.errors import ConfigError
from motiongen.commands.fit_command import main
from motiongen.skeleton import FOOT_JOINTS
from tests.helpers import user_error

A = 0.10                                              # LEMO's a, m/s
LEFT = FOOT_JOINTS[:2]                                # left ankle, left toe


@pytest.fixture(scope="module")
def sliding(bm):
    """A body standing still (toes 2 cm up) whose left foot target slides 10 cm along x over
    frames 8..18 (0.3 m/s, 3a) while on the floor: (target (T, 22, 3), T)."""
    p = {k: torch.as_tensor(v) for k, v in sample_motion(1, rng=np.random.default_rng(4)).items()}
    with torch.no_grad():
        X = bm.joints(p["global_orient"], p["body_pose"], p["transl"], p["betas"]).numpy()
    T = 30
    X = np.repeat(X, T, 0)
    X[..., 1] += 0.02 - X[..., 1].min()
    target = X.copy()
    target[:, list(LEFT), 0] += (np.clip((np.arange(T) - 8) / 10, 0, 1) * 0.10)[:, None]
    return target


def _speed(J, joints=LEFT):
    return np.linalg.norm(np.diff(J[:, list(joints)], axis=0), axis=-1) * 30            # (T-1, K) m/s


def test_loss_is_the_seeds_hinge_over_masked_feet():
    T = 5
    J = torch.zeros(T, 22, 3)
    toe = FOOT_JOINTS[1]
    J[:, toe, 0] = torch.arange(T) * 0.01                      # 0.3 m/s along x
    J[:, FOOT_JOINTS[2], 1] = torch.arange(T) * 0.002          # 0.06 m/s upwards: below a
    mask = torch.ones(T, 4, dtype=torch.bool)
    # Σ (0.3 - 0.1) over the 4 transitions of the toe, divided by (T-1)·K = 16
    assert foot_velocity_loss(J, mask, FOOT_JOINTS, 30.0, A).item() == pytest.approx(4 * 0.2 / 16, rel=1e-5)
    mask[2:, 1] = False                                        # only frames 0, 1 (frame T-1 has no step)
    assert foot_velocity_loss(J, mask, FOOT_JOINTS, 30.0, A).item() == pytest.approx(2 * 0.2 / 16, rel=1e-5)
    assert foot_velocity_loss(J, mask, FOOT_JOINTS, 30.0, 0.5).item() == 0.0
    # 3-D speed: the same motion along y costs the same
    Jy = torch.zeros(T, 22, 3)
    Jy[:, toe, 1] = torch.arange(T) * 0.01
    assert foot_velocity_loss(Jy, torch.ones(T, 4, dtype=torch.bool), FOOT_JOINTS, 30.0, A).item() == \
        pytest.approx(0.05, rel=1e-5)
    # gradient only on the masked, moving foot joint
    Jg = J.clone().requires_grad_(True)
    foot_velocity_loss(Jg, mask, FOOT_JOINTS, 30.0, A).backward()
    moving = torch.zeros(22, dtype=torch.bool)
    moving[toe] = True
    assert Jg.grad[:, ~moving].abs().max() == 0
    # d/dx of (fps·(x1 − x0) − a) + (fps·(x2 − x1) − a), over 16: −fps/16, 0, +fps/16, then nothing
    np.testing.assert_allclose(Jg.grad[:, toe, 0].numpy(), [-30 / 16, 0, 30 / 16, 0, 0], atol=1e-5)


def test_height_mask_measures_from_the_floor():
    X = torch.zeros(3, 22, 3)
    X[:, list(FOOT_JOINTS), 1] = torch.tensor([0.05, 0.10, 0.15, 0.30])
    np.testing.assert_array_equal(foot_velocity_mask(X, FOOT_JOINTS, 0.0, 0.10)[0], [True, True, False, False])
    np.testing.assert_array_equal(foot_velocity_mask(X, FOOT_JOINTS, 0.1, 0.10)[0], [True, True, True, False])


def test_term_holds_a_sliding_foot_to_a(bm, sliding):
    free = fit_joints(sliding, bm, None, fps=30.0)
    held = fit_joints(sliding, bm, None, config=RefineConfig(w_foot_vel=0.1), fps=30.0)
    assert _speed(free.joints).max() > 2.5 * A                                        # follows the slide
    assert _speed(held.joints).max() < 1.1 * A                                        # held to a
    # the foot still goes most of the way, as far as a allows: it starts earlier and ends
    # later, at most 29 steps of a / 30 fps = 9.7 cm
    assert 0.08 < held.joints[-1, LEFT[1], 0] - held.joints[0, LEFT[1], 0] < 0.1
    assert held.mpjpe < 0.01 and held.steps > free.steps


def test_contact_labels_pick_the_frames(bm, sliding):
    T = len(sliding)
    contact = np.zeros((T, 4), bool)
    contact[4:14, :2] = True                                  # the left foot, the slide's first half
    held = fit_joints(sliding, bm, None, contact=contact, config=RefineConfig(w_foot_vel=0.1, foot_vel_mask="contact"),
                      fps=30.0)
    v = _speed(held.joints)
    assert v[4:13].max() < 1.1 * A and v[14:].max() > 2 * A                            # labelled frames only
    # far above the floor, the height mask selects nothing: the foot slides
    high = fit_joints(sliding, bm, None, config=RefineConfig(w_foot_vel=0.1, floor_y=-1.0), fps=30.0)
    assert _speed(high.joints).max() > 2.5 * A


def test_bad_settings_are_config_errors(bm, sliding):
    X = torch.as_tensor(sliding[:5])
    R = torch.eye(3).expand(5, 22, 3, 3)
    with pytest.raises(ConfigError, match="contact flags"):
        refine(bm, X, R, torch.zeros(10), RefineConfig(w_foot_vel=1.0, foot_vel_mask="contact", max_steps=1))
    with pytest.raises(ConfigError, match="expected one of"):
        fit_joints(sliding[:5], bm, None, config=RefineConfig(w_foot_vel=1.0, foot_vel_mask="speed"))
    with pytest.raises(ConfigError, match=r"\(5, 4\)"):
        fit_joints(sliding[:5], bm, None, contact=np.ones((5, 2), bool),
                   config=RefineConfig(w_foot_vel=1.0, foot_vel_mask="contact"))


def test_fit_cli_foot_velocity_keys(tmp_path, capsys, sliding):
    T = len(sliding)
    contact = np.zeros((T, 22), bool)
    contact[4:14, list(LEFT)] = True
    src = tmp_path / "motion.npz"
    np.savez(src, joints=sliding, contact=contact, fps=np.array(30.0))
    out = tmp_path / "fit"
    main([f"input={src}", f"out={out}", "mlp=none", "mesh=false", "foot_vel.weight=0.1", "foot_vel.mask=contact"])
    report = json.loads((out / "report.json").read_text())
    assert report["foot_velocity"] == {"weight": 0.1, "a": 0.1, "z_thres": 0.1, "mask": "contact", "floor_y": 0.0}
    with np.load(out / "params.npz") as z:
        v = _speed(z["joints"])
    assert v[4:13].max() < 1.1 * A and v[14:].max() > 2 * A
    base = [f"out={tmp_path / 'o'}", "mlp=none", "mesh=false", "foot_vel.weight=0.1"]
    bare = tmp_path / "bare.npz"
    np.savez(bare, joints=sliding)
    assert "[contact]" in user_error(capsys, main, [f"input={bare}", "foot_vel.mask=contact"] + base)
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, joints=sliding, contact=np.zeros((T, 7), bool))
    assert "(30, 22)" in user_error(capsys, main, [f"input={wrong}", "foot_vel.mask=contact"] + base)
    assert "height or contact" in user_error(capsys, main, [f"input={bare}", "foot_vel.mask=speed"] + base)
    assert ">= 0" in user_error(capsys, main, [f"input={bare}", "foot_vel.a=-1"] + base)


def test_fit_cli_takes_contact_labels_from_a_dataset_sequence(tmp_path, sliding):
    """Labels in a dataset's contact.npy (written by `capture.contact_sensors` in use) pick the
    frames through `input=DATASET seq=NAME foot_vel.mask=contact`."""
    from motiongen.data.dataset_writer import DatasetWriter
    from motiongen.skeleton import BODY

    T = len(sliding)
    contact = np.zeros((T, 22), bool)
    contact[4:14, list(LEFT)] = True
    w = DatasetWriter(tmp_path / "ds", BODY, [], 30.0)
    w.add_scene(0)
    w.add_sequence("slide", 0, sliding.astype(np.float32), np.zeros((T, 0), bool), contact)
    w.finish()
    out = tmp_path / "fit"
    main([f"input={tmp_path / 'ds'}", "seq=slide", f"out={out}", "mlp=none", "mesh=false", "foot_vel.weight=0.1",
          "foot_vel.mask=contact"])
    with np.load(out / "params.npz") as z:
        v = _speed(z["joints"])
    assert v[4:13].max() < 1.1 * A and v[14:].max() > 2 * A
