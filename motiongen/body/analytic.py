"""Analytic pose initialisation from joint positions: *swing correction* down the kinematic
tree (`analytic_init`: each joint rotated by the smallest rotation, Kabsch at the pelvis and
spine3, that points its bones at the target joints, keeping the given twist) and temporal
smoothing of rotations (`smooth_rotations`). Used by the fit, the sampler's body projection
and multi-view fitting.

`analytic_init` runs in float64 numpy, one batched step per tree level: the sampler projects
every episode onto the body with it, and on a few dozen frames the cost is the number of small
array operations (numpy's are several times cheaper than torch's), not arithmetic."""

from __future__ import annotations

import numpy as np
import torch

from motiongen.body.model import tree_levels
from motiongen.body.rotations import matrix_to_rot6d, rot6d_to_matrix
from motiongen.skeleton import BODY_PARENTS, NUM_BODY_JOINTS

_CHILDREN = {j: [c for c in range(NUM_BODY_JOINTS) if BODY_PARENTS[c] == j] for j in range(NUM_BODY_JOINTS)}


def _depth(j: int) -> int:
    return 0 if BODY_PARENTS[j] < 0 else 1 + _depth(BODY_PARENTS[j])


# Joints by tree depth, each level split into (joints with one child, joints with several
# children, leaves): the one-child joints of a level are swung together, the others one by one.
_LEVELS = []
for _d in range(max(_depth(j) for j in range(NUM_BODY_JOINTS)) + 1):
    _js = [j for j in range(NUM_BODY_JOINTS) if _depth(j) == _d]
    _LEVELS.append(([j for j in _js if len(_CHILDREN[j]) == 1], [j for j in _js if len(_CHILDREN[j]) > 1],
                    [j for j in _js if not _CHILDREN[j]]))
_ONE_CHILD = {j: _CHILDREN[j][0] for j in range(NUM_BODY_JOINTS) if len(_CHILDREN[j]) == 1}
_PARENT_OR_ROOT = np.array([max(p, 0) for p in BODY_PARENTS])
_FK_LEVELS = tree_levels(BODY_PARENTS)                                      # [(joints, their parents)] below the root


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation R (T, 3, 3) minimising Σ‖R a_k − b_k‖² for vectors a, b (T, K, 3)."""
    H = np.einsum("tki,tkj->tij", a, b)                            # (T, 3, 3) = Σ a_k b_kᵀ
    U, _, Vh = np.linalg.svd(H)
    V, Ut = Vh.transpose(0, 2, 1), U.transpose(0, 2, 1)
    d = np.sign(np.linalg.det(V @ Ut))
    V = V.copy()
    V[:, :, 2] *= np.where(d == 0, 1.0, d)[:, None]
    return V @ Ut


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) with skew(v) u = v x u."""
    K = np.zeros(v.shape + (3,))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return K


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.sqrt((v * v).sum(-1, keepdims=True)), 1e-12)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b for (..., 3) arrays: `np.cross` costs several times more on the few dozen vectors
    a window has (it moves axes around first), and the projection calls it per tree level."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], -1)


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation (..., 3, 3) taking direction a to direction b (..., 3): with v = a × b
    and c = a · b, R = c I + [v]× + v vᵀ / (1 + c) (Rodrigues' formula, [v]×² = v vᵀ − |v|² I)."""
    a, b = _unit(a), _unit(b)
    c = (a * b).sum(-1)[..., None, None]
    v = _cross(a, b)
    R = c * np.eye(3) + _skew(v) + v[..., :, None] * v[..., None, :] / np.maximum(1 + c, 1e-6)
    flip = 1 + c < 1e-3
    if not flip.any():
        return R
    # Opposite directions: the formula divides by ~0; turn half-way round any axis normal to a.
    # (A target can point anywhere: an untrained network's bones do.)
    other = np.where(np.abs(a[..., :1]) < 0.9, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
    n = _unit(_cross(a, other))
    half_turn = 2 * n[..., :, None] * n[..., None, :] - np.eye(3)
    return np.where(flip, half_turn, R)


def _orthonormal(R: np.ndarray) -> np.ndarray:
    """R (..., 3, 3) re-orthonormalised by Gram-Schmidt of its first two columns: near-opposite
    directions leave rounding of ~1e-4 in the closed form (in float32), which compounds down the
    chain into stretched bones."""
    b1 = _unit(R[..., :, 0])
    a2 = R[..., :, 1]
    b2 = _unit(a2 - (b1 * a2).sum(-1, keepdims=True) * b1)
    return np.stack([b1, b2, _cross(b1, b2)], -1)


def analytic_init(joints: torch.Tensor, rest: torch.Tensor, rot_init: torch.Tensor | None = None) -> torch.Tensor:
    """Inverse kinematics by swing correction: joints (T, 22, 3), rest joints (22, 3) (or one
    rest pose per frame, (T, 22, 3)),
    optional local rotations (T, 22, 3, 3) to start from (e.g. the MLP's) -> local rotmats
    (T, 22, 3, 3) whose bone directions match the targets exactly (lengths are the rest ones),
    in the joints' dtype (computed in float64, not differentiable).

    Going down the tree, each joint's global rotation is rotated by the smallest rotation
    (Kabsch for the pelvis and spine3, which have several children) that points its bones at
    the targets. Twist about a bone is unobservable from its child alone, so it is kept from
    `rot_init` (none without it); leaves keep their initial local rotation.
    """
    X = joints.detach().cpu().double().numpy()                                  # (T, 22, 3)
    rest_np = np.broadcast_to(rest.detach().cpu().double().numpy(), X.shape)    # (T, 22, 3)
    init = None if rot_init is None else rot_init.detach().cpu().double().numpy()
    R, _ = swing(X, rest_np, init)
    return torch.from_numpy(R).to(device=joints.device, dtype=joints.dtype)


def swing(X: np.ndarray, rest: np.ndarray, init: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`analytic_init` in float64 numpy: joints X (T, 22, 3), rest joints (T, 22, 3), local
    rotations init (T, 22, 3, 3) or None -> (local rotations, global rotations), each
    (T, 22, 3, 3). The sampler's projection stays in numpy between its steps (`posed_joints`)."""
    T = X.shape[0]
    G = np.empty((T, NUM_BODY_JOINTS, 3, 3))                                    # global rotations
    for one, many, leaves in _LEVELS:
        js = one + many + leaves
        par = [BODY_PARENTS[j] for j in js]
        Gp = np.broadcast_to(np.eye(3), (T, len(js), 3, 3)) if par[0] < 0 else G[:, par]
        Gc = Gp @ init[:, js] if init is not None else Gp.copy()                # candidates (T, n, 3, 3)
        if one:
            kid = [_ONE_CHILD[j] for j in one]
            a = (Gc[:, :len(one)] @ (rest[:, kid] - rest[:, one])[..., None])[..., 0]      # (T, n1, 3)
            Gc[:, :len(one)] = _orthonormal(_min_rotation(a, X[:, kid] - X[:, one]) @ Gc[:, :len(one)])
        for i, j in enumerate(many, start=len(one)):
            kids = _CHILDREN[j]
            a = (rest[:, kids] - rest[:, j:j + 1]) @ Gc[:, i].transpose(0, 2, 1)      # (T, K, 3)
            Gc[:, i] = _orthonormal(_kabsch(a, X[:, kids] - X[:, j:j + 1]) @ Gc[:, i])
        G[:, js] = Gc
    R = G[:, _PARENT_OR_ROOT].transpose(0, 1, 3, 2) @ G                       # local = Gpᵀ G
    R[:, 0] = G[:, 0]
    return R, G


def posed_joints(G: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Forward kinematics from global rotations: G (T, 22, 3, 3), rest joints (T, 22, 3) ->
    joints (T, 22, 3) with the root at rest[0] (`body.model.forward_kinematics`'s positions,
    one numpy step per tree level: on a window's few dozen frames torch's per-op cost is most
    of the time)."""
    P = np.empty_like(rest)
    P[:, 0] = rest[:, 0]
    for js, par in _FK_LEVELS:
        P[:, js] = P[:, par] + (G[:, par] @ (rest[:, js] - rest[:, par])[..., None])[..., 0]
    return P


def smooth_rotations(R: torch.Tensor, sigma: float) -> torch.Tensor:
    """Gaussian smoothing over time of rotations (T, J, 3, 3), in 6D then re-orthonormalised.

    The MLP sees one frame (and two neighbours) at a time, so what joints do not determine
    (leaf-joint and twist rotations) jitters from frame to frame; this removes that before the
    prior anchors refinement to it."""
    T = R.shape[0]
    if sigma <= 0 or T < 3:
        return R
    r = min(int(3 * sigma), T - 1)
    x = torch.arange(-r, r + 1, dtype=R.dtype, device=R.device)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    k = (k / k.sum())[None, None]                                             # (1, 1, 2r+1)
    d6 = matrix_to_rot6d(R)                                                   # (T, J, 6)
    seq = d6.permute(1, 2, 0).reshape(-1, 1, T)                               # (J*6, 1, T)
    seq = torch.nn.functional.pad(seq, (r, r), mode="replicate")
    out = torch.nn.functional.conv1d(seq, k).reshape(d6.shape[1], 6, T).permute(2, 0, 1)
    return rot6d_to_matrix(out)
