"""One episode's window put on the motion's body: the seam's velocity jump faded out, the
network's skeleton scaled to the body's size, every frame projected onto the one body
(`motiongen.body.solve.MotionBody`: bone lengths are the body's whatever the network
predicted), the pinned frames restored exactly. The next episode then continues from a rigid
body."""

from __future__ import annotations

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d

from motiongen.metrics import bone_lengths
from motiongen.sampling.assemble import blend_seam
from motiongen.sampling.episode import Tail
from motiongen.skeleton import NUM_BODY_JOINTS, PELVIS

# Frames (model rate) over which the network's per-frame size is smoothed before scaling: its
# bone lengths jitter from frame to frame (within-window CV ~0.015), its size drifts slowly.
SIZE_SMOOTHING = 2.0


def body_size_ratio(world: np.ndarray, body) -> np.ndarray:
    """(S, L, J, 3) joints, a MotionBody -> (S, L) the body's summed bone length over the
    network's, per frame, smoothed over SIZE_SMOOTHING frames: > 1 where the network's skeleton
    is smaller than the body."""
    parents = body.bm.parents
    S, L = world.shape[:2]
    net = bone_lengths(world[:, :, :NUM_BODY_JOINTS].reshape(S * L, NUM_BODY_JOINTS, 3), parents)
    net = net.sum(-1).reshape(S, L)                                                           # (S, L)
    own = bone_lengths(body.rest.double().numpy(), parents).sum(-1)                          # (S,)
    return gaussian_filter1d(own[:, None] / np.maximum(net, 1e-6), SIZE_SMOOTHING, axis=1, mode="nearest")


def scale_to_body(world: np.ndarray, body) -> np.ndarray:
    """(S, L, J, 3) -> the same frames with each frame's skeleton scaled by `body_size_ratio`
    about the point on the floor (y = 0) below its pelvis: the pelvis keeps its path over the
    floor and the feet their floor contact, the pelvis height and the limbs' reach grow with
    the size. Without it the projection, which keeps the pelvis where the network put it and
    the feet on the network's, bends the body's longer legs under a smaller network skeleton,
    and the next episode continues from that crouch (docs/results.md, "The quality network's
    body drifts smaller, and the output crouches")."""
    s = body_size_ratio(world, body)[..., None, None]                                         # (S, L, 1, 1)
    centre = world[:, :, PELVIS:PELVIS + 1].copy()                                            # (S, L, 1, 3)
    centre[..., 1] = 0.0
    return centre + s * (world - centre)


def project_window(raw: np.ndarray, stance: np.ndarray, tail: Tail | None, pinned: int, blend_frames: int,
                   body, scale: bool = True) -> tuple[np.ndarray, np.ndarray, torch.Tensor | None]:
    """raw (S, L, J, 3) world joints as the network predicted them, stance (S, L, C) bool, the
    previous tail, `pinned` frames, body a MotionBody or None (no projection), scale: the
    network's skeleton scaled to the body's size first (`scale_to_body`) ->
    (world (S, L, J, 3), stance (S, L, C), rotations (S, L, 22, 3, 3) or None). `stance` is
    updated in place."""
    # The network's joints stay in `raw`; the clean-up starts with the seam (a second
    # difference, so blending in the world frame equals blending in the window's).
    world = blend_seam(raw, pinned, blend_frames)
    rot = None
    if body is not None:
        if scale:
            world = scale_to_body(world, body)
        world, rot, _ = body.project(world, None if tail is None or tail.rot is None else tail.rot[:, -1])
    if pinned:
        # The pinned frames come back as the previous frames up to float32 rounding of the
        # normalised values; keep the exact originals so seams carry no rounding jitter.
        world = world.copy()
        world[:, :pinned], stance[:, :pinned] = tail.joints, tail.stance
        if rot is not None:
            rot[:, :pinned] = tail.rot
    return world, stance, rot
