"""Window features: root-relative layout, stance channels, and what pinning the pelvis does."""

import numpy as np
import pytest
import torch

from motiongen.data.representation import Layout, stance_labels
from motiongen.errors import ConfigError
from motiongen.skeleton import BODY, FOOT_JOINTS
from tests.helpers import REST, walking_sequence


def _window():
    return walking_sequence(16, [0.0, 0.0], 0.3, 0.2, 1.0).astype(np.float64)          # (16, 22, 3)


@pytest.mark.parametrize("rep", ["root", "absolute"])
def test_encode_decode_round_trip(rep):
    layout = Layout(22, rep, FOOT_JOINTS)
    j = _window()
    stance = np.random.default_rng(0).random((16, 4)) > 0.5
    x = layout.encode(j, stance)
    assert x.shape == (16, 66 + 4) and layout.channels == 70
    back, st = layout.decode(x)
    np.testing.assert_allclose(back, j, atol=1e-12)
    assert np.array_equal(st, stance)
    # torch in, torch out, same numbers
    xt = layout.encode(torch.as_tensor(j), torch.as_tensor(stance))
    np.testing.assert_allclose(xt.numpy(), x)


def test_root_channels_hold_offsets_from_the_pelvis():
    x = Layout(22, "root").encode(_window())
    j = _window()
    np.testing.assert_allclose(x[:, :3], j[:, 0])                                     # pelvis as is
    np.testing.assert_allclose(x[:, 3:6], j[:, 1] - j[:, 0])                          # left hip from the pelvis


def test_moving_the_pelvis_moves_the_whole_body_in_root_layout():
    """What a goal does to a window: shifting the pelvis channels of the last frame by 1 m."""
    j = _window()
    for rep, whole_body in (("root", True), ("absolute", False)):
        layout = Layout(22, rep)
        x = layout.encode(j)
        x[-1, [0, 2]] += 1.0
        moved, _ = layout.decode(x)
        d = np.linalg.norm(moved[-1] - j[-1], axis=-1)                                 # (22,)
        if whole_body:
            np.testing.assert_allclose(d, 1.0 * np.sqrt(2), atol=1e-12)                # every joint, rigidly
        else:
            assert d[0] == pytest.approx(np.sqrt(2)) and np.all(d[1:] == 0)           # the pelvis alone


def test_layout_for_window_checks_names():
    from motiongen.data.windows import WindowConfig

    assert Layout.for_window(WindowConfig(), BODY).contact_joints == FOOT_JOINTS
    assert Layout.for_window(WindowConfig(contact_joints=()), BODY).channels == 66
    with pytest.raises(ConfigError, match="not in the joint set"):
        Layout.for_window(WindowConfig(contact_joints=("left_hoof",)), BODY)
    with pytest.raises(ConfigError, match="representation"):
        Layout(22, "quaternions")


def test_stance_is_contact_and_still():
    T = 30
    j = np.repeat(REST[None].astype(np.float64), T, 0)
    j[15:, 10, 0] += 0.5 * np.arange(T - 15) / 30.0                 # left toe slides at 0.5 m/s from frame 15
    contact = np.zeros((T, 22), bool)
    contact[:, 10] = True                                             # labelled in contact throughout
    contact[:20, 11] = True                                           # right toe: contact ends at 20
    st = stance_labels(j, contact, (10, 11), 30.0, stance_speed=0.2)
    assert st[:14, 0].all() and not st[16:, 0].any()                  # sliding is not stance
    assert st[:20, 1].all() and not st[20:, 1].any()                  # no contact, no stance
