"""Local occupancy at episode targets for the autoregressive loop: the scene grid plus the
objects placed in it, yaw-aligned with each window's frame (what training windows see)."""

from __future__ import annotations

import numpy as np
import torch

from motiongen.scene.local_occupancy import (DynamicObjects, GridBank, LocalGridSpec, TorchOccupancy,
                                              local_occupancy)
from motiongen.scene.occupancy import OccupancyGrid


def _scene_spec(window):
    lo, hi = window.grid_lo, window.grid_hi
    return LocalGridSpec(tuple(int(r) for r in window.grid_res), (lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2]))


class SceneQuery:
    """Local occupancy at episode targets: (S, Hy, Hx, Hz) float32, or None for a model
    without scene conditioning. No scene = an empty floor (all free)."""

    def __init__(self, loaded, grid, objects, device):
        self.enabled = loaded.window.scene and getattr(loaded.model, "scene_encoder", None) is not None
        self.spec = _scene_spec(loaded.window)
        self.outside = bool(loaded.window.outside_occupied)
        self.device = device
        self.bank = TorchOccupancy(grid, device) if (grid is not None and self.enabled) else None
        self.objects = None
        if objects and self.enabled and loaded.window.objects:
            bank = GridBank([g for g, _ in objects], device)
            poses = torch.as_tensor(np.stack([np.asarray(p, np.float64) for _, p in objects]), dtype=torch.float32)
            self._obj = (bank, poses)                                                        # poses (K, 4, 4)
            self.objects = DynamicObjects
        self._ids = None

    def __call__(self, at_goal: np.ndarray) -> torch.Tensor | None:
        """at_goal (S, 4, 4) local -> world frames centred on the targets."""
        if not self.enabled:
            return None
        S = at_goal.shape[0]
        if self.bank is None and self.objects is None:
            return torch.zeros((S, *self.spec.out_shape), dtype=torch.float32, device=self.device)
        T = torch.as_tensor(at_goal, dtype=torch.float32, device=self.device)
        objs = None
        if self.objects is not None:
            bank, poses = self._obj
            K = poses.shape[0]
            ids = torch.arange(K, device=self.device)[None].expand(S, K)                   # (S, K)
            objs = self.objects(bank, ids, poses.to(self.device)[None].expand(S, K, 4, 4))
        if self.bank is None:
            # Objects on an empty floor: an all-free 1-voxel grid far away plays the scene.
            self.bank = TorchOccupancy(OccupancyGrid.from_dense(np.zeros((1, 1, 1), bool), [1e6, 1e6, 1e6], 1.0),
                                       self.device)
            self.outside = False
        occ = local_occupancy(self.bank, T, self.spec, objects=objs, outside=self.outside)  # (S, Hy, Hx, Hz)
        return occ.float()
