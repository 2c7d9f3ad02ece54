"""The sampler's facing goal: towards the hand goal from the pelvis goal, in the window frame."""

import numpy as np

from motiongen.geometry import invert_rigid, local_to_world
from motiongen.sampling.conditioning import facing_values


def test_facing_points_from_the_pelvis_goal_to_the_hand_goal_in_the_window_frame():
    """Three samples whose windows face +z, +x and +z. Sample 0's object lies 0.4 m along +x of
    its pelvis goal (0, 1): it faces yaw 90 degrees, (sin, cos) = (1, 0). Sample 1's window is
    turned 90 degrees, and its pelvis goal (-1, 0) in that frame is the same world point: the same
    world direction is straight ahead in its frame, (0, 1). Sample 2 has
    no hand goal and is given no facing; a hand goal 5 cm across the floor from the pelvis goal
    (straight above it) gives none either."""
    to_world = local_to_world(np.array([0.0, np.pi / 2, 0.0]), np.zeros((3, 2)))          # (3, 4, 4)
    inv = invert_rigid(to_world)
    local_t = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, 0.0]])                              # pelvis goals, window frames
    point = np.array([[0.4, 0.8, 1.0], [0.4, 0.8, 1.0], [5.0, 0.8, 5.0]])                  # world wrist goals
    facing, given = facing_values(inv, local_t, np.array([21, 20, -1]), point)
    assert given.tolist() == [True, True, False]
    np.testing.assert_allclose(facing[:2], [[1.0, 0.0], [0.0, 1.0]], atol=1e-6)
    assert not facing[2].any()
    near = np.array([[0.05, 0.8, 1.0], [0.0, 0.8, 1.0], [0.0, 0.8, 0.0]])
    assert not facing_values(inv, local_t, np.array([21, 20, 20]), near)[1][0]
