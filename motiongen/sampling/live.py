"""Live generation: one body moving through goals that arrive while it moves (`motiongen serve`).

The episodes are `generate`'s (`autoregressive.run_episode`: condition, denoise, project onto
the body), for one sample, with the goal list left open: goals are appended or cleared between
episodes, and a change of where the body heads next throws the generated but not yet played
future away (`rollback`), so the motion answers within a fraction of a second rather than after
the buffered episodes have played. The goal state machine is `progress`'s, replanned from the
body's position whenever the list changes.

Output frames are the projected model frames resampled to `out_fps` (pelvis linearly, joint
rotations by slerp) and posed by the body's forward kinematics, so that the joints and the
rotations a viewer skins with agree exactly. `generate`'s whole-motion clean-up (smoothing, foot
lock, final solve) needs the whole motion and is not applied: what plays is each episode on the
body.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from motiongen.body.solve import MotionBody
from motiongen.errors import ConfigError
from motiongen.routing import WalkableMap
from motiongen.sampling.autoregressive import run_episode
from motiongen.sampling.conditioning import loop_hand_reach
from motiongen.sampling.episode import EpisodeState, Tail, loop_spec
from motiongen.sampling.goals import Goal, Route, action_index, check_actions, plan_route
from motiongen.sampling.interactions import aim_at_objects, hand_goals
from motiongen.sampling.progress import Progress, Targets, advance, goal_plan, next_targets
from motiongen.sampling.scene_query import SceneQuery
from motiongen.sampling.settings import LoopConfig, SamplerSettings
from motiongen.skeleton import PELVIS


class Cancelled(Exception):
    """An episode stopped half-way because `LiveSampler.cancel` was set."""


@dataclass
class Rest:
    """What the body does with no goal left: stay at `xz` doing `label` (a seat's height, NaN: free)."""

    xz: np.ndarray                 # (2,) world pelvis target
    label: int
    height: float = float("nan")


@dataclass
class Reached:
    """A goal done (acted at) or given up (stalled), at model frame `frame`, and the rest after it."""

    goal: Goal
    frame: int
    rest: Rest
    stalled: bool = False


class Track:
    """Arrays sharing their first (frame) axis, appended to in amortised constant time (the
    capacity doubles). A view handed out (`track[name]`) is never written again: appends go past
    its end and a truncation starts a fresh copy, so another thread may go on reading it."""

    def __init__(self):
        self.n, self.data = 0, {}

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[name][:self.n]

    def append(self, **arrays: np.ndarray) -> None:
        k = len(next(iter(arrays.values())))
        for name, a in arrays.items():
            buf = self.data.get(name)
            if buf is None or self.n + k > len(buf):
                new = np.empty((max(64, 2 * (self.n + k)),) + a.shape[1:], a.dtype)
                if buf is not None:
                    new[:self.n] = buf[:self.n]
                self.data[name] = buf = new
            buf[self.n:self.n + k] = a
        self.n += k

    def truncate(self, n: int) -> None:
        for name, buf in self.data.items():
            new = np.empty_like(buf)
            new[:n] = buf[:n]
            self.data[name] = new
        self.n = n


class LiveSampler:
    """One body, generated one episode at a time towards an open list of goals.

        live = LiveSampler(loaded, grid, fmap, body_model=bm, start_xz=(0, 0))
        live.add_goals([Goal([1.0, 2.0])]); live.step(); live.frames_since(0)

    Not thread-safe: one thread calls it (`motiongen.serve.session` owns that thread)."""

    def __init__(self, loaded, scene=None, walkable: WalkableMap | None = None, objects=(), *, body_model,
                 start_xz=(0.0, 0.0), start_yaw: float = 0.0, sampler: SamplerSettings = SamplerSettings(),
                 loop: LoopConfig = LoopConfig(), generator: torch.Generator | None = None,
                 subgoal_spacing: float = 0.6, approach: float = 0.0):
        start = np.asarray(start_xz, np.float64)
        route = Route(start, [], [], np.zeros((0, 2)), np.zeros(0, np.int64))
        self.spec = loop_spec(loaded, route, 1, loop, start_yaw, sampler, generator)
        self.loaded, self.scene, self.walkable, self.loop = loaded, scene, walkable, loop
        self.spacing, self.body_model = float(subgoal_spacing), body_model
        self.objects, self.approach = list(objects), float(approach)     # hand actions come straight on (goals.approach_leg)
        self.query = SceneQuery(loaded, scene, objects, self.spec.device)
        self.reach = loop_hand_reach(loaded, objects, scene, loop)
        names = list(loaded.action_names)
        walk, idle = action_index(names, "walk"), action_index(names, "stand")
        self.idle_label = idle if idle >= 0 else walk
        self.state = EpisodeState()
        self.model_fps, self.out_fps = self.spec.model_fps, float(loop.out_fps)
        # Model-rate frames so far: world joints (n, J, 3), stance (n, C), labels (n,), rotations
        # (n, 22, 3, 3) and the same as quaternions x, y, z, w (n, 22, 4).
        self.model = Track()
        # Output-rate frames so far: root = pelvis (N, 3), quats x, y, z, w (N, 22, 4), joints (N, J, 3), labels (N,).
        self.out = Track()
        self.goals: list[Goal] = []
        self.reached: list[Reached] = []
        self.rest = Rest(start, self.idle_label)
        self.plan = self.progress = None
        self.episodes = 0
        # Another thread sets `cancel` to stop the episode being denoised (its frames are about to
        # be thrown away): checked before each network call, so it stops within one step.
        self.cancel = threading.Event()
        self._hook = loaded.model.register_forward_pre_hook(self._check_cancel)
        self.warmup_s = []                      # each warm-up episode's generation time (s)
        for _ in range(max(1, loop.warmup)):
            t = time.perf_counter()
            self._episode(Targets.stand(start, self.idle_label, 1))
            self.warmup_s.append(time.perf_counter() - t)

    def close(self) -> None:
        """Detach from the model (its cancel hook)."""
        self._hook.remove()

    def _check_cancel(self, module, args) -> None:
        self._stop_if_cancelled()

    def _stop_if_cancelled(self) -> None:
        if self.cancel.is_set():
            raise Cancelled()

    # ---- what a viewer reads -----------------------------------------------------------

    @property
    def num_frames(self) -> int:
        """Output frames generated so far."""
        return len(self.out)

    @property
    def body(self) -> MotionBody:
        return self.state.body

    def frames_since(self, start: int) -> dict:
        """Output frames start.. as arrays: root (n, 3), quats (n, 22, 4), joints (n, J, 3), labels (n,)."""
        return {name: self.out[name][start:] for name in ("root", "quats", "joints", "labels")}

    def pelvis_xz(self) -> np.ndarray:
        """(2,) the pelvis x, z at the last frame generated."""
        return self.model["joints"][-1, PELVIS, [0, 2]].copy()

    def route_points(self) -> np.ndarray:
        """(K, 2) the subgoals planned from the last frame generated through the pending goals."""
        return np.zeros((0, 2)) if self.plan is None else self.plan.subgoals.copy()

    # ---- goals ---------------------------------------------------------------------------

    def add_goals(self, goals: list[Goal]) -> None:
        """Append goals (their actions checked against the vocabulary, the route to them planned:
        ConfigError when either fails, and then nothing is added)."""
        goals = [Goal(g.xz, g.action, g.duration) for g in goals]
        check_actions(goals, self.loaded.action_names)
        self._replan(self.goals + goals, carry=True)

    def clear_goals(self) -> None:
        """Forget every pending goal; the body stops where it is now."""
        self.goals, self.plan, self.progress = [], None, None
        self.rest = Rest(self.pelvis_xz(), self.idle_label)

    def heads_to(self) -> Goal | None:
        """The goal the body is heading to (or acting at), None when it has none."""
        return self.goals[0] if self.goals else None

    # ---- generation ----------------------------------------------------------------------

    def step(self) -> int:
        """Generate one episode towards the goals; returns the output frames it added. Raises
        Cancelled, having changed nothing, when `cancel` is set before or while it runs."""
        n0 = self.num_frames
        if self.plan is None:
            t = Targets("idle", self.rest.xz[None].copy(), np.array([self.rest.label]),
                        height=np.array([self.rest.height]))
            self._episode(t)
        else:
            before = len(self.model)
            t = next_targets(self.progress, self.plan, self.pelvis_xz()[None])
            new = self._episode(t)
            advance(self.progress, self.plan, t, new[None], before, self.episodes)
            self._settle()
        return self.num_frames - n0

    def rollback(self, keep_out: int, replan: bool = True) -> int:
        """Forget the output frames from `keep_out` on (and the model frames they need), so that the
        next `step` continues from there; goals done in the forgotten frames are pending again.
        replan=False leaves the route to `replan` (or to the `add_goals` that follows).
        Returns the first output frame that will change (num_frames when nothing was forgotten)."""
        k = self.spec.transition
        # The fewest model frames whose output frames (`out_frames`) reach keep_out: output frame
        # keep_out - 1 lies at model time (keep_out - 1)·ρ and needs the model frame after it only
        # when that time is not a whole frame. Keeping more would put off the change by up to a
        # model frame (1/15 s at the recipes' rate), all of it click latency.
        keep = max(k, int(np.ceil((keep_out - 1) * self.model_fps / self.out_fps - 1e-9)) + 1)
        if keep >= len(self.model):
            return self.num_frames
        self.model.truncate(keep)
        m = self.model
        self.state.tail = Tail(m["joints"][None, -k:].copy(), m["stance"][None, -k:].copy(),
                               m["labels"][None, -k:].copy(), torch.from_numpy(m["rot"][None, -k:].copy()))
        n_out = self.out_frames(keep)
        self.out.truncate(n_out)
        back = [r for r in self.reached if r.frame >= keep]
        self.reached = [r for r in self.reached if r.frame < keep]
        if back:
            self.rest = self.reached[-1].rest if self.reached else Rest(self.model["joints"][0, PELVIS, [0, 2]],
                                                                        self.idle_label)
        self.goals, self.plan, self.progress = [r.goal for r in back] + self.goals, None, None
        if replan:
            self.replan()
        return n_out

    def replan(self) -> None:
        """Plan the route through the pending goals afresh from the last frame generated."""
        self._replan(self.goals, carry=False)

    # ---- internals -----------------------------------------------------------------------

    def _episode(self, t: Targets) -> np.ndarray:
        """Run one episode; keep its new model frames, extend the output. Returns them (n, J, 3)."""
        if self.reach is not None and self.state.tail is not None:
            t.hand, t.hand_point = hand_goals(self.reach, self.state.tail.joints, t.hand_labels())
        run_episode(self.spec, self.loaded, self.query, self.body_model, self.state, t, between=self._stop_if_cancelled)
        st = self.state
        new = st.frames[-1][0]
        rot = st.rots[-1][0].numpy()
        # Quaternions once per model frame: resampling reads each one for several output frames.
        self.model.append(joints=new, stance=st.stances[-1][0], labels=st.labels[-1][0], rot=rot, quat=_quats(rot))
        # The tracks are the record; the episode lists would only grow.
        for lst in (st.frames, st.raws, st.stances, st.rots, st.labels, st.episodes):
            lst.clear()
        self.episodes += 1
        self._extend_output()
        return new

    def _settle(self) -> None:
        """Pop the goals the state machine finished (acted at, or stalled at), then replan the rest."""
        p, plan = self.progress, self.plan
        G = len(plan.goals)
        n_done = G if p.finished[0] else int(p.leg[0])
        if n_done == 0:
            return
        frame = len(self.model)
        for g in range(n_done):
            last = g == G - 1
            label = plan.final_label if last else plan.goal_labels[g]
            rest = Rest(plan.goal_xz[g].copy() if not p.stalled[0] else self.pelvis_xz(),
                        label if label >= 0 and not p.stalled[0] else self.idle_label, float(plan.seat_y[g]))
            self.reached.append(Reached(plan.goals[g], frame, rest, bool(p.stalled[0] and last)))
        self.rest = self.reached[-1].rest
        self._replan(self.goals[n_done:], carry=False)

    def _replan(self, goals: list[Goal], carry: bool) -> None:
        """Plan the route through `goals` from the body's position now. carry: keep acting at the
        head goal when it is being acted at (appending must not restart an action)."""
        if not goals:
            self.goals, self.plan, self.progress = [], None, None
            return
        if self.approach > 0:
            aim_at_objects(goals, self.objects, self.loop.hand_actions)
        route = plan_route(self._route_start(), goals, self.walkable, "astar" if self.walkable else "straight",
                           self.spacing, approach=self.approach)
        plan = goal_plan(route, self.loaded.action_names, self.scene, self.loop, self.spec,
                         self.loaded.mask.p_goal_y, self.walkable)
        prog = Progress.start(1, len(goals))
        old = self.progress
        if carry and old is not None and old.leg[0] == 0 and old.acting[0] > 0:
            prog.acting[0], prog.arrival_frame[0, 0] = old.acting[0], old.arrival_frame[0, 0]
            prog.ptr[0] = plan.leg_last[0] + 1
        self.goals, self.plan, self.progress = list(goals), plan, prog

    def _route_start(self) -> np.ndarray:
        """Where routes start: the pelvis now, or the nearest walkable point when it stands where
        the map has no floor (seated on furniture)."""
        xz = self.pelvis_xz()
        if self.walkable is None or self.walkable.is_free(xz):
            return xz
        near = self.walkable.nearest_free(xz, 1.5)
        if near is None:
            raise ConfigError(f"the body at ({xz[0]:.2f}, {xz[1]:.2f}) has no walkable floor within 1.5 m")
        return near

    def out_frames(self, n_model: int) -> int:
        """Output frames that n_model model frames cover (a `Reached.frame` is done by output
        frame out_frames(frame) - 1)."""
        return int(np.floor((n_model - 1) * self.out_fps / self.model_fps + 1e-9)) + 1

    def _extend_output(self) -> None:
        """Resample the model frames not yet covered to out_fps and pose them on the body."""
        m = self.model
        n0, n1 = self.num_frames, self.out_frames(len(m))
        if n1 <= n0:
            return
        t = np.arange(n0, n1) * self.model_fps / self.out_fps                                # model-frame times
        a = np.minimum(np.floor(t).astype(np.int64), len(m) - 2).clip(0)
        w = (t - a).clip(0, 1)[:, None]
        b = np.minimum(a + 1, len(m) - 1)
        root = (1 - w) * m["joints"][a, PELVIS] + w * m["joints"][b, PELVIS]                    # (n, 3)
        q = slerp(m["quat"][a], m["quat"][b], w)                                              # (n, 22, 4)
        rot = torch.as_tensor(Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(len(t), -1, 3, 3))
        body = self.state.body
        transl = torch.as_tensor(root) - body.rest[0, 0].double()
        joints = body.pose(rot[None].to(body.rest.dtype), transl[None].to(body.rest.dtype))[0]   # (n, J, 3)
        near = np.where(w[:, 0] < 0.5, a, b)
        self.out.append(root=root, quats=q, joints=joints.double().numpy(), labels=m["labels"][near].astype(np.int64))


def _quats(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions x, y, z, w."""
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat().reshape(R.shape[:-2] + (4,))


def slerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Spherical interpolation of unit quaternions q0, q1 (n, K, 4) by weights w (n, 1), the
    shorter way round."""
    dot = (q0 * q1).sum(-1, keepdims=True)                                                  # (n, K, 1)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot).clip(0, 1)
    theta = np.arccos(dot)
    s = np.sin(theta)
    w = w[:, None]                                                                         # (n, 1, 1)
    small = s < 1e-6
    s = np.where(small, 1.0, s)
    a = np.where(small, 1 - w, np.sin((1 - w) * theta) / s)
    b = np.where(small, w, np.sin(w * theta) / s)
    q = a * q0 + b * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)
