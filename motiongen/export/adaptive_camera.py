"""The adaptive camera of the TRUMANS supplement (B.7, video rendering): a camera on a ring
around the body that keeps the interaction in view with as little turning as it can.

As the supplement describes it:
* the camera stands 1.4 m above the floor, within 2 m of the body, looking at it; its pose is
  one angle about the vertical axis around the body;
* keyframes every 30 frames, each with 20 proposals evenly spaced on the ring;
* the interacting hand is the one nearer a dynamic object, or the right hand when both are
  more than 20 cm away;
* a joint is visible from a proposal when it projects into the image and the ray towards it
  first meets the scene within 10 cm of the joint (or not at all);
* the number of visible hand joints a proposal must reach adapts per keyframe: the best
  proposal's count, so that at least one proposal covers the interaction unless none sees
  any hand joint;
* dynamic programming picks the keyframe angles that minimise total rotation and maximise
  coverage; cubic splines of the angle join the keyframes.

Choices of ours, where the supplement is silent or our video differs:
* the ring is centred on the pelvis smoothed over `smooth_s` (the raw pelvis sways with every
  step), its angle measured in the world frame, so "rotation" is what the viewer sees turn;
* the camera looks at 0.9 m above the floor under the ring's centre rather than horizontally
  (with the panel's field of view a horizontal camera at 1.4 m, 2 m away, cuts off the feet);
* the body counts too: a proposal from which the pelvis is hidden costs more than missing the
  hand, and a view from behind the body costs a little, so an open floor gives a three-quarter
  view rather than an arbitrary one;
* the ring shrinks where the scene is nearer than 2 m (the camera stops `margin` short of the
  first wall along its ray from the body), so the camera never stands inside geometry;
  proposals that would stand nearer than `min_radius` are kept only when nothing else is left;
* the splines are monotone cubic (PCHIP): a cubic spline through the keyframes, C1, that does
  not overshoot a keyframe angle, so the camera never swings past where it is going.

Rays go against the scene's mesh when there is one (`MeshRays`), else against its occupancy
grid (`GridRays`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.ndimage as ndi
from scipy.interpolate import PchipInterpolator

from motiongen.export.camera import CAM_VIEW, CameraPath, PinholeCamera
from motiongen.skeleton import BODY_JOINT_NAMES, HEAD, LEFT_HIP, PELVIS, RIGHT_HIP

ARMS = tuple(tuple(BODY_JOINT_NAMES.index(f"{side}_{part}") for part in ("shoulder", "elbow", "wrist"))
             for side in ("left", "right"))                     # (2, 3): the joints counted per hand
RIGHT = 1


@dataclass(frozen=True)
class RingSettings:
    height: float = 1.4          # camera above the floor (m)
    radius: float = 2.0          # the ring's radius (m), less where the scene is nearer
    key_every: int = 30          # frames between keyframes
    proposals: int = 20          # camera angles per keyframe
    hand_object_m: float = 0.20  # a hand farther than this from every dynamic object is not interacting
    visible_m: float = 0.10      # a ray's first scene hit this near the joint still sees it
    look_height: float = 0.9     # from the full radius the camera looks at this height above the centre
    focal: float = 1.0           # wider than the follow camera's 1.6: the whole body and its surroundings at 2 m
    min_focal: float = 0.6       # the widest lens, where walls bring the camera nearer than `radius`
    margin: float = 0.25         # the camera stays this far in front of the first wall
    min_radius: float = 0.8      # nearer than this the body fills the panel
    smooth_s: float = 0.5        # the ring's centre: the pelvis smoothed over this (Gaussian sigma, s)
    rotation_weight: float = 1.0  # cost of camera travel round the body: times (θ + θ²), θ in radians
    hand_weight: float = 1.0     # reward of a keyframe whose proposal covers the interaction
    body_weight: float = 3.0     # reward of a keyframe whose proposal sees the pelvis
    back_weight: float = 2.0     # cost of looking at the body's back (times the cosine)


class GridRays:
    """First hits of segments against an `OccupancyGrid` (space outside the grid is free)."""

    def __init__(self, grid):
        self.grid = grid
        self.step = grid.voxel_size / 2

    def first_hit(self, origins: np.ndarray, ends: np.ndarray) -> np.ndarray:
        """(N,) distance from each origin (N, 3) to the first occupied point on its way to
        `ends` (N, 3); inf where the segment is free."""
        seg = ends - origins                                                                  # (N, 3)
        length = np.linalg.norm(seg, axis=-1)                                                 # (N,)
        n = max(2, int(math.ceil(length.max(initial=0.0) / self.step)) + 1)
        s = np.linspace(0.0, 1.0, n)                                                          # (n,)
        pts = origins[:, None] + s[None, :, None] * seg[:, None]                              # (N, n, 3)
        occ = self.grid.occupied(pts, outside=False)                                          # (N, n)
        first = np.argmax(occ, axis=1)
        return np.where(occ.any(1), s[first] * length, np.inf)


class MeshRays:
    """First hits of segments against a triangle mesh (trimesh's ray queries)."""

    def __init__(self, mesh):
        self.mesh = mesh

    def first_hit(self, origins: np.ndarray, ends: np.ndarray) -> np.ndarray:
        seg = ends - origins
        length = np.linalg.norm(seg, axis=-1)
        out = np.full(len(origins), np.inf)
        if not len(origins):
            return out
        loc, ray, _ = self.mesh.ray.intersects_location(origins, seg / np.maximum(length, 1e-9)[:, None])
        if not len(ray):
            return out
        d = np.linalg.norm(np.reshape(loc, (-1, 3)) - origins[ray], axis=-1)                 # (H,)
        np.minimum.at(out, ray, d)
        return np.where(out <= length, out, np.inf)


def visible(rays, eyes: np.ndarray, points: np.ndarray, cams: list[PinholeCamera], near: float = 0.10) -> np.ndarray:
    """(P, N) bool: point n (P, N, 3) seen from camera p (eyes (P, 3)): inside its image and the
    ray's first scene hit within `near` of the point, or none."""
    P, N = points.shape[:2]
    inview = np.stack([c.in_view(points[p], CAM_VIEW) for p, c in enumerate(cams)])          # (P, N)
    o = np.repeat(eyes, N, axis=0)                                                            # (P*N, 3)
    e = points.reshape(-1, 3)
    hit = rays.first_hit(o, e).reshape(P, N)
    dist = np.linalg.norm(points - eyes[:, None], axis=-1)                                    # (P, N)
    return inview & (hit >= dist - near)


def acting_hands(joints: np.ndarray, objects: np.ndarray | None, near: float = 0.20) -> tuple[np.ndarray, np.ndarray]:
    """Per frame of joints (T, J, 3): the interacting side (T,) (0 left, 1 right: the wrist nearer
    a dynamic object, the right beyond `near`) and whether it interacts (T,). objects: (T, N, 3)
    or (N, 3) points on the dynamic objects, or None."""
    T = len(joints)
    if objects is None or not np.size(objects):
        return np.full(T, RIGHT), np.zeros(T, bool)
    obj = np.broadcast_to(objects, (T, *np.shape(objects)[-2:]))                              # (T, N, 3)
    wrists = joints[:, [ARMS[0][-1], ARMS[1][-1]]]                                            # (T, 2, 3)
    d = np.stack([np.linalg.norm(obj - wrists[:, h:h + 1], axis=-1).min(1) for h in (0, 1)], -1)   # (T, 2)
    acting = d.min(1) <= near
    return np.where(acting, d.argmin(1), RIGHT), acting


def ring_centre(joints: np.ndarray, fps: float, smooth_s: float) -> np.ndarray:
    """(T, 2) the pelvis x, z smoothed over time (Gaussian, sigma smooth_s seconds)."""
    xz = joints[:, PELVIS][:, [0, 2]].astype(np.float64)
    sigma = smooth_s * fps
    return ndi.gaussian_filter1d(xz, sigma, axis=0, mode="nearest") if sigma > 0 and len(xz) > 1 else xz


def ring_radius(rays, centre: np.ndarray, angle: np.ndarray, s: RingSettings) -> np.ndarray:
    """(N,) the ring's radius at centres (N, 2) and angles (N,): `radius`, or `margin` short of
    the first wall along the ray from the centre at camera height (never inside geometry)."""
    o = np.stack([centre[:, 0], np.full(len(centre), s.height), centre[:, 1]], -1)          # (N, 3)
    d = np.stack([np.sin(angle), np.zeros_like(angle), np.cos(angle)], -1)
    hit = rays.first_hit(o, o + (s.radius + s.margin) * d)                                   # (N,)
    return np.minimum(s.radius, np.maximum(hit - s.margin, 0.5 * hit))


def lens(radius: np.ndarray, s: RingSettings) -> np.ndarray:
    """(N,) the focal length at ring radii (N,): nearer than `radius` the lens widens in
    proportion, so the body keeps its size in the image, down to `min_focal`."""
    return np.maximum(s.focal * radius / s.radius, s.min_focal)


def ring_cameras(centre: np.ndarray, angle: np.ndarray, radius: np.ndarray, s: RingSettings) -> tuple[np.ndarray, np.ndarray]:
    """Eyes (N, 3) and targets (N, 3) of ring cameras at centres (N, 2), angles and radii (N,).
    The camera looks at `look_height` from the full radius and keeps that pitch nearer in (a
    near camera pitched as steeply would look at the feet and cut off the head)."""
    eye = np.stack([centre[:, 0] + radius * np.sin(angle), np.full(len(angle), s.height),
                    centre[:, 1] + radius * np.cos(angle)], -1)
    look = s.height - (s.height - s.look_height) * radius / s.radius                        # (N,)
    target = np.stack([centre[:, 0], look, centre[:, 1]], -1)
    return eye, target


def keyframe_costs(joints: np.ndarray, centre: np.ndarray, keys: np.ndarray, side: np.ndarray, acting: np.ndarray,
                   rays, s: RingSettings) -> np.ndarray:
    """(K, P) cost of each proposal at each keyframe (lower is better)."""
    angles = 2 * np.pi * np.arange(s.proposals) / s.proposals                               # (P,)
    across = joints[:, LEFT_HIP] - joints[:, RIGHT_HIP]
    facing = np.arctan2(-across[:, 2], across[:, 0])                                         # (T,) the body's front, as an angle
    cost = np.zeros((len(keys), s.proposals))
    for k, t in enumerate(keys):
        c = np.repeat(centre[t][None], s.proposals, 0)                                       # (P, 2)
        r = ring_radius(rays, c, angles, s)                                                  # (P,)
        eye, target = ring_cameras(c, angles, r, s)
        cams = [PinholeCamera(e, g, f) for e, g, f in zip(eye, target, lens(r, s))]
        body = visible(rays, eye, np.repeat(joints[t, [PELVIS, HEAD]][None], s.proposals, 0), cams, s.visible_m)
        cost[k] -= s.body_weight * body[:, 0] + 0.5 * s.body_weight * body[:, 1]
        if acting[t]:
            arm = np.repeat(joints[t, list(ARMS[side[t]])][None], s.proposals, 0)             # (P, 3, 3)
            count = visible(rays, eye, arm, cams, s.visible_m).sum(1)                         # (P,)
            # The threshold adapts: the best proposal's count, unless no proposal sees any.
            if count.max() > 0:
                cost[k] -= s.hand_weight * (count >= count.max())
        cost[k] += s.back_weight * np.maximum(0.0, -np.cos(angles - facing[t]))
        cost[k] += 10.0 * (s.body_weight + s.hand_weight) * (r < s.min_radius)
    return cost


def best_sequence(cost: np.ndarray, angles: np.ndarray, rotation_weight: float) -> np.ndarray:
    """(K,) proposal index per keyframe minimising the keyframes' costs (K, P) plus
    rotation_weight times (θ + θ²) for the angle θ (radians) turned between keyframes
    (dynamic programming)."""
    turn = np.abs(np.angle(np.exp(1j * (angles[None, :] - angles[:, None]))))              # (P, P) radians
    # Squared too: a half turn costs more than two quarter turns, so big turns spread over keyframes.
    turn = turn + turn ** 2
    acc = cost[0].copy()
    back = np.zeros(cost.shape, np.int64)
    for k in range(1, len(cost)):
        total = acc[:, None] + rotation_weight * turn                                         # (from, to)
        back[k] = np.argmin(total, axis=0)
        acc = total[back[k], np.arange(len(angles))] + cost[k]
    seq = np.empty(len(cost), np.int64)
    seq[-1] = int(np.argmin(acc))
    for k in range(len(cost) - 1, 0, -1):
        seq[k - 1] = back[k, seq[k]]
    return seq


def interpolate_angles(keys: np.ndarray, key_angles: np.ndarray, T: int) -> np.ndarray:
    """(T,) the angle per frame: keyframe angles unwrapped (each step the short way round) and
    joined by a monotone cubic spline, constant beyond the first and last keyframes."""
    a = np.unwrap(key_angles)
    if len(keys) < 2:
        return np.full(T, a[0] if len(a) else 0.0)
    return PchipInterpolator(keys, a)(np.clip(np.arange(T), keys[0], keys[-1]))


def adaptive_path(joints: np.ndarray, fps: float, rays, objects: np.ndarray | None = None,
                  settings: RingSettings = RingSettings()) -> CameraPath:
    """The camera path (one eye and target per frame) for joints (T, J, 3) at `fps` in a scene
    whose `rays` answer first hits (`GridRays`, `MeshRays`); objects: points on the dynamic
    objects, (T, N, 3) or (N, 3), or None."""
    s = settings
    T = len(joints)
    centre = ring_centre(joints, fps, s.smooth_s)                                            # (T, 2)
    keys = np.unique(np.r_[np.arange(0, T, s.key_every), T - 1])                             # (K,)
    side, acting = acting_hands(joints, objects, s.hand_object_m)
    angles = 2 * np.pi * np.arange(s.proposals) / s.proposals
    seq = best_sequence(keyframe_costs(joints, centre, keys, side, acting, rays, s), angles, s.rotation_weight)
    angle = interpolate_angles(keys, angles[seq], T)                                         # (T,)
    radius = ring_radius(rays, centre, angle, s)                                             # (T,) the wall limit per frame
    # Smooth the radius where a wall or door frame passes (no sudden zoom), staying in front of walls.
    calm = ndi.gaussian_filter1d(ndi.minimum_filter1d(radius, max(1, int(fps)), mode="nearest"), fps / 4,
                                 mode="nearest") if T > 1 else radius
    r = np.minimum(calm, radius)
    eye, target = ring_cameras(centre, angle, r, s)
    return CameraPath(eye, target, lens(r, s), "adaptive")
