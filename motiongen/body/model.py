"""SMPL-X body model: fast joints-only kinematics, and the full skinned mesh on request.

Fitting needs only the 22 body joints, so we never touch vertices there. With
J(β) = J_regressor·(v_template + shapedirs·β) the rest joints are linear in β; we precompute
J_template = J_regressor·v_template (55, 3) and J_dirs = J_regressor·shapedirs (55, 3, nβ)
once, and a forward pass is then a tiny linear map plus forward kinematics over 22 joints —
no per-vertex work (10475 vertices × 486 pose-blend coefficients in the full model).

Joint positions equal SMPL-X's (the `smplx` package's `joints[:, :22]`): posed joint j is
G_parent(j)·(J_j − J_parent(j)) + posed parent, with the root at J_0(β) + transl.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from motiongen.body.procedural import ensure_procedural_model
from motiongen.body.rotations import axis_angle_to_matrix
from motiongen.errors import DataError
from motiongen.skeleton import BODY_PARENTS, NUM_BODY_JOINTS

MODEL_ENV = "MOTIONGEN_SMPLX_MODEL"
_REQUIRED = ("v_template", "shapedirs", "J_regressor", "kintree_table", "weights", "posedirs", "f")


def tree_levels(parents) -> list[tuple[list[int], list[int]]]:
    """Joints grouped by tree depth (root excluded): [(joints, their parents), ...].
    One batched step per level instead of one per joint."""
    depth = [0] * len(parents)
    for j in range(1, len(parents)):
        depth[j] = depth[parents[j]] + 1
    out = []
    for d in range(1, max(depth) + 1):
        js = [j for j in range(len(parents)) if depth[j] == d]
        out.append((js, [parents[j] for j in js]))
    return out


def forward_kinematics(rotmats: torch.Tensor, rest: torch.Tensor, parents, levels=None, with_rotations: bool = True):
    """Posed joints and global rotations.

    rotmats: (..., J, 3, 3) local rotations (root: global orientation); rest: (..., J, 3)
    rest joints (broadcastable). Returns positions (..., J, 3) with the root at rest[0], and
    global rotations (..., J, 3, 3) (None unless with_rotations).
    """
    # One small matmul per joint on (..., 3, 3) slices: measured faster on CPU than batching
    # by tree level (gathers/scatters cost more than they save at J = 22..55).
    order = [j for js, _ in (levels if levels is not None else tree_levels(parents)) for j in js]
    par = torch.as_tensor(parents[1:], device=rest.device)
    offsets = torch.cat([rest[..., :1, :], rest[..., 1:, :] - rest[..., par, :]], -2)  # (..., J, 3)
    # numpy's, not torch's: torch.broadcast_shapes imports sympy on its first call (0.3–0.7 s, 35 MiB).
    batch = np.broadcast_shapes(rotmats.shape[:-3], offsets.shape[:-2])
    R = rotmats.expand(batch + rotmats.shape[-3:]).unbind(-3)
    O = offsets.expand(batch + offsets.shape[-2:]).unbind(-2)
    G, P = [None] * len(R), [None] * len(R)
    G[0], P[0] = R[0], O[0]
    for j in order:
        p = parents[j]
        G[j] = G[p] @ R[j]
        P[j] = P[p] + (G[p] @ O[j][..., None])[..., 0]
    return torch.stack(P, -2), (torch.stack(G, -3) if with_rotations else None)


@dataclass
class BodyParams:
    """SMPL-X body parameters of a motion: what `BodyModel.motion_vertices` poses and
    `fit.save_amass_npz` writes. Fit results, sampled bodies and multi-view fits extend it."""

    global_orient: np.ndarray       # (T, 3) axis-angle
    body_pose: np.ndarray           # (T, 63) axis-angle, 21 body joints
    transl: np.ndarray              # (T, 3) metres
    betas: np.ndarray               # (nβ,)


class BodyModel(torch.nn.Module):
    """An SMPL-X model read from an official-layout `.npz`.

        bm = load_body_model()                      # user file, else the procedural one
        joints = bm.joints(global_orient, body_pose, transl, betas)   # (..., 22, 3)
        verts = bm.vertices(global_orient, body_pose, transl, betas)  # (..., V, 3)
    """

    def __init__(self, path: str | Path, num_betas: int = 10, dtype: torch.dtype = torch.float32):
        super().__init__()
        self.path = Path(path)
        self._file, data = _load_npz(self.path)
        self._data = data  # numpy arrays, kept for the mesh path (loaded lazily into tensors)
        shapedirs = data["shapedirs"]                    # (V, 3, S)
        # Official files hold 300 shape + 100 expression directions (400) or 10 + 10 (20).
        self.num_shape_available = 300 if shapedirs.shape[-1] >= 400 else min(10, shapedirs.shape[-1])
        self.num_betas = min(num_betas, self.num_shape_available)
        parents = data["kintree_table"][0].astype(np.int64).copy()
        parents[0] = -1
        if tuple(parents[:NUM_BODY_JOINTS]) != BODY_PARENTS:
            raise DataError(self.path, "kintree_table", "the first 22 joints do not have the SMPL-X body topology")
        self.full_parents = tuple(int(p) for p in parents)
        self.parents = BODY_PARENTS
        self._levels = tree_levels(self.parents)
        self._full_levels = tree_levels(self.full_parents)
        Jreg = np.asarray(data["J_regressor"].todense() if hasattr(data["J_regressor"], "todense") else data["J_regressor"],
                          dtype=np.float64)             # (55, V)
        self.num_vertices = data["v_template"].shape[0]
        self.register_buffer("J_template", torch.as_tensor(Jreg @ data["v_template"], dtype=dtype))  # (55, 3)
        J_dirs = np.einsum("jv,vcs->jcs", Jreg, shapedirs[..., : self.num_betas])
        self.register_buffer("J_dirs", torch.as_tensor(J_dirs, dtype=dtype))                      # (55, 3, nβ)
        self.faces = np.asarray(data["f"], dtype=np.int64)                                       # (F, 3)
        self.is_procedural = "motiongen_procedural" in data
        self._mesh_buffers: dict | None = None

    # ---- joints ----------------------------------------------------------------------

    def rest_joints(self, betas: torch.Tensor | None = None, body_only: bool = True) -> torch.Tensor:
        """Shaped rest joints (..., 22, 3) (or all 55 joints with body_only=False)."""
        n = NUM_BODY_JOINTS if body_only else self.J_template.shape[0]
        J = self.J_template[:n]
        if betas is None:
            return J
        return J + torch.einsum("jck,...k->...jc", self.J_dirs[:n], betas.to(J.dtype))

    def joints(self, global_orient: torch.Tensor, body_pose: torch.Tensor, transl: torch.Tensor | None = None,
               betas: torch.Tensor | None = None) -> torch.Tensor:
        """Posed body joints (..., 22, 3).

        Axis-angle global_orient (..., 3) and body_pose (..., 63) or (..., 21, 3); transl
        (..., 3); betas (nβ,) or (..., nβ). For matrices use `joints_from_rotmats`.
        """
        R = torch.cat([_root_rotmat(global_orient), _body_rotmats(body_pose)], -3)  # (..., 22, 3, 3)
        return self.joints_from_rotmats(R, transl, betas)

    def joints_from_rotmats(self, rotmats: torch.Tensor, transl: torch.Tensor | None = None,
                            betas: torch.Tensor | None = None) -> torch.Tensor:
        """rotmats (..., 22, 3, 3) (root first) -> posed joints (..., 22, 3)."""
        P, _ = forward_kinematics(rotmats, self.rest_joints(betas), self.parents, self._levels, with_rotations=False)
        return P if transl is None else P + transl[..., None, :]

    # ---- mesh ------------------------------------------------------------------------

    @property
    def template_vertices(self) -> np.ndarray:
        """(V, 3) rest-pose template (mean shape), float64."""
        return np.asarray(self._data["v_template"], np.float64)

    @property
    def skinning_weights(self) -> np.ndarray:
        """(V, 55) linear blend skinning weights."""
        return np.asarray(self._data["weights"])

    def _mesh(self, device, dtype) -> dict:
        if self._mesh_buffers is None or self._mesh_buffers["v_template"].device != torch.device(device):
            d = self._data
            with np.load(self._file, allow_pickle=True) as z:
                posedirs = np.asarray(z["posedirs"])       # (V, 3, P)
            P = posedirs.shape[-1]
            self._mesh_buffers = {
                "v_template": torch.as_tensor(d["v_template"], dtype=dtype, device=device),
                "shapedirs": torch.as_tensor(d["shapedirs"][..., : self.num_betas], dtype=dtype, device=device),
                "posedirs": torch.as_tensor(posedirs.reshape(-1, P).T, dtype=dtype, device=device),  # (P, V*3)
                "weights": torch.as_tensor(d["weights"], dtype=dtype, device=device),               # (V, 55)
                "J_regressor": torch.as_tensor(np.asarray(d["J_regressor"]), dtype=dtype, device=device),
            }
        return self._mesh_buffers

    def part_vertices(self, joint: int) -> np.ndarray:
        """(K,) ids of the vertices moved most by `joint` (of the full skeleton) or a joint below
        it: `part_vertices(21)` is the right hand, fingers included."""
        owner = np.asarray(self.skinning_weights).argmax(1)                               # (V,)
        below = np.zeros(len(self.full_parents), bool)
        for j in range(len(self.full_parents)):
            k = j
            while k >= 0 and k != joint:
                k = self.full_parents[k]
            below[j] = k == joint
        return np.flatnonzero(below[owner])

    def motion_vertices(self, params, frames=slice(None), vertex_ids=None) -> np.ndarray:
        """(n, K, 3) mesh vertices (numpy, the model's dtype) of a motion's parameters at
        `frames` (a slice or indices), only `vertex_ids` (default all). params: a `BodyParams`
        (a `FitResult`, a `BodyMotion`, ...) or anything with its four fields (an AMASS-style
        npz's)."""
        dev, dt = self.J_template.device, self.J_template.dtype

        def t(a, f=frames):
            return torch.as_tensor(np.asarray(a)[f], dtype=dt, device=dev)

        with torch.no_grad():
            v = self.vertices(t(params.global_orient), t(params.body_pose), t(params.transl),
                              t(params.betas, slice(None)), vertex_ids=vertex_ids)
        return v.cpu().numpy()

    def vertices(self, global_orient, body_pose, transl=None, betas=None, left_hand_pose=None,
                 right_hand_pose=None, jaw_pose=None, leye_pose=None, reye_pose=None,
                 vertex_ids=None) -> torch.Tensor:
        """Full mesh by linear blend skinning with pose blend shapes: (..., V, 3).

        Hand poses are full axis-angle (..., 45) (no PCA, flat-hand mean); omitted parts are
        zero. Expression is zero. vertex_ids (K,): pose only those vertices, (..., K, 3) (the
        joints still come from the whole shaped template); the cost of blend shapes and skinning
        scales with K, which makes per-frame meshes of long motions affordable (penetration).
        """
        dev, dt = self.J_template.device, self.J_template.dtype
        R_body = torch.cat([_root_rotmat(global_orient), _body_rotmats(body_pose)], -3)   # (..., 22, 3, 3)
        batch = R_body.shape[:-3]
        eye = torch.eye(3, dtype=dt, device=dev)

        def part(x, n):
            if x is None:
                return eye.expand(batch + (n, 3, 3))
            return axis_angle_to_matrix(x.reshape(x.shape[:-1] + (n, 3)))

        R = torch.cat([R_body, part(jaw_pose, 1), part(leye_pose, 1), part(reye_pose, 1),
                       part(left_hand_pose, 15), part(right_hand_pose, 15)], -3)  # (..., 55, 3, 3)
        return self._skin(R, transl, betas, vertex_ids)

    def vertices_from_rotmats(self, rotmats: torch.Tensor, transl: torch.Tensor | None = None,
                              betas: torch.Tensor | None = None, vertex_ids=None) -> torch.Tensor:
        """Body rotation matrices (..., 22, 3, 3) (root first; jaw, eyes and hands at rest) ->
        posed vertices (..., V, 3), or (..., K, 3) for vertex_ids (K,). Differentiable w.r.t.
        rotmats, transl (..., 3) and betas (nβ,) or (..., nβ): what marker-based objectives pose."""
        eye = torch.eye(3, dtype=self.J_template.dtype, device=self.J_template.device)
        rest = eye.expand(rotmats.shape[:-3] + (self.J_template.shape[0] - NUM_BODY_JOINTS, 3, 3))
        return self._skin(torch.cat([rotmats, rest], -3), transl, betas, vertex_ids)

    def _skin(self, R: torch.Tensor, transl, betas, vertex_ids) -> torch.Tensor:
        """Linear blend skinning with pose blend shapes of all 55 local rotations R
        (..., 55, 3, 3) -> (..., V or K, 3): the one implementation behind `vertices` and
        `vertices_from_rotmats`."""
        dev, dt = self.J_template.device, self.J_template.dtype
        batch = R.shape[:-3]
        eye = torch.eye(3, dtype=dt, device=dev)
        m = self._mesh(dev, dt)
        v = m["v_template"]
        if betas is not None:
            v = v + torch.einsum("vck,...k->...vc", m["shapedirs"], betas.to(dt))           # (..., V, 3)
        J = torch.einsum("jv,...vc->...jc", m["J_regressor"], v)                           # (..., 55, 3)
        posedirs, weights = m["posedirs"], m["weights"]
        if vertex_ids is not None:
            ids = torch.as_tensor(vertex_ids, dtype=torch.long, device=dev)
            v = v[..., ids, :]
            cols = (3 * ids[:, None] + torch.arange(3, device=dev)).reshape(-1)              # (3K,) x, y, z of each
            posedirs, weights = posedirs[:, cols], weights[ids]
        pose_feat = (R[..., 1:, :, :] - eye).flatten(-3)                                     # (..., 486)
        v = v + (pose_feat @ posedirs).reshape(batch + (-1, 3))                             # (..., V, 3)
        P, G = forward_kinematics(R, J, self.full_parents, self._full_levels)
        # Skinning transforms map rest points to posed: x -> G x + (P - G J).
        t = P - (G @ J[..., None].expand(batch + J.shape[-2:] + (1,)))[..., 0]              # (..., 55, 3)
        Gv = torch.einsum("vj,...jab->...vab", weights, G)                                  # (..., V, 3, 3)
        tv = torch.einsum("vj,...ja->...va", weights, t)                                    # (..., V, 3)
        out = (Gv @ v[..., None])[..., 0] + tv
        return out if transl is None else out + transl[..., None, :]

    def regress_joints(self, vertices: torch.Tensor) -> torch.Tensor:
        """Body joints regressed from (posed) vertices (..., V, 3) -> (..., 22, 3)."""
        m = self._mesh(vertices.device, vertices.dtype)
        return torch.einsum("jv,...vc->...jc", m["J_regressor"][:NUM_BODY_JOINTS], vertices)


def _root_rotmat(x: torch.Tensor) -> torch.Tensor:
    """Axis-angle (..., 3) -> (..., 1, 3, 3)."""
    return axis_angle_to_matrix(x)[..., None, :, :]


def _body_rotmats(x: torch.Tensor) -> torch.Tensor:
    """Axis-angle (..., 63) or (..., 21, 3) -> (..., 21, 3, 3)."""
    if x.shape[-1] == 63:
        return axis_angle_to_matrix(x.reshape(x.shape[:-1] + (21, 3)))
    if x.shape[-2:] == (21, 3):
        return axis_angle_to_matrix(x)
    raise ValueError(f"body_pose: expected axis-angle (..., 63) or (..., 21, 3), got {tuple(x.shape)}")


def _load_npz(path: Path) -> dict:
    if path.is_dir():
        cand = path / "SMPLX_NEUTRAL.npz"
        if not cand.is_file():
            raise DataError(path, None, "directory has no SMPLX_NEUTRAL.npz (set body.model_path to the .npz file)")
        path = cand
    if not path.is_file():
        raise DataError(path, None, f"SMPL-X model file not found (set body.model_path or ${MODEL_ENV})")
    try:
        with np.load(path, allow_pickle=True) as z:
            # posedirs (V, 3, 486) is most of the file and only the mesh path needs it.
            data = {k: z[k] for k in z.files if k != "posedirs"}
            if "posedirs" in z.files:
                data["posedirs"] = None
    except Exception as e:  # zipfile / pickle errors of all kinds
        raise DataError(path, None, f"not a readable SMPL-X .npz file ({type(e).__name__}: {e})") from None
    for k in _REQUIRED:
        if k not in data:
            raise DataError(path, k, "required SMPL-X model array is missing")
    if data["kintree_table"].shape[-1] < NUM_BODY_JOINTS or data["J_regressor"].shape[0] < NUM_BODY_JOINTS:
        raise DataError(path, "kintree_table", f"expected at least {NUM_BODY_JOINTS} joints")
    if data["shapedirs"].ndim != 3 or data["shapedirs"].shape[:2] != data["v_template"].shape:
        raise DataError(path, "shapedirs", f"expected (V, 3, S) matching v_template {data['v_template'].shape}")
    return path, data


def resolve_model_path(path: str | Path | None = None) -> Path:
    """`path` if given, else ``$MOTIONGEN_SMPLX_MODEL``, else the procedural model (generated
    into the cache on first use)."""
    if path not in (None, ""):
        return Path(path).expanduser()
    env = os.environ.get(MODEL_ENV)
    if env:
        return Path(env).expanduser()
    return ensure_procedural_model()


def load_body_model(path: str | Path | None = None, num_betas: int = 10, device: str | torch.device = "cpu",
                    dtype: torch.dtype = torch.float32) -> BodyModel:
    """Load the body model; see `resolve_model_path`. Loading takes a fraction of a second:
    callers fitting many sequences should load once and pass the model along."""
    return BodyModel(resolve_model_path(path), num_betas=num_betas, dtype=dtype).to(device)
