"""Walking and turning from a root trajectory: alternating footsteps, planted stance feet,
swing feet on arcs, heel rise in late stance, and a pelvis height that lets the legs reach.

A foot lands where the root will be a quarter cycle later (offset sideways by the stance
width), so the pelvis passes over it mid-stance. Stance feet never slide: the toe stays put
and the heel lifts (the foot pivots about the toe) when the hip moves out of reach.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from motiongen.synthetic.body import Body, rot_x, rot_y
from motiongen.synthetic.routes import minjerk, wrap

TOE_OUT = 0.1      # rad, feet turn out a little
SWING = 0.4        # fraction of the gait cycle a foot is in the air


@dataclass
class Feet:
    """Where the two feet are planted: flat ankle positions (2, 3) and foot yaws (2,)."""
    ankle: np.ndarray
    yaw: np.ndarray


def stance_feet(body: Body, xz: np.ndarray, yaw: float) -> Feet:
    """Feet side by side under the hips of a body standing at (x, z) facing yaw."""
    off = np.array([[0.09, 0.0], [-0.09, 0.0]]) * body.s
    c, s = np.cos(yaw), np.sin(yaw)
    pts = xz + np.stack([c * off[:, 0] + s * off[:, 1], -s * off[:, 0] + c * off[:, 1]], -1)
    ankle = np.column_stack([pts[:, 0], np.full(2, body.ankle_h), pts[:, 1]])
    return Feet(ankle, np.array([yaw + TOE_OUT, yaw - TOE_OUT]))


def cycle_seconds(body: Body, speed: float) -> float:
    """Stride time from a stride length that grows with stature and speed (about 1 s)."""
    stride = 0.7 * body.height * np.sqrt(max(speed, 0.3) / 1.3)
    return float(np.clip(stride / max(speed, 1e-3), 0.9, 1.2))


@dataclass
class Walk:
    pelvis: np.ndarray    # (T, 3)
    yaw: np.ndarray       # (T,)
    ankle: np.ndarray     # (T, 2, 3)
    foot_rot: np.ndarray  # (T, 2, 3, 3)
    swinging: np.ndarray  # (T, 2) bool
    feet: Feet            # planted at the end


@dataclass
class _Steps:
    """The footsteps of a walk: flat stance ankles (T, 2, 3) and foot yaws (T, 2) per frame
    (where each foot is planted or will land), and the swings (foot, lift frame, land frame)."""
    xz: np.ndarray        # (T, 2) root, held at its last value after the root stops
    yaw: np.ndarray       # (T,)
    ankle: np.ndarray     # (T, 2, 3)
    foot_yaw: np.ndarray  # (T, 2)
    swings: list[tuple[int, int, int]]

    def swinging(self) -> np.ndarray:
        """(T, 2) bool: the foot is in the air (between its lift and land frames)."""
        out = np.zeros((len(self.xz), 2), bool)
        for foot, lift, land in self.swings:
            out[lift + 1:land, foot] = True
        return out


def walk(body: Body, xz: np.ndarray, yaw: np.ndarray, feet: Feet, fps: float, cycle_s: float,
         first: int) -> Walk:
    """Frames 0..T-1 of stepping along root (x, z) (n, 2) / yaw (n,); frame 0 is the standing
    start. Steps go on after the root stops until both feet are under the body again."""
    steps = _plan_steps(body, xz, yaw, feet, cycle_s * fps, first)
    swinging = steps.swinging()
    R = rot_y(steps.yaw)                                                            # (T, 3, 3)
    pelvis = _pelvis(body, steps, swinging, R)
    hips = pelvis[:, None] + np.einsum("tij,kj->tki", R, body.hip)                  # (T, 2, 3)
    ankle, pitch = _heel_rise(body, steps, swinging, hips)
    fyaw = _swing_arcs(body, steps, ankle, pitch)
    foot_rot = rot_y(fyaw) @ rot_x(pitch)                                              # (T, 2, 3, 3)
    # Keep the toes above the floor through the swing.
    toe_y = ankle[..., 1] + np.einsum("tkij,kj->tki", foot_rot, body.foot)[..., 1]
    ankle[..., 1] += np.where(swinging, np.maximum(body.toe_h - toe_y, 0.0), 0.0)
    end_feet = Feet(steps.ankle[-1].copy(), steps.foot_yaw[-1].copy())
    return Walk(pelvis, steps.yaw, ankle, foot_rot, swinging, end_feet)


def _plan_steps(body: Body, xz: np.ndarray, yaw: np.ndarray, feet: Feet, C: float, first: int) -> _Steps:
    """Alternating footsteps every half cycle of C frames, starting with foot `first`, until
    one cycle after the root's n frames; a step that would gain nothing is skipped."""
    n = len(xz)
    horizon = n + int(2 * C) + 2
    xz = np.concatenate([xz, np.repeat(xz[-1:], horizon - n, 0)])
    yaw = np.concatenate([yaw, np.repeat(yaw[-1:], horizon - n, 0)])
    plant = [(feet.ankle[k].copy(), float(feet.yaw[k])) for k in (0, 1)]
    track_a = np.repeat(feet.ankle[None], horizon, 0)          # (H, 2, 3) flat stance ankles
    track_y = np.repeat(feet.yaw[None], horizon, 0)            # (H, 2)
    swings: list[tuple[int, int, int]] = []                    # (foot, lift frame, land frame)
    end = n
    k = 0
    while True:
        lift = int(round(k * C / 2))
        if lift > n + C:
            break
        foot = (first + k) % 2
        k += 1
        land = lift + max(int(round(SWING * C)), 4)
        q = min(int(round(land + 0.25 * C)), horizon - 1)
        side = 0.09 * body.s * (1 if foot == 0 else -1)
        c, s = np.cos(yaw[q]), np.sin(yaw[q])
        target = np.array([xz[q, 0] + c * side, body.ankle_h, xz[q, 1] - s * side])
        tyaw = yaw[q] + (TOE_OUT if foot == 0 else -TOE_OUT)
        a0, y0 = plant[foot]
        if np.linalg.norm(target - a0) < 0.03 and abs(wrap(tyaw - y0)) < 0.09:
            continue  # nothing to gain from this step: keep the foot planted
        tyaw = y0 + wrap(tyaw - y0)
        plant[foot] = (target, tyaw)
        track_a[land:, foot] = target
        track_y[land:, foot] = tyaw
        swings.append((foot, lift, land))
        end = max(end, land + 1)
    T = end
    return _Steps(xz[:T], yaw[:T], track_a[:T], track_y[:T], swings)


def _pelvis(body: Body, steps: _Steps, swinging: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(T, 3) pelvis over the root: as high as standing allows, low enough that flat feet ahead
    reach the floor (smoothed without rising above that limit). R (T, 3, 3): the root's yaw."""
    xz, track_a = steps.xz, steps.ankle
    fwd = np.stack([np.sin(steps.yaw), np.cos(steps.yaw)], -1)                      # (T, 2)
    hip_off = body.hip                                                              # (2, 3)
    hip_xz = xz[:, None] + np.einsum("tij,kj->tki", R, hip_off)[..., [0, 2]]        # (T, 2, 2)
    reach = 0.985 * body.leg
    d = track_a[..., [0, 2]] - hip_xz
    ahead = np.einsum("tkj,tj->tk", d, fwd) > -0.02
    lim = track_a[..., 1] + np.sqrt(np.maximum(reach ** 2 - np.sum(d ** 2, -1), 0.0)) - hip_off[:, 1]
    lim = np.where(ahead & ~swinging, lim, np.inf).min(1)
    h = np.minimum(body.stand_pelvis_y, lim)
    r = 5
    h = ndimage.minimum_filter1d(h, 2 * r + 1, mode="nearest")
    h = ndimage.gaussian_filter1d(h, sigma=r / 2.5, truncate=2.5, mode="nearest")  # stays <= the limit
    return np.column_stack([xz[:, 0], h, xz[:, 1]])


def _heel_rise(body: Body, steps: _Steps, swinging: np.ndarray, hips: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ankles (T, 2, 3) and foot pitches (T, 2): stance feet pivot about the toe (bisection on
    the pitch) until the ankle is within reach of the hip (T, 2, 3)."""
    track_a, track_y, foot_vec = steps.ankle, steps.foot_yaw, body.foot             # foot_vec (2, 3)
    ankle = track_a.copy()
    pitch = np.zeros((len(track_a), 2))
    for f in (0, 1):
        toe = track_a[:, f] + np.einsum("tij,j->ti", rot_y(track_y[:, f]), foot_vec[f])
        far = (~swinging[:, f]) & (np.linalg.norm(hips[:, f] - track_a[:, f], axis=-1) > 0.99 * body.leg)
        if far.any():
            lo, hi = np.zeros(far.sum()), np.full(far.sum(), 1.3)
            Ry = rot_y(track_y[far, f])
            for _ in range(18):
                mid = (lo + hi) / 2
                a = toe[far] - np.einsum("tij,tj->ti", Ry @ rot_x(mid), np.broadcast_to(foot_vec[f], (len(mid), 3)))
                ok = np.linalg.norm(hips[far, f] - a, axis=-1) <= 0.99 * body.leg
                hi, lo = np.where(ok, mid, hi), np.where(ok, lo, mid)
            pitch[far, f] = hi
            ankle[far, f] = toe[far] - np.einsum("tij,tj->ti", Ry @ rot_x(hi), np.broadcast_to(foot_vec[f], (len(hi), 3)))
    return ankle, pitch


def _swing_arcs(body: Body, steps: _Steps, ankle: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """Swinging feet on minimum-jerk arcs from lift-off to landing, with a clearance that grows
    with the step: writes their ankles (T, 2, 3) and pitches (T, 2) in place and returns the
    foot yaws (T, 2)."""
    track_a, track_y = steps.ankle, steps.foot_yaw
    fyaw = track_y.copy()
    for foot, lift, land in steps.swings:
        a0, a1 = ankle[lift, foot], track_a[land, foot]
        y0, y1, p0 = fyaw[lift, foot], track_y[land, foot], pitch[lift, foot]
        u = (np.arange(lift + 1, land) - lift) / (land - lift)
        m = minjerk(u)[:, None]
        step = np.linalg.norm((a1 - a0)[[0, 2]])
        clear = np.clip(0.04 + 0.06 * step, 0.04, 0.09) * body.s
        a = a0 + (a1 - a0) * m
        a[:, 1] = a0[1] + (a1[1] - a0[1]) * m[:, 0] + clear * np.sin(np.pi * u)
        fyaw[lift + 1:land, foot] = y0 + (y1 - y0) * m[:, 0]
        pitch[lift + 1:land, foot] = p0 * (1 - minjerk(np.clip(u * 2, 0, 1)))
        ankle[lift + 1:land, foot] = a
    return fyaw
