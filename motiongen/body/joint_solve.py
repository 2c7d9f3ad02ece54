"""The final solve's objective, solved exactly in joint space.

`fit.refine` minimises its objective over rotations with L-BFGS; in the sampler's final solve
that takes 80 iterations of forward kinematics and its backward over the whole motion (most of
`sample`'s time with a few-step sampler), and still stops short of the minimum. Without the
rigid-body constraint the same terms are a quadratic in the joint positions, and separable:
each joint coordinate's T values interact only with their own neighbours in time. So
`solve_joints` minimises, per joint coordinate, with the weights of `RefineConfig`:

    w_joints        · mean ‖Y − X‖²                        follow the (projected) prediction
  + w_smooth_joints · mean ‖Y_{t-1} − 2Y_t + Y_{t+1}‖²     joint acceleration (w_smooth_contact
                                                          for the contact joints, if set)
  + w_contact       · mean over planted entries of ‖Y_t − c_span‖²  (foot lock: c_span is the
                                                          span's mean, upwards its held height)
  + w_reach         · weighted mean of ‖Y_f,j − p‖²         (a hand on an object, a seated pelvis)
  + w_floor         · floor_y − y, squared, where a joint centre is below the floor
  + w_clearance     · X_y − y, squared, where a swinging foot joint is below its prediction

one sparse symmetric positive definite system of T unknowns per joint coordinate (banded: the
acceleration term spans five frames, a lock span couples its own frames). The two one-sided
terms are active-set constraints: solve, switch on the entries that violate them, solve again
until the set stops changing (7-9 solves of the heights of the joints whose set changed, on
sampled motions). The minimum is exact where L-BFGS stops early, so the sampler gives this
solve its own, weaker acceleration weights (`sampling.assemble.solve_weights`).

`solve.MotionBody.solve_joint_space` then moves the trunk with the feet the lock holds
(`follow_locks`) and where a held limb's end is out of its reach (`into_reach`), and puts the
result on the body analytically (bone directions, two-bone limbs: ankles, wrists and pelvis go
where this solve put them). The rotation terms of `refine`
(rotation acceleration, prior) have no joint-space form: the twist comes from the episodes'
rotations, interpolated.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solveh_banded
from scipy.ndimage import gaussian_filter1d

from motiongen.body.fit import RefineConfig
from motiongen.body.limbs import LIMBS
from motiongen.spans import true_runs

ACTIVE_SET_ROUNDS = 20     # solves at most; on sampled motions the set settles in 7-9


def solve_joints(X: np.ndarray, cfg: RefineConfig, planted: np.ndarray | None = None, contact_joints=(),
                 reach: tuple | None = None, planted_heights: np.ndarray | None = None) -> np.ndarray:
    """Joints Y (T, 22, 3) float64 minimising the objective above for targets X (T, 22, 3).

    planted (T, C) bool flags `contact_joints` (C,) as planted (lock spans; the others swing,
    for the clearance term); None: no lock and no clearance. reach = (frames (N,), joints (N,),
    points (N, 3), weights (N,)) or None. With cfg.lock_height a lock span is held at the mean
    over the span of planted_heights (T, C) (None: of X's heights), as `fit.lock_loss` does:
    upwards the lock is then a pull towards a fixed height, not a rank-one part."""
    X = np.asarray(X, np.float64)
    T, J = X.shape[:2]
    if T < 3:
        return X.copy()
    # Each term's weight per squared entry, all multiplied by J·T (the joint term's count), in
    # lower banded storage (3, T): the joint term's diagonal plus the acceleration term's DᵀD.
    n = J * T
    dtd = _dtd_banded(T)
    per_acc = n / (J * (T - 2))                         # the acceleration term's mean, per entry
    base = np.zeros((3, T))
    base[0] = cfg.w_joints
    feet = base + (cfg.w_smooth_joints if cfg.w_smooth_contact is None else cfg.w_smooth_contact) * per_acc * dtd
    base += cfg.w_smooth_joints * per_acc * dtd
    contact_joints = list(contact_joints)
    bases = [feet if j in contact_joints else base for j in range(J)]     # (3, T) per joint
    diag = np.zeros((J, T))                             # reach and lock diagonals, per joint
    rhs = cfg.w_joints * X.transpose(1, 2, 0).copy()    # (J, 3, T)
    planted = None if planted is None else np.asarray(planted, bool)
    locks, locks_y, held = _lock_terms(X, cfg, planted, contact_joints, planted_heights, n, diag)
    if reach is not None and cfg.w_reach:
        f, jj, p, w = (np.asarray(a) for a in reach)
        w = cfg.w_reach * n * w.astype(np.float64) / max(float(w.sum()), 1e-9)
        np.add.at(diag, (jj, f), w)
        np.add.at(rhs, (jj, slice(None), f), w[:, None] * p)
    # Horizontal coordinates: no one-sided terms, solved once.
    Y = np.empty((T, J, 3))
    Y[:, :, [0, 2]] = _solve_joints(range(J), bases, diag, locks, rhs[:, [0, 2]].transpose(0, 2, 1)).transpose(1, 0, 2)
    # Heights: the floor and the swinging feet's clearance are one-sided (active where violated).
    bound_w = np.zeros((J, T))
    bound_y = np.zeros((J, T))
    if cfg.w_floor:
        bound_w[:] = cfg.w_floor * n / T
        bound_y[:] = cfg.floor_y
    swing_w = np.zeros((J, T))
    if planted is not None and cfg.w_clearance and len(contact_joints):
        swing = ~planted                                                                 # (T, C)
        w = cfg.w_clearance * n / max(int(swing.sum()), 1)
        for c, j in enumerate(contact_joints):
            swing_w[j] = np.where(swing[:, c], w, 0.0)
    floor_on = np.zeros((J, T), bool)
    swing_on = np.zeros((J, T), bool)
    todo = range(J)
    # Semismooth Newton on the hinges: each solve's violated entries are the next one's active
    # set; only the joints whose set changed are solved again.
    for _ in range(ACTIVE_SET_ROUNDS):
        fw = np.where(floor_on, bound_w, 0.0)                                           # (J, T)
        sw = np.where(swing_on, swing_w, 0.0)
        b = rhs[:, 1] + held + fw * bound_y + sw * X[:, :, 1].T                             # (J, T)
        todo = list(todo)
        Y[:, todo, 1] = _solve_joints(todo, bases, diag + fw + sw, locks_y, b[:, :, None])[..., 0].T
        new_floor = (Y[:, :, 1].T < bound_y) & (bound_w > 0)
        new_swing = (Y[:, :, 1].T < X[:, :, 1].T) & (swing_w > 0)
        todo = np.nonzero((new_floor != floor_on).any(1) | (new_swing != swing_on).any(1))[0]
        floor_on, swing_on = new_floor, new_swing
        if not len(todo):
            break
    return Y


def _lock_terms(X: np.ndarray, cfg: RefineConfig, planted: np.ndarray | None, contact_joints: list,
                planted_heights: np.ndarray | None, n: int, diag: np.ndarray) -> tuple[dict, dict, np.ndarray]:
    """The foot lock's parts of the systems of `solve_joints` (targets X (T, J, 3), n its joint
    term's count): each lock span's weight added to `diag` (J, T) in place; returns (locks:
    joint -> (span indicators (T, k), weight per span (k,)) for the rank-one parts across the
    floor, the same upwards ({} where spans are held at a height: cfg.lock_height), the
    held heights' right-hand side (J, T))."""
    T, J = X.shape[:2]
    locks: dict[int, tuple] = {}
    held = np.zeros((J, T))
    if planted is None or not len(contact_joints) or not cfg.w_contact or not planted.any():
        return locks, locks, held
    w = cfg.w_contact * n / planted.sum()
    H = X[:, list(contact_joints), 1] if planted_heights is None else np.asarray(planted_heights, np.float64)
    for c, j in enumerate(contact_joints):
        spans = true_runs(planted[:, c])
        if spans:
            U = np.zeros((T, len(spans)))
            for k, (a, b) in enumerate(spans):
                U[a:b, k] = 1.0
                diag[j, a:b] += w
                if cfg.lock_height:
                    held[j, a:b] = w * H[a:b, c].mean()
            locks[j] = (U, w / U.sum(0))
    return locks, {} if cfg.lock_height else locks, held


def _dtd_banded(T: int) -> np.ndarray:
    """DᵀD of the second difference (T-2, T) in lower banded storage (3, T)."""
    ab = np.zeros((3, T))
    c = (1.0, -2.0, 1.0)                          # row k of D: +1, -2, +1 at k, k+1, k+2
    for a in range(3):
        for b in range(a, 3):
            ab[b - a, a:a + T - 2] += c[a] * c[b]
    return ab


def _solve_joints(joints, bases, diag: np.ndarray, locks: dict, b: np.ndarray) -> np.ndarray:
    """x (len(joints), T, m) of `_solve` for each joint j of `joints` (bases[j], diag (J, T),
    locks.get(j), right-hand sides b (J, T, m)). Joints without a lock whose systems are equal
    (most: no reach, no active bound) share one factorisation."""
    out = np.empty((len(joints), b.shape[1], b.shape[2]))
    groups: dict = {}
    for i, j in enumerate(joints):
        if j in locks:
            out[i] = _solve(bases[j], diag[j], locks[j], b[j])
        else:
            groups.setdefault((id(bases[j]), diag[j].tobytes()), []).append(i)
    for rows in groups.values():
        js = [joints[i] for i in rows]
        x = _solve(bases[js[0]], diag[js[0]], None, np.concatenate(list(b[js]), 1))       # (T, m·k)
        out[rows] = np.stack(np.split(x, len(rows), 1))
    return out


def _solve(base: np.ndarray, diag: np.ndarray, lock, b: np.ndarray) -> np.ndarray:
    """x (T, m) solving (base + diag(diag) − Σ_spans w_k u_k u_kᵀ) x = b (T, m): the banded part
    by Cholesky, the lock's rank-one parts (u_k a span's indicator) by Woodbury's identity."""
    ab = base.copy()
    ab[0] += diag
    if lock is None:
        return solveh_banded(ab, b, lower=True)
    U, w = lock                                                                       # (T, k), (k,)
    Z = solveh_banded(ab, np.concatenate([b, U], 1), lower=True)                      # B⁻¹ [b, U]
    Bb, BU = Z[:, :b.shape[1]], Z[:, b.shape[1]:]
    small = np.diag(1.0 / w) - U.T @ BU                                               # (k, k)
    return Bb + BU @ np.linalg.solve(small, U.T @ Bb)


# The joints a trunk shift moves (`into_reach`): everything but the limbs' middles and ends (and
# the toes): the middles follow from the two-bone fit, the ends stay where the solve put them.
LIMB_JOINTS = tuple((m, e) + ((leaf,) if leaf >= 0 else ()) for _, m, e, leaf in LIMBS)
TRUNK = tuple(j for j in range(22) if all(j not in limb for limb in LIMB_JOINTS))
SMOOTH_ROUNDS = 8         # smoothing and topping up of the shift
SHIFT_ROUNDS = 8          # cyclic projections onto the held limbs' reach constraints


def into_reach(Y: np.ndarray, reach: np.ndarray, held: np.ndarray, sigma: float) -> np.ndarray:
    """Y (T, 22, 3) with the trunk moved, frame by frame, by the smallest translation that
    brings the end (ankle, wrist) of every held limb (`held` (T, 4) bool in `limbs.LIMBS` order,
    `held_limbs`) within `reach` (4,) m of its root (hip, shoulder), smoothed over time
    (Gaussian, sigma frames) and topped up again where the smoothing left an end out of reach.

    The solve in joint space holds a planted foot or a hand on an object where the objective
    wants it, which may be farther from the hip or shoulder than the limb is long: the rigid body
    then has to bring the hips or shoulders closer, as the rotation solve's coupling through the
    skeleton does. Without it the leg snaps straight and the foot slides off its spot."""
    held = np.asarray(held, bool)
    shift = _reach_shift(Y, reach, held, np.zeros((Y.shape[0], 3)))
    if not shift.any():
        return Y
    if sigma > 0:
        # smoothing lowers the peaks below what they need; what is still missing is added,
        # smoothed too, a few rounds: a shift that is smooth and (nearly) enough
        shift = gaussian_filter1d(shift, sigma, axis=0, mode="nearest")
        for _ in range(SMOOTH_ROUNDS):
            missing = _reach_shift(Y, reach, held, shift) - shift
            if not missing.any():
                break
            shift += gaussian_filter1d(missing, sigma, axis=0, mode="nearest")
    out = Y.copy()
    out[:, list(TRUNK)] += shift[:, None]
    return out


def follow_locks(Y: np.ndarray, X: np.ndarray, planted: np.ndarray | None, contact_joints, sigma: float) -> np.ndarray:
    """Y (T, 22, 3) with the trunk moved across the floor, frame by frame, by the planted
    contact joints' moves from their targets X to where the lock holds them (Y), summed and
    divided by the number of contact joints (both feet held: their mean move; one foot: half
    of it, the other leg stays free), smoothed over time (Gaussian, sigma frames).

    The lock holds a planted foot at its span's mean; the network's "planted" foot often
    slides (30-50 cm over a stance that runs from the arrival at a goal through a sit), so the
    lock moves it 20-35 cm from where the network had it. The rotation solve's rigid legs
    carry the trunk along with the held foot; the joint-space solve moved only the foot (the
    trunk kept its target, `into_reach` acts only beyond the leg's length), which left the
    body 2-4 cm farther from its goals at the arrival frame than `solve` (val scenes 71-75:
    `solve` without the lock 0.140 m, with it 0.099 m; the joint-space solve 0.151 m)."""
    if planted is None or not len(contact_joints):
        return Y
    P = np.asarray(planted, bool)
    cj = list(contact_joints)
    d = (Y[:, cj] - X[:, cj])[..., [0, 2]] * P[..., None]                              # (T, C, 2)
    shift = np.zeros((Y.shape[0], 3))
    shift[:, [0, 2]] = d.sum(1) / len(cj)                                               # 0 where none planted
    if sigma > 0:
        shift = gaussian_filter1d(shift, sigma, axis=0, mode="nearest")
    out = Y.copy()
    out[:, list(TRUNK)] += shift[:, None]
    return out


def _reach_shift(Y: np.ndarray, reach: np.ndarray, held: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """shift (T, 3) moved on by cyclic projections onto the held limbs' reach constraints, each
    linearised along its root-end line."""
    shift = shift.copy()
    for _ in range(SHIFT_ROUNDS):
        moved = False
        for k, (r, _, e, _) in enumerate(LIMBS):
            v = Y[:, e] - (Y[:, r] + shift)                                        # (T, 3) root to end
            d = np.linalg.norm(v, axis=-1)
            over = np.where(held[:, k] & (d > reach[k] + 1e-6), d - reach[k], 0.0)
            if not over.any():
                continue
            moved = True
            shift += over[:, None] * v / np.maximum(d, 1e-9)[:, None]
        if not moved:
            break
    return shift


def held_limbs(T: int, reach: tuple | None) -> np.ndarray:
    """(T, 4) bool in `limbs.LIMBS` order, the limbs whose ends `into_reach` must reach: the legs
    on every frame (a planted foot is held; a swinging one out of reach would fall short of its
    path, and a constraint that switched on at each plant would jolt the trunk), an arm on the
    frames its wrist has a reach target (reach = (frames, joints, ...) or None)."""
    held = np.zeros((T, len(LIMBS)), bool)
    for k, (_, _, e, leaf) in enumerate(LIMBS):
        held[:, k] = leaf >= 0
        if reach is not None:
            f, jj = np.asarray(reach[0]), np.asarray(reach[1])
            held[f[jj == e], k] = True
    return held
