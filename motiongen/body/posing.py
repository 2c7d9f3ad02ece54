"""A fixed body posed from 6D rotations, with a hand-written backward pass: the hot path of the
final solve (`fit.refine`), where L-BFGS evaluates the loss and its gradient some 40–80 times on
every frame of a motion.

The same map as `rot6d_to_matrix` followed by `BodyModel.joints_from_rotmats` (Gram-Schmidt,
then forward kinematics over the 22 body joints), to float rounding. Autograd records one small
(T, 3, 3) operation per joint and step there, and on a 2-core CPU its per-operation cost, not
the arithmetic, was most of the solve (docs/results.md, "The final solve's posing pass"). Here every
quantity is laid out with the frames last, (..., T), so each step of the tree is a few
elementwise operations over whole frame vectors, and the backward pass walks the tree once in
reverse without a recorded graph.
"""

from __future__ import annotations

import torch

from motiongen.body.model import tree_levels


class FixedBodyPose:
    """pose(rot6d (T, J, 6), transl (T, 3)) -> joints (T, J, 3), local rotations (T, J, 3, 3),
    for one body: rest joints (J, 3) held fixed (no gradient to the shape). Differentiable in
    rot6d and transl."""

    def __init__(self, rest: torch.Tensor, parents):
        rest = rest.detach()
        self.parents = tuple(int(p) for p in parents)
        self.order = [j for js, _ in tree_levels(self.parents) for j in js]
        # A joint without children needs no global rotation (its position is its parent's work).
        self.leaves = frozenset(range(len(self.parents))) - set(self.parents)
        par = list(self.parents[1:])
        self.offsets = torch.cat([rest[:1], rest[1:] - rest[par]], 0)                 # (J, 3)

    def __call__(self, rot6d: torch.Tensor, transl: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return _Pose.apply(rot6d, transl, self.offsets.to(rot6d.dtype), self.parents, self.order, self.leaves)


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Cross product over the first axis of (3, ...) tensors (torch.linalg.cross is slower on
    these shapes)."""
    return torch.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


class _Pose(torch.autograd.Function):
    @staticmethod
    def forward(ctx, rot6d, transl, offsets, parents, order, leaves):
        T, J, _ = rot6d.shape
        d = rot6d.permute(2, 1, 0)                                                     # (6, J, T)
        a1, a2 = d[:3].contiguous(), d[3:].contiguous()                                # (3, J, T)
        # Gram-Schmidt, as rotations.rot6d_to_matrix (F.normalize's eps).
        n1 = a1.square().sum(0).sqrt().clamp(min=1e-12)                               # (J, T)
        b1 = a1 / n1
        s = (b1 * a2).sum(0)
        u = a2 - s * b1
        n2 = u.square().sum(0).sqrt().clamp(min=1e-12)
        b2 = u / n2
        R = torch.stack([b1, b2, _cross(b1, b2)], 1)                                   # (3 row, 3 col, J, T)
        Rj = R.permute(2, 0, 1, 3).contiguous().unbind(0)                              # J × (3, 3, T)
        G, P = [None] * J, [None] * J                                                  # global rotations, positions
        G[0], P[0] = Rj[0], transl.T + offsets[0][:, None]                             # (3, 3, T), (3, T)
        for j in order:
            Gp = G[parents[j]]
            if j not in leaves:
                G[j] = (Gp[:, :, None] * Rj[j][None]).sum(1)
            P[j] = P[parents[j]] + (Gp * offsets[j][None, :, None]).sum(1)
        ctx.save_for_backward(a2, b1, b2, n1, n2, s, offsets)
        ctx.G, ctx.Rj, ctx.parents, ctx.order = G, Rj, parents, order
        return torch.stack(P, 0).permute(2, 0, 1).contiguous(), R.permute(3, 2, 0, 1).contiguous()

    @staticmethod
    def backward(ctx, gP, gR):
        a2, b1, b2, n1, n2, s, offsets = ctx.saved_tensors
        G, Rj, parents, order = ctx.G, ctx.Rj, ctx.parents, ctx.order
        J, T = b1.shape[1:]
        if gP is None:
            gP = torch.zeros(T, J, 3, dtype=b1.dtype, device=b1.device)
        if gR is None:
            gR = torch.zeros(T, J, 3, 3, dtype=b1.dtype, device=b1.device)
        gPj = list(gP.permute(1, 2, 0).contiguous().unbind(0))                         # J × (3, T)
        gRj = list(gR.permute(1, 2, 3, 0).contiguous().unbind(0))                      # J × (3, 3, T)
        gG = [None] * J
        # P[j] = P[p] + G[p] o_j and G[j] = G[p] R[j], children before their parents.
        for j in reversed(order):
            p = parents[j]
            g = gPj[j][:, None, :] * offsets[j][None, :, None]                         # (3, 3, T)
            if gG[j] is not None:
                gRj[j] = gRj[j] + (G[p][:, :, None] * gG[j][:, None, :]).sum(0)        # G[p]ᵀ gG[j]
                g = g + (gG[j][:, None, :, :] * Rj[j][None, :, :, :]).sum(2)           # gG[j] R[j]ᵀ
            gG[p] = g if gG[p] is None else gG[p] + g
            gPj[p] = gPj[p] + gPj[j]
        if gG[0] is not None:
            gRj[0] = gRj[0] + gG[0]
        gRall = torch.stack(gRj, 0)                                                    # (J, 3 row, 3 col, T)
        gb1, gb2, gb3 = (gRall[:, :, c].transpose(0, 1) for c in range(3))            # (3, J, T)
        # Gram-Schmidt's backward: b3 = b1 × b2, b2 = u / |u|, u = a2 − (b1·a2) b1, b1 = a1 / |a1|.
        gb1 = gb1 + _cross(b2, gb3)
        gb2 = gb2 + _cross(gb3, b1)
        gu = (gb2 - b2 * (b2 * gb2).sum(0)) / n2
        ga2 = gu - b1 * (b1 * gu).sum(0)
        gb1 = gb1 - s * gu - (gu * b1).sum(0) * a2
        ga1 = (gb1 - b1 * (b1 * gb1).sum(0)) / n1
        return torch.cat([ga1, ga2], 0).permute(2, 1, 0), gPj[0].T, None, None, None, None
