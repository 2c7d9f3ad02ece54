"""Scripted sequences: walk -> interact -> walk, as per-frame pose controls, then joints,
object poses and labels.

A `Timeline` appends segments (idle, walk, turn, sit, lie, pick up) that each start exactly
at the previous segment's last frame, so the sequence is continuous; key poses are blended
with minimum-jerk timing. Everything is deterministic given the rng.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from motiongen.synthetic.body import Body, Controls, J, pose, rot_y, torso
from motiongen.synthetic.gait import Feet, cycle_seconds, stance_feet, walk
from motiongen.synthetic.labels import action_rows, contacts
from motiongen.synthetic.routes import minjerk, path_trajectory, plan_walk, random_free, turn_trajectory, wrap
from motiongen.routing import WalkableMap
from motiongen.synthetic.scenes import MAX_OBJECTS, Bed, Scene, Seat
from motiongen.geometry import facing_yaw

PALM = 0.07  # wrist -> centre of a grasped object, m (reference body)


def _rep(a: np.ndarray, n: int) -> np.ndarray:
    return np.repeat(np.asarray(a)[None], n, 0)


def _lerp(a, b, w, tail: int):
    """a + (b - a) w for weights w (n,) over values with `tail` trailing dims -> (n, ...)."""
    w = np.asarray(w).reshape(-1, *([1] * tail))
    return a + (b - a) * w


class Timeline:
    def __init__(self, body: Body, scene: Scene, floor: WalkableMap, rng: np.random.Generator, fps: float,
                 xz: np.ndarray, yaw: float):
        self.body, self.scene, self.floor, self.rng, self.fps = body, scene, floor, rng, fps
        self.xz, self.yaw, self.exit_xz = np.asarray(xz, float), float(yaw), np.asarray(xz, float)
        self.feet = stance_feet(body, self.xz, self.yaw)
        self.speed = rng.uniform(0.95, 1.35)
        self.parts: list[Controls] = []
        self.acts: list[np.ndarray] = []
        self.holding: int | None = None             # hand holding an object
        self.grasp: tuple[int, int, int] | None = None  # (item, first held frame, hand)
        self.frames = 0
        pelvis = np.array([self.xz[0], body.stand_pelvis_y, self.xz[1]])
        self._push(self._standing(_rep(pelvis, 1), np.array([self.yaw]), self.feet), action_rows(1, "stand"), skip_first=False)

    # -- helpers -------------------------------------------------------------------------
    @property
    def last(self) -> Controls:
        return self.parts[-1].take(slice(-1, None))

    def seconds(self) -> float:
        return self.frames / self.fps

    def _push(self, c: Controls, acts: np.ndarray, skip_first: bool = True) -> None:
        """Append a segment whose frame 0 repeats the current last frame (dropped)."""
        s = slice(1, None) if skip_first else slice(None)
        c, acts = c.take(s), acts[s]
        if self.holding is not None:
            acts = acts.copy()
            acts[:, 5] = True  # carry
        self.parts.append(c)
        self.acts.append(acts)
        self.frames += len(c)

    def _arms(self, pelvis, root, lean, swing=None) -> np.ndarray:
        """Wrist targets (n, 2, 3): arms hanging (swinging by angle (n, 2)), or the holding
        hand in front of the belly."""
        b = self.body
        n = len(pelvis)
        a = np.zeros((n, 2)) if swing is None else swing
        t = torso(b, pelvis, root, lean)
        local = np.stack([np.stack([np.full(n, 0.04 * b.s * sgn), -0.97 * b.arm * np.cos(a[:, k]),
                                    0.97 * b.arm * np.sin(a[:, k]) + 0.03 * b.s], -1)
                          for k, sgn in ((0, 1), (1, -1))], 1)                 # (n, 2, 3)
        wrist = t["shoulder"] + np.einsum("tij,tkj->tki", t["R3"], local)
        if self.holding is not None:
            h = self.holding
            carry = np.array([0.12 * (1 if h == 0 else -1), 0.2, 0.3]) * b.s
            wrist[:, h] = pelvis + root @ carry
        return wrist

    def _standing(self, pelvis: np.ndarray, yaw: np.ndarray, feet: Feet, lean=None) -> Controls:
        n = len(pelvis)
        root = rot_y(yaw)
        lean = np.zeros(n) if lean is None else lean
        frot = _rep(rot_y(feet.yaw), n)
        return Controls(pelvis, root, lean, _rep(feet.ankle, n), frot, frot[..., 2], self._arms(pelvis, root, lean))

    def _n(self, seconds: float) -> int:
        return max(int(round(seconds * self.fps)), 2) + 1

    # -- segments ------------------------------------------------------------------------
    def idle(self, seconds: float) -> None:
        n = self._n(seconds)
        u = np.arange(n) / (n - 1)
        env = np.sin(np.pi * u) ** 2  # zero at both ends: joins its neighbours smoothly
        ph = self.rng.uniform(0, 2 * np.pi, 2)
        t = np.arange(n) / self.fps
        sway = 0.012 * self.body.s * env[:, None] * np.stack([np.sin(2 * np.pi * 0.3 * t + ph[0]), 0 * t,
                                                              np.sin(2 * np.pi * 0.23 * t + ph[1])], -1)
        pelvis = self.last.pelvis + sway
        c = self._standing(pelvis, np.full(n, self.yaw), self.feet)
        self._push(c, action_rows(n, "stand"))

    def _step(self, xz: np.ndarray, yaw: np.ndarray) -> None:
        b = self.body
        cyc = cycle_seconds(b, self.speed)
        first = int(self.rng.integers(2))
        w = walk(b, xz, yaw, self.feet, self.fps, cyc, first)
        n = len(w.pelvis)
        root = rot_y(w.yaw)
        fwd = root[:, :, 2]
        # Arms swing against the legs: the left arm goes forward as the right foot does.
        lead = np.einsum("tj,tj->t", w.ankle[:, 1] - w.ankle[:, 0], fwd)
        swing = np.stack([0.5 * lead, -0.5 * lead], -1) / b.s
        c = Controls(w.pelvis, root, np.zeros(n), w.ankle, w.foot_rot, w.foot_rot[..., 2],
                     self._arms(w.pelvis, root, np.zeros(n), swing))
        speed = np.linalg.norm(np.gradient(w.pelvis[:, [0, 2]], axis=0), axis=-1) * self.fps
        moving = w.swinging.any(1) | (speed > 0.05)
        acts = action_rows(n, "walk")
        acts[~moving] = action_rows(1, "stand")
        self._push(c, acts)
        self.feet, self.xz, self.yaw = w.feet, w.pelvis[-1, [0, 2]], float(w.yaw[-1])

    def turn_to(self, yaw: float) -> None:
        if abs(wrap(yaw - self.yaw)) > 0.05:
            self._step(*turn_trajectory(self.xz, self.yaw, yaw, self.fps))

    def walk_to(self, goal: np.ndarray, final: np.ndarray | None = None) -> bool:
        """Walk to the free point `goal`, then on to `final` (just outside furniture) if given."""
        start = self.xz if self.floor.is_free(self.xz) else self.exit_xz
        path = plan_walk(self.floor, start, goal)
        if path is None:
            return False
        if start is not self.xz:
            path = np.concatenate([self.xz[None], path])
        if final is not None:
            path = np.concatenate([path, np.asarray(final)[None]])
        path = path[np.concatenate([[True], np.linalg.norm(np.diff(path, axis=0), axis=1) > 1e-6])]
        if len(path) < 2:
            return True
        head = np.arctan2(*(path[1] - path[0]))
        if abs(wrap(head - self.yaw)) > np.deg2rad(100):
            self.turn_to(head)
        speed = float(np.clip(self.speed + self.rng.normal(0, 0.05), 0.9, 1.4))
        self._step(*path_trajectory(path, self.yaw, speed, self.fps))
        self.exit_xz = np.asarray(goal, float)
        return True

    def _seat_pelvis(self, surface: np.ndarray) -> np.ndarray:
        return surface + np.array([0.0, self.body.tissue[J["pelvis"]], 0.0])

    def _sit_transition(self, seat: Seat, down: bool, label=("sit",)) -> None:
        """Standing <-> seated on `seat`, feet planted; the trunk hinges forward mid-way."""
        b, n = self.body, self._n(self.rng.uniform(1.2, 1.7))
        u = np.arange(n) / (n - 1)
        up_p = np.array([self.xz[0], b.stand_pelvis_y, self.xz[1]])
        lo_p = self._seat_pelvis(seat.surface)
        if not down:
            u = 1 - u  # played backwards
        w_xz, w_y = minjerk(np.clip(u * 1.25, 0, 1)), minjerk(u)
        pelvis = up_p + (lo_p - up_p) * np.stack([w_xz, w_y, w_xz], -1)
        lean = 0.6 * np.sin(np.pi * u) ** 1.5
        root = _rep(rot_y(self.yaw), n)
        hang = self._arms(pelvis, root, lean)
        wrist = _lerp(hang, self._thigh_hands(pelvis, root), minjerk(u), 2)
        frot = _rep(rot_y(self.feet.yaw), n)
        c = Controls(pelvis, root, lean, _rep(self.feet.ankle, n), frot, frot[..., 2], wrist)
        self._push(c, action_rows(n, *label))

    def _thigh_hands(self, pelvis: np.ndarray, root: np.ndarray) -> np.ndarray:
        """Wrist targets (n, 2, 3) resting on the thighs of a seated body."""
        local = np.array([[0.15, 0.12, 0.2], [-0.15, 0.12, 0.2]]) * self.body.s
        return pelvis[:, None] + np.einsum("tij,kj->tki", root, local)

    def _hold_still(self, seconds: float, label: tuple[str, ...], breathe: float = 0.02) -> None:
        """Stay in the current pose, breathing (a slow small bend of the spine)."""
        n = self._n(seconds)
        last = self.last
        c = Controls(*(_rep(getattr(last, f)[0], n) for f in Controls.FIELDS))
        u = np.arange(n) / (n - 1)
        c.lean = c.lean + breathe * np.sin(np.pi * u) ** 2 * np.sin(2 * np.pi * 0.25 * np.arange(n) / self.fps)
        self._push(c, action_rows(n, *label))

    def _sit_down_at(self, seat: Seat, hold_s: tuple[float, float]) -> bool:
        """Walk to the seat, turn, sit down and stay seated for a random time in hold_s."""
        if not self.walk_to(seat.pre_xz, seat.stand_xz):
            return False
        self.turn_to(seat.yaw)
        self._sit_transition(seat, True)
        self._hold_still(self.rng.uniform(*hold_s), ("sit",))
        return True

    def sit(self, seat: Seat) -> bool:
        if not self._sit_down_at(seat, (2.0, 6.0)):
            return False
        self._sit_transition(seat, False)
        return True

    def _lie_transition(self, bed: Bed, down: bool) -> None:
        b, n = self.body, self._n(self.rng.uniform(1.8, 2.4))
        u = np.arange(n) / (n - 1)
        if not down:
            u = 1 - u
        seat_p = self._seat_pelvis(bed.edge.surface)
        lie_p = self._seat_pelvis(bed.lie_surface)
        up = np.array([0.0, 1.0, 0.0])
        R_lie = np.column_stack([np.cross(bed.head_dir, up), bed.head_dir, up])
        R_seat = rot_y(self.yaw)
        m = minjerk(u)
        root = Slerp([0, 1], Rotation.from_matrix(np.stack([R_seat, R_lie])))(m).as_matrix()
        pelvis = seat_p + (lie_p - seat_p) * m[:, None]
        # Legs follow the trunk a little later, lifted over the mattress edge.
        mf = minjerk(np.clip(u * 1.25 - 0.25, 0, 1))
        lie_ankle = lie_p + np.einsum("ij,kj->ki", R_lie, np.array([[0.09, -0.085 - 0.97 * b.leg / b.s, -0.04],
                                                                       [-0.09, -0.085 - 0.97 * b.leg / b.s, -0.04]]) * b.s)
        ankle = _lerp(self.feet.ankle, lie_ankle, mf, 2)
        lift = max(bed.lie_surface[1] + 0.1 - lie_ankle[:, 1].min(), 0.0) + 0.12
        ankle[..., 1] += lift * np.sin(np.pi * np.clip(u * 1.25 - 0.25, 0, 1))[:, None]
        frot = np.stack([Slerp([0, 1], Rotation.from_matrix(np.stack([rot_y(self.feet.yaw[k]), R_lie])))(mf).as_matrix()
                         for k in (0, 1)], 1)
        lean = np.zeros(n)
        # Hands leave the thighs (where sitting put them) for the sides of the body.
        wrist = _lerp(self._thigh_hands(seat_p[None], R_seat[None]), self._arms(pelvis, root, lean),
                      minjerk(np.clip(u * 2, 0, 1)), 2)
        c = Controls(pelvis, root, lean, ankle, frot, frot[..., 2], wrist)
        self._push(c, action_rows(n, "lie down"))

    def lie(self, bed: Bed) -> bool:
        edge = bed.edge
        if not self._sit_down_at(edge, (0.3, 0.8)):
            return False
        self._lie_transition(bed, True)
        self._hold_still(self.rng.uniform(3.0, 7.0), ("lie down",), breathe=0.0)
        self._lie_transition(bed, False)
        self._hold_still(self.rng.uniform(0.3, 0.8), ("sit",))
        self._sit_transition(edge, False)
        return True

    def _reach_pose(self, target: np.ndarray, hand: int):
        """(lean, pelvis drop, grasp point) that puts the wrist PALM short of target, or None."""
        b = self.body
        p0 = np.array([self.xz[0], b.stand_pelvis_y, self.xz[1]])
        R = rot_y(self.yaw)[None]
        best = None
        for drop in (0.0, 0.1, 0.2, 0.3):
            for lean in np.linspace(0.0, 1.0, 11):
                pel = p0 + np.array([0, -drop * b.s, 0]) - R[0, :, 2] * 0.1 * b.s * np.sin(lean)
                sh = torso(b, pel[None], R, np.array([lean]))["shoulder"][0, hand]
                d = target - sh
                grasp = target - d / np.linalg.norm(d) * PALM * b.s
                if np.linalg.norm(grasp - sh) <= 0.97 * b.arm:
                    cost = lean + 3 * drop
                    if best is None or cost < best[0]:
                        best = (cost, lean, pel, grasp)
                    break
        return None if best is None else best[1:]

    def pick_up(self, item_index: int) -> bool:
        item = self.scene.items[item_index]
        if self.holding is not None:
            return False
        if not self.walk_to(item.pre_xz, item.stand_xz):
            return False
        self.turn_to(item.yaw)
        target = item.rest[:3, 3]
        left = rot_y(self.yaw)[:, 0]
        hand = 0 if (target[[0, 2]] - self.xz) @ left[[0, 2]] > 0 else 1
        plan = self._reach_pose(target, hand)
        if plan is None:
            self.idle(0.5)
            return True
        lean1, pel1, grasp = plan
        p0 = self.last.pelvis[0]
        root_1 = rot_y(self.yaw)
        frot = rot_y(self.feet.yaw)
        for phase in ("reach", "hold", "lift"):
            n = self._n({"reach": self.rng.uniform(0.9, 1.3), "hold": 0.3, "lift": self.rng.uniform(0.9, 1.2)}[phase])
            u = np.arange(n) / (n - 1)
            m = minjerk(u) if phase != "hold" else np.ones(n)
            if phase == "lift":
                m = 1 - m
            pelvis = _lerp(p0, pel1, m, 1)
            lean = lean1 * m
            root = _rep(root_1, n)
            if phase == "lift":
                self.holding = hand  # from here on the hand's default pose is the carry pose
            wrist = self._arms(pelvis, root, lean)
            if phase == "reach":
                wrist[:, hand] = _lerp(wrist[:, hand], grasp, minjerk(np.clip(u * 1.2 - 0.2, 0, 1)), 1)
            elif phase == "hold":
                wrist[:, hand] = grasp
            else:
                wrist[:, hand] = _lerp(wrist[:, hand], grasp, m, 1)
            c = Controls(pelvis, root, lean, _rep(self.feet.ankle, n), _rep(frot, n), _rep(frot[..., 2], n), wrist)
            if phase == "hold":
                self.grasp = (item_index, self.frames, hand)
                self.holding = hand
                self._push(c, action_rows(n, "pick up"))
            else:
                self._push(c, action_rows(n, "pick up"))
        return True

    # -- output --------------------------------------------------------------------------
    def finish(self) -> dict[str, np.ndarray]:
        """joints (T,22,3) f32, actions (T,A) bool, contact (T,22) bool,
        object_poses (T,K,4,4) f32, object_ids (T,K) i32 (slot k = scene item k)."""
        c = Controls.cat(self.parts)
        joints = pose(self.body, c)                                            # (T, 22, 3)
        T, K = len(joints), MAX_OBJECTS
        items = self.scene.items
        poses = np.broadcast_to(np.eye(4), (T, K, 4, 4)).copy()
        ids = np.full((T, K), -1, np.int32)
        for k, it in enumerate(items):
            poses[:, k] = it.rest
            ids[:, k] = self.scene.id * 10 + k
        if self.grasp is not None:
            k, g, hand = self.grasp
            wj = J["left_wrist" if hand == 0 else "right_wrist"]
            yaw = facing_yaw(joints)
            off = rot_y(yaw[g]).T @ (items[k].rest[:3, 3] - joints[g, wj])
            held = slice(g, None)
            poses[held, k, :3, 3] = joints[held, wj] + rot_y(yaw[held]) @ off
            poses[held, k, :3, :3] = rot_y(yaw[held] - yaw[g]) @ items[k].rest[:3, :3]
        radius = np.array([it.radius for it in items])
        contact = contacts(joints, self.body.tissue, self.scene.boxes, poses[:, :len(items), :3, 3], radius)
        return {"joints": joints.astype(np.float32), "actions": np.concatenate(self.acts), "contact": contact,
                "object_poses": poses.astype(np.float32), "object_ids": ids}


def make_sequence(scene: Scene, floor: WalkableMap, rng: np.random.Generator, fps: float,
                  seconds: float) -> tuple[dict[str, np.ndarray], float]:
    """One scripted sequence of about `seconds` (at least 4 s): the arrays of `Timeline.finish`
    and the body height."""
    body = Body(float(rng.uniform(1.55, 1.90)))
    start = random_free(floor, rng)
    tl = Timeline(body, scene, floor, rng, fps, start, rng.uniform(-np.pi, np.pi))
    tl.idle(rng.uniform(0.8, 2.0))
    failures = 0
    while (tl.seconds() < seconds or tl.seconds() < 4.0) and failures < 6:
        choices = ["goto"]
        if tl.holding is None:
            choices += ["sit"] * (2 if scene.seats else 0) + ["lie"] * (2 if scene.beds else 0) + \
                       ["pick"] * (2 if scene.items else 0)
        what = choices[int(rng.integers(len(choices)))]
        if what == "goto":
            goal = random_free(floor, rng, tl.xz, 2.0)
            ok = goal is not None and tl.walk_to(goal)
        elif what == "sit":
            ok = tl.sit(scene.seats[int(rng.integers(len(scene.seats)))])
        elif what == "lie":
            ok = tl.lie(scene.beds[int(rng.integers(len(scene.beds)))])
        else:
            ok = tl.pick_up(int(rng.integers(len(scene.items))))
        failures += not ok
        if ok:
            tl.idle(rng.uniform(0.5, 2.0))
    return tl.finish(), body.height
