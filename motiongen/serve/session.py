"""A live session: the generation thread, the playback clock and what the web API reads.

One thread owns the `LiveSampler` and runs episodes while what is generated is less than
`lead_s` seconds ahead of playback. Requests never touch the sampler: they queue goal commands
(validated first, so a bad goal is refused at once) and read the frames the thread published.
A command that changes where the body heads next (a goal given to an idle body, a clear) rolls
the sampler back to a little after the play head, `margin_s` ahead: just long enough for the
next episode to be generated before playback gets there. The episode being generated when such
a command comes is stopped (`LiveSampler.cancel`): its frames lie past that point. Each rollback bumps `rev`, so a viewer knows which of its frames
changed (`frames`).

The playback clock runs on the wall clock while playing and waits, counting the wait as a stall,
when it reaches the last generated frame.
"""

from __future__ import annotations

import collections
import threading
import time
import traceback
from dataclasses import dataclass

import numpy as np

from motiongen.errors import ConfigError
from motiongen.routing import WalkableMap
from motiongen.sampling.goals import Goal, check_actions, plan_route
from motiongen.sampling.live import Cancelled, LiveSampler
from motiongen.skeleton import NUM_BODY_JOINTS


@dataclass
class Published:
    """What the thread last published: the frames (arrays are never changed in place) and the
    goal state as generated (ahead of playback)."""

    frames: dict                   # LiveSampler.frames_since(0)
    goals: list                    # Goals not yet done in the frames generated, in order
    subgoals: np.ndarray           # (K, 2) planned from the last frame generated through `goals`
    done: list                     # (output frame, Goal, stalled) of each goal done in the frames generated


class LiveSession:
    """The generation thread around a LiveSampler, and the API's view of it."""

    def __init__(self, live: LiveSampler, walkable: WalkableMap | None, *, lead_s: float = 1.5,
                 max_pending: int = 100, clock=time.monotonic):
        self.live, self.walkable = live, walkable
        self.lead_s, self.max_pending, self.clock = float(lead_s), int(max_pending), clock
        self.fps = live.out_fps
        self.lock = threading.Lock()
        self.wake = threading.Event()
        self.queue: list[tuple[str, list[Goal]]] = []
        self.applying: list[tuple[str, list[Goal]]] = []   # taken from the queue, not yet published
        self.playing, self.played, self.stall_s, self._last = True, 0.0, 0.0, clock()
        self.rev, self.rollbacks, self.changed_from = 0, [], 0
        self.episode_s = 0.1                      # running mean of one episode's generation time
        # The last episodes' generation times; the warm-up's until the thread has timed its own.
        self.recent = collections.deque(live.warmup_s[-1:], maxlen=8)   # the first also pays one-time costs
        self.recent_apply = collections.deque([0.0], maxlen=8)   # the last rollbacks' replanning times
        self.gen_s, self.gen_frames = 0.0, 0      # generation time and frames, in all (the real-time factor)
        self.error: str | None = None             # the last goal the thread could not plan
        self.pub = self._snapshot()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="motiongen-live", daemon=True)

    # ---- lifetime ------------------------------------------------------------------------

    def start(self) -> "LiveSession":
        self._last = self.clock()
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self.live.cancel.set()
        self.wake.set()
        self._thread.join(timeout=10)
        self.live.close()

    # ---- requests ------------------------------------------------------------------------

    def add_goals(self, goals: list[Goal], replace: bool = False) -> int:
        """Queue goals after the pending ones (replace: instead of them, in one command, so the body
        changes course at once); ConfigError (nothing queued) for an unknown action, a point off
        the walkable floor or out of the scene, no route to it, or too many pending. Returns the
        number pending."""
        check_actions(goals, self.live.loaded.action_names)
        with self.lock:
            pending = [] if replace else self._pending()
            here = self.pub.frames["root"][self._frame_played(), [0, 2]]
        start = pending[-1].xz if pending else here
        if len(pending) + len(goals) > self.max_pending:
            raise ConfigError(f"too many goals: {len(pending)} pending, at most {self.max_pending}")
        # The route from the last pending goal: a goal that cannot be reached is refused now.
        if self.walkable is not None:
            free = start if self.walkable.is_free(start) else self.walkable.nearest_free(start, 1.5)
            plan_route(free if free is not None else goals[0].xz, goals, self.walkable, "astar", 0.6)
        with self.lock:
            if replace:
                self.queue = [("clear", [])]
            self._queue("add", list(goals), heads=replace or not self._pending())
            return len(self._pending())

    def _pending(self) -> list[Goal]:
        """The goals pending once the queue is applied (under the lock)."""
        commands = self.applying + self.queue
        cleared = any(kind == "clear" for kind, _ in commands)
        return ([] if cleared else list(self.pub.goals)) + [g for kind, gs in commands if kind == "add" for g in gs]

    def clear_goals(self) -> None:
        with self.lock:
            self.queue = []
            self._queue("clear", [], heads=True)

    def _queue(self, kind: str, goals: list[Goal], heads: bool) -> None:
        """Queue a command (under the lock) and wake the thread; when it changes where the body
        heads, stop the episode being generated too, when its frames lie past the rollback point:
        what is generated reaches past it. (Otherwise the episode is what playback reaches next,
        a click soon after another: stopping it would stall playback, so it finishes and the
        rollback drops what it made past the point.) The thread clears `cancel` under the lock as
        it takes the queue, so no stop outlives its command."""
        self.queue.append((kind, goals))
        if heads:
            self._tick()
            if self._generated_s() > self.played + self._margin_s():
                self.live.cancel.set()
        self.wake.set()

    def set_playing(self, playing: bool) -> None:
        with self.lock:
            self._tick()
            self.playing = bool(playing)

    def state(self) -> dict:
        """The API's /api/state (docs/serve.md)."""
        with self.lock:
            self._tick()
            pub, f = self.pub, self._frame_played()
            commands = self.applying + self.queue          # requested, not yet in what was published
            queued = [g for kind, gs in commands if kind == "add" for g in gs]
            cleared = any(kind == "clear" for kind, _ in commands)
            # What the viewer sees: a goal is pending until playback has reached its done frame.
            ahead = [g for frame, g, _ in pub.done if frame > f]
            played = [stalled for frame, _, stalled in pub.done if frame <= f]
            goals = ([] if cleared else ahead + pub.goals) + queued
            joints = pub.frames["joints"][f, :NUM_BODY_JOINTS]
            names = self.live.loaded.action_names
            label = int(pub.frames["labels"][f])
            return {"time_played": self.played, "time_generated": self._generated_s(),
                    "frame_played": f, "frames_generated": len(pub.frames["root"]), "fps": self.fps,
                    "playing": self.playing, "rev": self.rev, "changed_from": self.changed_from,
                    "hips": joints[0].tolist(), "joints": joints.tolist(),
                    "goals": [goal_json(g) for g in goals], "goals_reached": played.count(False),
                    "goals_stalled": played.count(True), "route": self._route(f, goals, queued, cleared).tolist(),
                    "action_now": names[label] if 0 <= label < len(names) else None,
                    "stall_s": self.stall_s, "episode_s": self.episode_s, "error": self.error,
                    "real_time_factor": self.gen_frames / self.fps / self.gen_s if self.gen_s else None}

    def _route(self, f: int, goals: list, queued: list, cleared: bool) -> np.ndarray:
        """(N, 2) the way ahead of the body playing frame f: the pelvis over the frames generated
        (every 5th), the subgoals planned on from there, then goals queued but not yet planned
        (straight); empty without goals pending."""
        if not goals:
            return np.zeros((0, 2))
        root = self.pub.frames["root"]
        walked = root[list(range(f, len(root), 5)) + [len(root) - 1]][:, [0, 2]]
        planned = np.zeros((0, 2)) if cleared else self.pub.subgoals
        waiting = np.array([g.xz for g in queued], np.float64).reshape(-1, 2)
        return np.concatenate([walked, planned, waiting]).round(3)

    def frames(self, start: int, rev: int | None) -> dict:
        """Frames from `start` on for a viewer at revision `rev`: from the first frame a later
        rollback changed when that comes earlier."""
        with self.lock:
            fr, total = self.pub.frames, len(self.pub.frames["root"])
            if rev is not None:
                for r, f in self.rollbacks:
                    if r > rev:
                        start = min(start, f)
            start = int(np.clip(start, 0, total))
            return {"rev": self.rev, "start": start, "total": total, "fps": self.fps,
                    "root": fr["root"][start:].round(5).tolist(), "quats": fr["quats"][start:].round(6).tolist(),
                    "joints": fr["joints"][start:, :NUM_BODY_JOINTS].round(5).tolist()}

    def snapshot_frames(self) -> dict:
        """Every frame generated so far (for downloads)."""
        with self.lock:
            return dict(self.pub.frames)

    # ---- the generation thread -------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._turn()
            except Exception as e:                     # a bug: say so, drop the goals, keep serving
                traceback.print_exc()
                self.error = f"generation failed ({type(e).__name__}: {e}); goals dropped"
                self.live.cancel.clear()
                self.live.clear_goals()
                self._publish()

    def _turn(self) -> None:
        """One turn of the thread: apply queued commands, then generate one episode when playback
        needs it (else wait a little)."""
        with self.lock:
            self._tick()
            commands, self.queue = self.queue, []
            self.applying = commands
            self.live.cancel.clear()
            ahead = self._generated_s() - self.played
        if commands:
            self._apply(commands)
        elif ahead > self.lead_s:
            self.wake.wait(0.02)
            self.wake.clear()
            return
        t = time.perf_counter()
        try:
            n = self.live.step()
        except Cancelled:
            return
        dt = time.perf_counter() - t
        with self.lock:                            # requests read the margin (`_queue`)
            self.episode_s = 0.8 * self.episode_s + 0.2 * dt
            self.recent.append(dt)
            self.gen_s, self.gen_frames = self.gen_s + dt, self.gen_frames + n
        self._publish()

    def _apply(self, commands: list) -> None:
        """Apply queued commands; roll back first when they change where the body heads next."""
        t, live = time.perf_counter(), self.live
        heads = any(kind == "clear" for kind, _ in commands) or live.heads_to() is None
        if heads:
            with self.lock:
                self._tick()
                keep = self._frame_played() + int(np.ceil(self._margin_s() * self.fps))
            first = live.rollback(keep, replan=False)     # the commands below plan the route once
            with self.lock:
                if first < len(self.pub.frames["root"]):
                    self.rev += 1
                    self.rollbacks.append((self.rev, first))
                self.changed_from = first
        for kind, goals in commands:
            try:
                live.clear_goals() if kind == "clear" else live.add_goals(goals)
                self.error = None
            except ConfigError as e:                   # validated when queued; the body may stand elsewhere by now
                self.error = str(e)
        if live.plan is None and live.goals:
            try:
                live.replan()
            except ConfigError as e:                   # the goals a rollback brought back cannot be reached from here
                self.error = str(e)
                live.clear_goals()
        self._publish()
        if heads:
            with self.lock:
                self.recent_apply.append(time.perf_counter() - t)

    def _margin_s(self) -> float:
        """How far past the play head a rollback keeps: the next episode's generation time, taken as
        the slowest of the last few with some room (a mean would stall playback every time an
        episode runs long), plus the route planning a rollback does first."""
        return 1.15 * max(self.recent) + max(self.recent_apply) + 0.03

    def _publish(self) -> None:
        snap = self._snapshot()
        with self.lock:
            self.pub, self.applying = snap, []

    def _snapshot(self) -> Published:
        live = self.live
        done = [(live.out_frames(r.frame) - 1, r.goal, r.stalled) for r in live.reached]
        return Published(live.frames_since(0), list(live.goals), live.route_points(), done)

    # ---- the clock (under the lock) -----------------------------------------------------------

    def _tick(self) -> None:
        now = self.clock()
        dt, self._last = now - self._last, now
        if not self.playing:
            return
        end = self._generated_s()
        want = self.played + dt
        if want > end:
            self.stall_s += want - max(end, self.played)
        self.played = min(want, end)

    def _generated_s(self) -> float:
        """Seconds of motion published: the time of the last frame generated."""
        return (len(self.pub.frames["root"]) - 1) / self.fps

    def _frame_played(self) -> int:
        return int(min(np.floor(self.played * self.fps + 1e-9), len(self.pub.frames["root"]) - 1))


def goal_json(g: Goal) -> dict:
    return {"x": float(g.xz[0]), "z": float(g.xz[1]), "action": g.action}
