"""The state of one `generate` call between its episodes, and the bookkeeping after each.

* `LoopSpec`: what every episode of the call shares, fixed before the first (window size,
  pinned frames, model rate, reach, the sampler and its noise generator).
* `EpisodeState`: what the episodes have produced so far: the kept frames, the `Tail` the next
  episode pins, and the motion's body (fitted to the first window).
* `Window`: one episode's window once it is on the body; `record_episode` keeps it.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import torch

from motiongen.body.solve import MotionBody
from motiongen.errors import ConfigError
from motiongen.geometry import local_to_world
from motiongen.sampling.goals import Route
from motiongen.sampling.settings import Episode, LoopConfig, SamplerSettings, resolve_sampler
from motiongen.skeleton import PELVIS


def model_reach(stats, cfg: LoopConfig) -> float:
    """How far (m) an episode may pin its target: reach_fraction x the largest forward pelvis
    offset in the training windows (pelvis z channel max; windows start facing +z)."""
    if cfg.reach is not None:
        return float(cfg.reach)
    forward = float(stats.center[2] + stats.half_range[2])
    return max(0.05, cfg.reach_fraction * forward)


def pelvis_xz(x: np.ndarray) -> np.ndarray:
    """(..., J, 3) joints -> (..., 2) pelvis x, z."""
    return x[..., PELVIS, :][..., [0, 2]]


@dataclass(frozen=True)
class LoopSpec:
    """What every episode of one `generate` call shares."""

    samples: int                   # S, sampled together in one batch
    length: int                    # L frames per model window
    channels: int                  # D features per frame (loaded.layout.channels)
    transition: int                # k frames pinned from the previous episode
    model_fps: float               # the model's frame rate: data fps / window stride
    reach: float                   # m: farther targets are clamped (`model_reach`)
    predict_goal: bool             # the network predicts the goal entries (else they are written in)
    blend_frames: int              # free frames over which the seam's velocity jump fades
    body_scale: bool               # each window's skeleton scaled to the body's before projection
    start_frame: np.ndarray        # (4, 4) local -> world of the first window: the start pose
    device: torch.device           # the network's
    sampler: SamplerSettings
    generator: torch.Generator | None   # the diffusion noise's (reproducible runs)
    facing_goal: bool = False      # the network is asked to face the object in a hand action's own episodes
    facing_on_arrival: bool = False  # ... and in the episode that walks onto its spot


def loop_spec(loaded, route: Route, num_samples: int, loop: LoopConfig, start_yaw: float | None,
              sampler: SamplerSettings, generator: torch.Generator | None) -> LoopSpec:
    """The `LoopSpec` of a call; raises ConfigError for a transition the window cannot hold or
    sampler settings the checkpoint cannot run (`resolve_sampler`: a distilled student's step
    count) and warns when it pins more frames than the checkpoint was trained with."""
    sampler = resolve_sampler(sampler, loaded)
    L, most = loaded.window.length, loaded.mask.max_transition
    k = loop.transition if loop.transition is not None else int(most)
    if not 1 <= k < L:
        raise ConfigError(f"transition frames must be in 1..{L - 1} (checkpoint trained with up to "
                          f"{most}); got {k}")
    if k > most:
        warnings.warn(f"pinning {k} transition frames; the model was trained with at most {most}")
    # The checkpoint's own rate unless the caller names the data's rate (evaluation does).
    model_fps = loaded.model_fps if loop.source_fps is None else float(loop.source_fps) / loaded.window.stride
    blend_s = LoopConfig.seam_blend if loop.seam_blend is None else float(loop.seam_blend)
    return LoopSpec(num_samples, L, loaded.layout.channels, k, model_fps, model_reach(loaded.stats, loop),
                    loaded.predict_goal and not loop.pin_goal, round(blend_s * model_fps), loop.body_scale,
                    start_frame(route, start_yaw), next(loaded.model.parameters()).device, sampler, generator,
                    loop.facing_goal and loaded.mask.p_facing > 0, loop.facing_on_arrival)


def start_frame(route: Route, start_yaw: float | None) -> np.ndarray:
    """(4, 4) the start pose: at the route's start, facing `start_yaw` (None: the first subgoal)."""
    if start_yaw is None:
        d = route.subgoals[0] - route.start
        start_yaw = math.atan2(d[0], d[1]) if np.linalg.norm(d) > 1e-6 else 0.0
    return local_to_world(np.float64(start_yaw), np.asarray(route.start, np.float64))


@dataclass
class Tail:
    """The last k frames so far: what the next episode pins."""

    joints: np.ndarray             # (S, k, J, 3) float64 world
    stance: np.ndarray             # (S, k, C) bool predicted planted flags
    labels: np.ndarray             # (S, k) int action index per frame
    rot: torch.Tensor | None       # (S, k, 22, 3, 3) local rotations on the body; None without one


@dataclass
class Window:
    """One episode's window on the body, world frame."""

    pinned: int                    # frames 0..pinned-1 are the previous episode's (0: the first)
    to_world: np.ndarray           # (S, 4, 4) the window's local -> world frame
    raw: np.ndarray                # (S, L, J, 3) float64 as the network predicted them
    world: np.ndarray              # (S, L, J, 3) float64 seam-blended, projected, pinned frames exact
    stance: np.ndarray             # (S, L, C) bool
    rot: torch.Tensor | None       # (S, L, 22, 3, 3), None without a body
    labels: np.ndarray             # (S, L) int action index per frame


@dataclass
class EpisodeState:
    """What the episodes have produced so far (kept frames only, at the model rate)."""

    tail: Tail | None = None       # None before the first episode
    body: MotionBody | None = None  # the motion's body, fitted to the first window (loop.project)
    frames: list[np.ndarray] = field(default_factory=list)    # each (S, n, J, 3) float64 world
    raws: list[np.ndarray] = field(default_factory=list)      # the same frames as the network predicted them
    stances: list[np.ndarray] = field(default_factory=list)   # each (S, n, C) bool
    rots: list[torch.Tensor] = field(default_factory=list)    # each (S, n, 22, 3, 3) on the body
    labels: list[np.ndarray] = field(default_factory=list)    # each (S, n) int action index
    n_frames: int = 0              # model frames kept so far
    episodes: list[Episode] = field(default_factory=list)

    def pelvis_now(self) -> np.ndarray:
        """(S, 2) pelvis x, z at the last frame so far."""
        return pelvis_xz(self.tail.joints[:, -1])


def record_episode(state: EpisodeState, spec: LoopSpec, kind: str, target: np.ndarray, w: Window) -> None:
    """Keep a window's new frames (from `w.pinned` on) and its last k as the next tail."""
    L, k, p = spec.length, spec.transition, w.pinned
    state.episodes.append(Episode(kind, state.n_frames, p, target.copy(), w.world.astype(np.float32), w.to_world,
                                  w.raw.astype(np.float32)))
    state.frames.append(w.world[:, p:])
    state.raws.append(w.raw[:, p:])
    state.stances.append(w.stance[:, p:])
    if w.rot is not None:
        state.rots.append(w.rot[:, p:])
    state.labels.append(w.labels[:, p:])
    state.n_frames += L - p
    state.tail = Tail(w.world[:, L - k:], w.stance[:, L - k:], w.labels[:, L - k:],
                      None if w.rot is None else w.rot[:, L - k:])


def drop_warmup(state: EpisodeState, k: int) -> None:
    """Forget the warm-up frames but the last k: the history the first goal episode pins."""
    t = state.tail
    state.frames, state.raws, state.labels = [t.joints.copy()], [state.raws[-1][:, -k:].copy()], [t.labels.copy()]
    state.stances, state.rots = [t.stance.copy()], ([t.rot.clone()] if t.rot is not None else [])
    state.n_frames = k
    state.episodes[-1].start = 0
