"""Motion-quality metrics: pure numpy functions on joint positions.

Inputs are joint positions (T, J, 3) in metres, world y-up, SMPL-X body joint order
(`motiongen.skeleton.BODY`; the 24-joint set shares the first 22), with `fps` where time
matters. Each function's docstring gives its definition and source; docs/metrics.md lists
them together with what they do not capture.
"""

from __future__ import annotations

from itertools import combinations
from typing import Callable, Mapping, NamedTuple, Sequence

import numpy as np
from scipy.ndimage import uniform_filter1d

from motiongen.geometry import facing_yaw
from motiongen.scene.distance_field import surface_distance as grid_surface_distance
from motiongen.scene.occupancy import OccupancyGrid
from motiongen.skeleton import BODY_JOINT_NAMES, LEFT_FOOT_JOINTS, PELVIS, RIGHT_FOOT_JOINTS

# GMD evaluates the two toe joints ("left_foot", "right_foot" = SMPL-X 10, 11) only.
TOE_JOINTS = (LEFT_FOOT_JOINTS[1], RIGHT_FOOT_JOINTS[1])


def _joints(x, name: str = "joints", ndim: int = 3) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != ndim or a.shape[-1] != 3:
        raise ValueError(f"{name}: expected {ndim}-D array ending in 3, got shape {a.shape}")
    return a


# ---------------------------------------------------------------------------------------
# Foot skating


def foot_skating_frames(joints, fps: float, height_thresh: float = 0.05, speed_thresh: float = 0.5,
                        window: int = 5, foot_joints: Sequence[int] = TOE_JOINTS) -> np.ndarray:
    """(T-1,) bool: transition t -> t+1 skates. See `foot_skating_ratio`."""
    j = _joints(joints)[:, list(foot_joints)]                         # (T, F, 3)
    speed = np.linalg.norm(np.diff(j[..., [0, 2]], axis=0), axis=-1) * fps   # (T-1, F) m/s, horizontal
    # GMD averages with zero padding at the clip ends (mode="constant"); kept for comparability.
    speed_avg = uniform_filter1d(speed, size=window, axis=0, mode="constant", origin=0)
    low = j[..., 1] < height_thresh                                    # (T, F)
    contact = low[:-1] & low[1:]                                       # (T-1, F) low in both frames
    skating = contact & (speed > speed_thresh) & (speed_avg > speed_thresh)
    return skating.any(axis=1)


def foot_skating_ratio(joints, fps: float, height_thresh: float = 0.05, speed_thresh: float = 0.5,
                       window: int = 5, foot_joints: Sequence[int] = TOE_JOINTS) -> float:
    """Fraction of frame transitions in which a foot skates (Guided Motion Diffusion,
    Karunratanakul et al. 2023, `calculate_skating_ratio`; also used by OmniControl).

    A foot joint is in contact on the transition t -> t+1 when its height y is below
    `height_thresh` in both frames; it skates when, in contact, its horizontal (x, z) speed
    exceeds `speed_thresh` both instantaneously and averaged over `window` transitions
    (zero-padded at the ends, as GMD does). A transition counts when any foot joint skates.
    Ratio over the T-1 transitions. Default joints: the two toe joints (SMPL-X "left_foot",
    "right_foot"), as in GMD; pass `motiongen.skeleton.FOOT_JOINTS` to add the ankles.
    Heights are measured from y = 0, so the floor must be at 0 (our import puts the
    clip's lowest joint there, the HumanML3D convention GMD's thresholds assume).
    """
    frames = foot_skating_frames(joints, fps, height_thresh, speed_thresh, window, foot_joints)
    return float(frames.mean()) if frames.size else 0.0


# ---------------------------------------------------------------------------------------
# One body: bone lengths, grounded feet


def bone_lengths(joints, parents: Sequence[int]) -> np.ndarray:
    """(T, B) length (m) of every bone (joint j > 0 to its parent), in joint order."""
    j = _joints(joints)
    kids = [c for c, p in enumerate(parents) if p >= 0]
    return np.linalg.norm(j[:, kids] - j[:, [parents[c] for c in kids]], axis=-1)


class BoneConsistency(NamedTuple):
    cv_median: float       # median over bones of std / mean of its length over the frames
    cv_max: float          # the worst bone's coefficient of variation
    max_deviation: float   # largest |length - median length| / median length over bones and frames
    worst_bone: int        # child joint index of the bone with the largest deviation


def bone_consistency(joints, parents: Sequence[int]) -> BoneConsistency:
    """How well a motion keeps one body: per bone, the coefficient of variation of its length
    over the T frames, and its largest relative deviation from its own median length. A rigid
    skeleton gives 0 and 0; real mocap through our importer gives < 0.005."""
    L = bone_lengths(joints, parents)                                   # (T, B)
    med = np.median(L, axis=0)                                          # (B,)
    cv = L.std(axis=0) / np.maximum(L.mean(axis=0), 1e-9)
    dev = np.abs(L - med).max(axis=0) / np.maximum(med, 1e-9)          # (B,)
    kids = [c for c, p in enumerate(parents) if p >= 0]
    return BoneConsistency(float(np.median(cv)), float(cv.max()), float(dev.max()), int(kids[int(np.argmax(dev))]))


def grounded_slide(joints, fps: float, height_thresh: float = 0.05, foot_joints: Sequence[int] = TOE_JOINTS,
                   floor_y: float = 0.0) -> float:
    """Median horizontal speed (m/s) of the foot joints while on the floor: over every
    (foot joint, transition t -> t+1) with the joint below `floor_y + height_thresh` in both
    frames, the median of |Δ(x, z)|·fps. A planted foot gives 0; a foot dragged along the
    floor at v m/s gives v. NaN when no foot ever comes down (a floating body). Unlike
    `foot_skating_ratio` it has no speed threshold, so it also sees slow creep."""
    j = _joints(joints)[:, list(foot_joints)]                          # (T, F, 3)
    speed = np.linalg.norm(np.diff(j[..., [0, 2]], axis=0), axis=-1) * fps   # (T-1, F)
    low = j[..., 1] < floor_y + height_thresh
    on = low[:-1] & low[1:]
    return float(np.median(speed[on])) if on.any() else float("nan")


def pelvis_velocity(joints, fps: float) -> np.ndarray:
    """(T-2, 2) the pelvis's horizontal velocity (x, z; m/s) at frames 1..T-2 of joints (T, J, 3),
    by central differences (empty below 3 frames)."""
    j = _joints(joints)
    return (j[2:, PELVIS] - j[:-2, PELVIS])[:, [0, 2]] * fps / 2 if len(j) >= 3 else np.zeros((0, 2))


def walking_frames(joints, fps: float, min_speed: float = 0.5) -> np.ndarray:
    """(T,) bool: the frames of joints (T, J, 3) where the pelvis moves faster than min_speed m/s
    (`pelvis_velocity`; never the first or last frame)."""
    moving = np.zeros(len(joints), bool)
    moving[1:-1] = np.linalg.norm(pelvis_velocity(joints, fps), axis=-1) > min_speed
    return moving


def heading_off_travel_angles(joints, fps: float, min_speed: float = 0.5) -> np.ndarray:
    """Angles (degrees, in [0, 180]) between where a body faces (`geometry.facing_yaw`, from its
    hips) and where its pelvis moves (horizontal velocity by central differences), on the frames
    of joints (T, J, 3) where it moves faster than min_speed m/s. People walk facing where they
    go (the synthetic data: 0.4° median); a body that walks sideways is off by tens of degrees
    while its bones and feet can be perfect."""
    j = _joints(joints)
    if len(j) < 3:
        return np.zeros(0)
    v = pelvis_velocity(j, fps)                                                              # (T-2, 2)
    speed = np.linalg.norm(v, axis=-1)
    yaw = facing_yaw(j[1:-1])                                                                # (T-2,)
    forward = np.stack([np.sin(yaw), np.cos(yaw)], -1)                                      # (T-2, 2) x, z
    moving = speed > min_speed
    cos = (forward[moving] * v[moving]).sum(-1) / speed[moving]
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def heading_off_travel(joints, fps: float, min_speed: float = 0.5) -> float:
    """Median of `heading_off_travel_angles` (degrees); NaN when the body never moves faster
    than min_speed m/s."""
    a = heading_off_travel_angles(joints, fps, min_speed)
    return float(np.median(a)) if a.size else float("nan")


# (hip, knee, ankle) of each leg in the SMPL-X body joints.
LEGS = ((1, 4, 7), (2, 5, 8))


def walking_knee_angle(joints, fps: float, min_speed: float = 0.5) -> float:
    """Median over the frames where the pelvis moves faster than min_speed m/s of the two knees'
    mean angle (degrees; 180 = straight legs) of joints (T, J, 3): how upright a body walks.
    The synthetic data's validation sequences read 134-145° (median 141°). A body put where a shrinking
    network's pelvis is walks crouched on legs of its own length, which no bone or foot figure
    sees. NaN when the body never moves that fast."""
    j = _joints(joints)
    w = j[walking_frames(j, fps, min_speed)]                                                 # (N, J, 3)
    return float(np.median(knee_angles(w))) if len(w) else float("nan")


def leg_knee_angles(joints) -> np.ndarray:
    """(T, 2) each knee's angle between thigh and shin (degrees; 180 = straight) of joints
    (T, J, 3), frame by frame, in the order of `LEGS` (left, right)."""
    j = _joints(joints)
    angles = []
    for hip, knee, ankle in LEGS:
        u, v = j[:, hip] - j[:, knee], j[:, ankle] - j[:, knee]
        cos = (u * v).sum(-1) / np.maximum(np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1), 1e-12)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.stack(angles, 1)


def knee_angles(joints) -> np.ndarray:
    """(T,) the two knees' mean angle (`leg_knee_angles`), frame by frame."""
    return leg_knee_angles(joints).mean(1)


# The pelvis at least this far above the lower toe: the body is on its feet (standing ~0.9 m,
# seated ~0.45 m; lying on a bed ~0).
UPRIGHT_M = 0.3


def lower_toe_height(joints, floor_y: float = 0.0, foot_joints: Sequence[int] = TOE_JOINTS) -> float:
    """Median over the frames of joints (T, J, 3) where the body is on its feet (the pelvis at
    least `UPRIGHT_M` above the lower toe) of the lower toe joint's height above the floor (m):
    how high a body carries its feet. The data walks with it about 2 cm up (the toe joint sits
    above the sole); a body lifted over the skating figure's 5 cm line cannot skate by that
    figure, so this one sits beside it. A body lying on a bed carries its toes at the bed's
    height, which says nothing of floating feet: those frames are left out. NaN for no frames
    on its feet."""
    j = _joints(joints)
    toe = j[:, list(foot_joints), 1].min(1)                                                  # (T,)
    on_feet = j[:, PELVIS, 1] - toe >= UPRIGHT_M
    return float(np.median(toe[on_feet] - floor_y)) if on_feet.any() else float("nan")


def body_metrics(joints, fps: float, parents: Sequence[int]) -> dict:
    """The one-body figures of a motion (T, J, 3), as every table reports them: bone-length CV
    (median over bones) and largest relative deviation, grounded-toe median slide (m/s, NaN
    when no foot comes down), the foot skating ratio, the lower toe's median height (m) and the
    median angle between where the walking body faces and where it goes and its median walking
    knee angle (degrees, NaN when it never walks)."""
    b = bone_consistency(joints, parents)
    return {"bone_cv": b.cv_median, "bone_max_dev": b.max_deviation, "slide_mps": grounded_slide(joints, fps),
            "foot_skating": foot_skating_ratio(joints, fps), "toe_height_m": lower_toe_height(joints),
            "heading_deg": heading_off_travel(joints, fps), "knee_walk_deg": walking_knee_angle(joints, fps)}


def finite_mean(xs) -> float:
    """Mean of the finite values among xs (None and NaN skipped); NaN when there are none."""
    v = np.asarray([x for x in xs if x is not None and np.isfinite(x)], np.float64)
    return float(v.mean()) if v.size else float("nan")


def finite_median(xs) -> float:
    """Median of the finite values among xs (grounded slide over motions: a floating motion is
    NaN, not zero); NaN when there are none."""
    v = np.asarray([x for x in xs if x is not None and np.isfinite(x)], np.float64)
    return float(np.median(v)) if v.size else float("nan")


# ---------------------------------------------------------------------------------------
# Goal reaching


def goal_distances(joints, goals, arrival_frames: Sequence[int] | None = None) -> np.ndarray:
    """(G,) ground-plane distance (m) of the pelvis (x, z) to each goal on arrival.

    goals: (G, 2) as (x, z) or (G, 3) world points (y ignored). With `arrival_frames` (G,),
    the distance at those frames. Without, goals are visited in order: goal g's arrival is
    the frame of closest approach at or after goal g-1's arrival (frame 0 for the first), so a
    path that passes near a later goal early does not get credit for it.
    """
    pelvis = _joints(joints)[:, PELVIS][:, [0, 2]]                     # (T, 2)
    goals = np.asarray(goals, np.float64)
    goals = goals[:, [0, 2]] if goals.shape[-1] == 3 else goals        # (G, 2)
    if arrival_frames is not None:
        return np.linalg.norm(pelvis[np.asarray(arrival_frames)] - goals, axis=-1)
    out, start = np.empty(len(goals)), 0
    for g, goal in enumerate(goals):
        d = np.linalg.norm(pelvis[start:] - goal, axis=-1)
        k = int(np.argmin(d))
        out[g], start = d[k], start + k
    return out


def goal_success(distances, thresholds: Sequence[float] = (0.2, 0.5)) -> dict[float, float]:
    """Fraction of goals reached within each threshold (m): {threshold: rate}.
    `distances` may be one (G,) array or a list of them (one per trajectory); all goals pool."""
    d = np.concatenate([np.ravel(x) for x in distances]) if _is_ragged(distances) else np.ravel(distances)
    return {float(t): float((d < t).mean()) if d.size else 0.0 for t in thresholds}


def trajectory_fail_rate(distances: Sequence, threshold: float = 0.5) -> float:
    """Fraction of trajectories that miss any goal: some goal distance >= `threshold` (m).
    `distances`: one (G_i,) array per trajectory (e.g. from `goal_distances`)."""
    if len(distances) == 0:
        return 0.0
    return float(np.mean([bool((np.asarray(d) >= threshold).any()) for d in distances]))


def _is_ragged(x) -> bool:
    return isinstance(x, (list, tuple)) and len(x) > 0 and np.ndim(x[0]) >= 1


# ---------------------------------------------------------------------------------------
# Scene penetration and contact


def scene_penetration(joints, grid: OccupancyGrid, vertices=None, sdf: Callable | None = None) -> dict[str, float]:
    """Penetration of the body into the scene's occupancy.

    A point penetrates when `grid.occupied(point, outside=False)`; the points are the joints
    (T, J, 3) and, when given, vertex samples (T, V, 3). Returns
      frame_ratio: fraction of frames with any penetrating point;
      mean_depth:  mean depth (m) over penetrating points (0 when none);
      max_depth:   deepest penetration (m).
    Depth = -signed distance from `surface_distance(grid)` (or the `sdf` given).
    Joints lie inside the body, so joint-only penetration under-reports contact with surfaces;
    vertices measure the skin. Cf. TRUMANS supplement Fig. A3 (per-vertex penetration stats).
    """
    pts = _joints(joints)
    if vertices is not None:
        pts = np.concatenate([pts, _joints(vertices, "vertices")], axis=1)   # (T, J+V, 3)
    inside = grid.occupied(pts, outside=False)                                # (T, P)
    if not inside.any():
        return {"frame_ratio": 0.0, "mean_depth": 0.0, "max_depth": 0.0}
    sdf = sdf or grid_surface_distance(grid)
    depth = np.maximum(-sdf(pts[inside]), 0.0)
    return {"frame_ratio": float(inside.any(axis=1).mean()), "mean_depth": float(depth.mean()),
            "max_depth": float(depth.max())}


def floor_penetration(joints, floor_y: float = 0.0, tol: float = 0.0) -> dict[str, float]:
    """Joints below the floor: frame_ratio = fraction of frames with any joint below
    `floor_y - tol`; mean_depth / max_depth (m) over the joints below it (0 when none).
    `tol` forgives capture noise; joint centres sit centimetres above the skin, so any joint
    below the floor is a real penetration."""
    y = _joints(joints)[..., 1]                                         # (T, J)
    below = y < floor_y - tol
    if not below.any():
        return {"frame_ratio": 0.0, "mean_depth": 0.0, "max_depth": 0.0}
    depth = floor_y - y[below]
    return {"frame_ratio": float(below.any(axis=1).mean()), "mean_depth": float(depth.mean()),
            "max_depth": float(depth.max())}


# Which joints should touch a surface during an action (any one of them suffices).
DEFAULT_CONTACT_PARTS: dict[str, tuple[str, ...]] = {
    "sit": ("pelvis",),
    "lie down": ("pelvis", "spine1", "spine2", "spine3"),
    "pick up": ("left_wrist", "right_wrist", "left_index1", "right_index1"),
    "mouse": ("left_wrist", "right_wrist", "left_index1", "right_index1"),
    "keyboard": ("left_wrist", "right_wrist", "left_index1", "right_index1"),
    "laptop": ("left_wrist", "right_wrist", "left_index1", "right_index1"),
}
# Joint centre to skin (m), subtracted from the joint's surface distance: a seated pelvis
# joint is ~10 cm above the seat, a wrist joint ~3 cm from the palm. Rough SMPL-X figures.
DEFAULT_SKIN_OFFSET: dict[str, float] = {
    "pelvis": 0.10, "spine1": 0.10, "spine2": 0.10, "spine3": 0.10,
    "left_wrist": 0.03, "right_wrist": 0.03, "left_index1": 0.01, "right_index1": 0.01,
    "left_ankle": 0.07, "right_ankle": 0.07, "left_foot": 0.03, "right_foot": 0.03,
}


def contact_rate(joints, actions, action_names: Sequence[str], surface_distance: Callable | OccupancyGrid,
                 joint_names: Sequence[str] = BODY_JOINT_NAMES,
                 expected_parts: Mapping[str, Sequence[str]] = DEFAULT_CONTACT_PARTS,
                 skin_offset: Mapping[str, float] = DEFAULT_SKIN_OFFSET, thresh: float = 0.02) -> dict[str, float]:
    """Fraction of action-labelled frames in which the expected body part touches a surface.

    joints (T, J, 3) named by `joint_names` (default the 22 body joints; pass the 24-joint
    names to use index fingers); actions (T, A) bool labelled by `action_names`;
    surface_distance: a callable points (N, 3) -> (N,) distance to the nearest surface (e.g.
    `surface_distance(grid, floor_y=0)`), or an OccupancyGrid (its `surface_distance(grid)`).
    A frame labelled with action a is in contact when any joint in `expected_parts[a]` that
    the skeleton has lies within `thresh` of a surface after subtracting its `skin_offset`.
    Returns {action: rate} for each action in both `expected_parts` and `action_names` that
    labels at least one frame, and "all": the rate over all those (frame, action) pairs.
    """
    j = _joints(joints)
    acts = np.asarray(actions, bool)
    if acts.shape != (j.shape[0], len(action_names)):
        raise ValueError(f"actions: expected shape {(j.shape[0], len(action_names))}, got {acts.shape}")
    dist = grid_surface_distance(surface_distance) if isinstance(surface_distance, OccupancyGrid) else surface_distance
    out, hits, total = {}, 0, 0
    for a, name in enumerate(action_names):
        parts = [p for p in expected_parts.get(name, ()) if p in joint_names]
        frames = np.flatnonzero(acts[:, a])
        if not parts or frames.size == 0:
            continue
        idx = [list(joint_names).index(p) for p in parts]
        d = dist(j[frames][:, idx].reshape(-1, 3)).reshape(len(frames), len(idx))   # (Fa, P)
        d = d - np.array([skin_offset.get(p, 0.0) for p in parts])
        ok = (d < thresh).any(axis=1)
        out[name] = float(ok.mean())
        hits, total = hits + int(ok.sum()), total + len(frames)
    out["all"] = hits / total if total else float("nan")
    return out


# ---------------------------------------------------------------------------------------
# Diversity and smoothness


def apd(samples) -> float:
    """Average pairwise distance between K samples (K, T, J, 3) for the same conditions:
    mean over the K(K-1)/2 pairs of the L2 norm of the flattened difference (m). The
    definition of DLow (Yuan & Kitani 2020) and later diverse-prediction work; it grows with
    sqrt(T*J), so compare only runs with equal T and J."""
    s = np.asarray(samples, np.float64)
    if s.ndim != 4 or s.shape[-1] != 3 or s.shape[0] < 2:
        raise ValueError(f"samples: expected (K>=2, T, J, 3), got {s.shape}")
    flat = s.reshape(s.shape[0], -1)
    return float(np.mean([np.linalg.norm(flat[a] - flat[b]) for a, b in combinations(range(len(flat)), 2)]))


def mean_jerk(joints, fps: float) -> float:
    """Mean jerk magnitude (m/s^3): third finite difference of positions times fps^3, norm per
    joint, averaged over joints and the T-3 frames. Lower is smoother; mocap walking at
    30 fps is of order 10^1-10^2."""
    j = _joints(joints)
    if j.shape[0] < 4:
        raise ValueError(f"joints: need at least 4 frames for jerk, got {j.shape[0]}")
    return float(np.linalg.norm(np.diff(j, n=3, axis=0), axis=-1).mean() * fps ** 3)


class SeamJump(NamedTuple):
    seam: float        # largest per-frame displacement across an episode boundary (m)
    elsewhere: float   # median per-frame displacement over the other transitions (m)
    ratio: float       # seam / elsewhere (1 = seams invisible; inf if the motion is otherwise still)


def seam_jump(joints, boundaries: Sequence[int]) -> SeamJump:
    """Discontinuity at the seams of autoregressively stitched episodes.

    Per-frame displacement D_t = max over joints of |x_t - x_{t-1}| (t = 1..T-1): the fastest
    joint, so one popping hand shows. `boundaries` are the first frames of new episodes; the
    seam value is max_b D_b, compared with the median of D_t elsewhere.
    """
    j = _joints(joints)
    D = np.linalg.norm(np.diff(j, axis=0), axis=-1).max(axis=1)        # (T-1,); D[t-1] is t-1 -> t
    b = np.asarray([x for x in boundaries if 1 <= x < j.shape[0]], int)
    if b.size == 0:
        raise ValueError(f"boundaries: need at least one frame index in [1, {j.shape[0] - 1}], got {list(boundaries)}")
    mask = np.zeros(len(D), bool)
    mask[b - 1] = True
    seam = float(D[mask].max())
    elsewhere = float(np.median(D[~mask])) if (~mask).any() else float("nan")
    ratio = seam / elsewhere if elsewhere > 0 else (float("inf") if seam > 0 else 1.0)
    return SeamJump(seam, elsewhere, ratio)


# ---------------------------------------------------------------------------------------
# Power-spectrum KL (LEMO supplement B.3, after Hernandez et al. 2019)


def _mean_power_spectrum(motions: list[np.ndarray], fps: float, length: int) -> np.ndarray:
    """PS(C|f), Eq. 10, normalised over frequency: (E, F) with E = length - 2 FFT bins."""
    ps = []
    for m in motions:
        acc = np.diff(m[:length], n=2, axis=0).reshape(length - 2, -1) * fps ** 2   # (E, F), F = 3J
        ps.append(np.abs(np.fft.fft(acc, axis=0)) ** 2)                            # PS(s_f) = |FFT(s_f)|^2
    mean = np.mean(ps, axis=0)
    return mean / np.maximum(mean.sum(axis=0, keepdims=True), np.finfo(float).tiny)


def pskl(a, b, fps: float, length: int | None = None, eps: float = 1e-12) -> tuple[float, float]:
    """Power-spectrum KL divergence between two sets of motions: (PSKL(a, b), PSKL(b, a)).

    LEMO (Zhang et al. 2021) supplement B.3, Eqs. 10-11: features are the x, y, z
    accelerations of every joint (F = 3J); each feature's power spectrum |FFT(s_f)|^2 is
    averaged over the N sequences of a set (Eq. 10) and normalised over frequency; PSKL(C, D)
    = 1/F sum_f sum_e PS(C|f)_e log(PS(C|f)_e / PS(D|f)_e) (Eq. 11). KL is asymmetric, so both
    directions are returned.

    a, b: (N, T, J, 3) arrays or lists of (T_i, J, 3); both sets must share fps and J. The FFT
    needs one length: every sequence is cut to its first `length` frames (default: the
    shortest sequence in either set). Accelerations are second differences times fps^2 (the
    scale cancels in the normalisation). The full two-sided FFT is used, as the formula
    reads; for real input this equals the one-sided spectrum with folded bins. `eps` is added
    to the normalised spectra before the log so empty bins stay finite.
    """
    A = [_joints(m, "a") for m in a]
    B = [_joints(m, "b") for m in b]
    if not A or not B:
        raise ValueError("pskl: both sets need at least one motion")
    if {m.shape[1] for m in A + B} != {A[0].shape[1]}:
        raise ValueError("pskl: all motions need the same number of joints")
    length = length or min(m.shape[0] for m in A + B)
    if length < 4 or any(m.shape[0] < length for m in A + B):
        raise ValueError(f"pskl: need sequences of at least max(4, length={length}) frames")
    pa, pb = _mean_power_spectrum(A, fps, length), _mean_power_spectrum(B, fps, length)   # (E, F)
    pa, pb = pa + eps, pb + eps
    pa, pb = pa / pa.sum(axis=0), pb / pb.sum(axis=0)
    kl_ab = float(np.mean(np.sum(pa * np.log(pa / pb), axis=0)))
    kl_ba = float(np.mean(np.sum(pb * np.log(pb / pa), axis=0)))
    return kl_ab, kl_ba


__all__ = ["TOE_JOINTS", "bone_lengths", "BoneConsistency", "bone_consistency", "grounded_slide",
           "heading_off_travel_angles", "lower_toe_height", "heading_off_travel", "walking_knee_angle", "knee_angles",
           "leg_knee_angles", "pelvis_velocity", "walking_frames",
           "body_metrics",
           "finite_mean", "finite_median", "foot_skating_frames", "foot_skating_ratio", "goal_distances", "goal_success",
           "trajectory_fail_rate", "scene_penetration", "floor_penetration",
           "DEFAULT_CONTACT_PARTS", "DEFAULT_SKIN_OFFSET", "contact_rate", "apd", "mean_jerk",
           "SeamJump", "seam_jump", "pskl"]
