"""One episode's window put on the motion's body: the seam's velocity jump faded out, every
frame projected onto the one body (`motiongen.body.solve.MotionBody`: bone lengths are the
body's whatever the network predicted), the pinned frames restored exactly. The next episode
then continues from a rigid body."""

from __future__ import annotations

import numpy as np
import torch

from motiongen.sampling.assemble import blend_seam
from motiongen.sampling.episode import Tail


def project_window(raw: np.ndarray, stance: np.ndarray, tail: Tail | None, pinned: int, blend_frames: int,
                   body) -> tuple[np.ndarray, np.ndarray, torch.Tensor | None]:
    """raw (S, L, J, 3) world joints as the network predicted them, stance (S, L, C) bool, the
    previous tail, `pinned` frames, body a MotionBody or None (no projection) ->
    (world (S, L, J, 3), stance (S, L, C), rotations (S, L, 22, 3, 3) or None). `stance` is
    updated in place."""
    # The network's joints stay in `raw`; the clean-up starts with the seam (a second
    # difference, so blending in the world frame equals blending in the window's).
    world = blend_seam(raw, pinned, blend_frames)
    rot = None
    if body is not None:
        world, rot, _ = body.project(world, None if tail is None or tail.rot is None else tail.rot[:, -1])
    if pinned:
        # The pinned frames come back as the previous frames up to float32 rounding of the
        # normalised values; keep the exact originals so seams carry no rounding jitter.
        world = world.copy()
        world[:, :pinned], stance[:, :pinned] = tail.joints, tail.stance
        if rot is not None:
            rot[:, :pinned] = tail.rot
    return world, stance, rot
