"""Training windows: canonicalised, normalised joint windows with their conditions.

A window is L frames taken every `stride`-th frame of a sequence (default 16 frames every 3rd
frame of 30 fps data: 1.6 s at 10 fps). It is expressed in the frame of its first pose
(pelvis x, z at the origin, yaw 0; see motiongen.geometry) and min–max normalised per channel
to [-1, 1] with statistics computed once on the train split. Items follow the contract in
docs/CONTRACTS.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.data import Dataset

from motiongen.data.format import MotionDataset, release
from motiongen.data.representation import DEFAULT_CONTACT_JOINTS, Layout, stance_labels
from motiongen.errors import ConfigError, DataError
from motiongen.geometry import canonical_frame, invert_rigid, transform_points
from motiongen.scene.local_occupancy import LocalGridSpec, local_occupancy_np
from motiongen.scene.voxelize import voxelize_mesh
from motiongen.skeleton import PELVIS


@dataclass
class WindowConfig:
    length: int = 16          # L frames per window
    stride: int = 3           # take every stride-th frame (30 fps -> 10 fps)
    hop: int = 1              # frames between consecutive window starts
    scene: bool = True        # query the local occupancy at the window goal
    objects: bool = True      # add dynamic objects to the occupancy query
    outside_occupied: bool = True
    # Local grid around the goal, in the window frame: resolution (x, y, z) and extent (m).
    grid_res: tuple[int, int, int] = (32, 32, 32)
    grid_lo: tuple[float, float, float] = (-0.6, 0.0, -0.6)
    grid_hi: tuple[float, float, float] = (0.6, 1.2, 0.6)
    # Features (motiongen.data.representation): "absolute" = every joint in the window frame
    # (the public TRUMANS code), "root" = pelvis + joints relative to it (measured worse at goals
    # and feet, docs/models.md). Stance channels for `contact_joints` (names; () for none):
    # dataset contact label and slower than `stance_speed` m/s.
    representation: str = "absolute"
    contact_joints: tuple[str, ...] = DEFAULT_CONTACT_JOINTS
    stance_speed: float = 0.2

    def __post_init__(self):
        # Hydra (the `window` group) and checkpoints (a dict) hand over lists: tuples here.
        self.grid_res, self.grid_lo, self.grid_hi = tuple(self.grid_res), tuple(self.grid_lo), tuple(self.grid_hi)
        self.contact_joints = tuple(self.contact_joints)

    def span(self) -> int:
        """Frames of the source sequence one window covers."""
        return (self.length - 1) * self.stride + 1


@dataclass
class NormStats:
    """Per-channel min–max statistics: x_norm = (x - center) / half_range."""

    center: np.ndarray       # (D,) float32
    half_range: np.ndarray   # (D,) float32

    def normalize(self, x):
        c, h = self._as(x)
        return (x - c) / h

    def denormalize(self, x):
        c, h = self._as(x)
        return x * h + c

    def _as(self, x):
        if isinstance(x, torch.Tensor):
            return (torch.as_tensor(self.center, dtype=x.dtype, device=x.device),
                    torch.as_tensor(self.half_range, dtype=x.dtype, device=x.device))
        return self.center, self.half_range

    def state_dict(self) -> dict:
        return {"center": self.center.tolist(), "half_range": self.half_range.tolist()}

    @classmethod
    def from_state_dict(cls, d: dict) -> "NormStats":
        return cls(np.asarray(d["center"], np.float32), np.asarray(d["half_range"], np.float32))


def window_starts(ds: MotionDataset, split: str | None, cfg: WindowConfig) -> np.ndarray:
    """(W,) int64 absolute start frames of every window lying inside one sequence."""
    span = cfg.span()
    starts = [np.arange(s.start, s.end - span + 1, cfg.hop) for s in ds.split_sequences(split) if s.num_frames >= span]
    return np.concatenate(starts).astype(np.int64) if starts else np.zeros(0, np.int64)


def sequence_starts(ds: MotionDataset, starts: np.ndarray) -> np.ndarray:
    """(W,) int64 the first frame of the sequence each window start (W,) lies in."""
    firsts = np.array(sorted(s.start for s in ds.sequences), np.int64)
    if len(starts) == 0:
        return np.zeros(0, np.int64)
    return firsts[np.searchsorted(firsts, starts, side="right") - 1]


def canonicalize(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Express windows (..., L, J, 3) in their first frame. Returns local joints and the
    (..., 4, 4) local -> world transforms."""
    T = canonical_frame(joints[..., 0, :, :])
    return transform_points(invert_rigid(T)[..., None, :, :], joints), T


def compute_stats(ds: MotionDataset, cfg: WindowConfig, split: str = "train", min_half_range: float = 1e-2) -> NormStats:
    """Min–max statistics of canonicalised, encoded windows over a split, sequence by sequence
    so memory stays bounded. Channels that barely vary (the first frame's pelvis x, z are always
    0) get `min_half_range` so normalisation never divides by ~0; stance channels keep their
    fixed {-1, +1} scale."""
    layout = Layout.for_window(cfg, ds.joint_set)
    P = layout.pose_channels
    lo = np.full(P, np.inf)
    hi = np.full(P, -np.inf)
    span = cfg.span()
    for seq in ds.split_sequences(split):
        if seq.num_frames < span:
            continue
        frames = np.asarray(ds.joints[seq.start:seq.end], np.float64)          # (T, J, 3)
        starts = np.arange(0, seq.num_frames - span + 1, cfg.hop)
        idx = starts[:, None] + cfg.stride * np.arange(cfg.length)[None]        # (W, L)
        local, _ = canonicalize(frames[idx])                                    # (W, L, J, 3)
        flat = Layout(layout.num_joints, layout.representation).encode(local).reshape(-1, P)
        lo, hi = np.minimum(lo, flat.min(0)), np.maximum(hi, flat.max(0))
    release(ds.joints)
    if not np.isfinite(lo).all():
        raise DataError(ds.root, split, f"no sequence in split {split!r} is long enough for a window of {span} frames")
    half = np.maximum((hi - lo) / 2, min_half_range)
    c_fix, h_fix = layout.fixed_stats()
    return NormStats(np.concatenate([(hi + lo) / 2, c_fix]).astype(np.float32),
                     np.concatenate([half, h_fix]).astype(np.float32))


def dataset_stance(ds: MotionDataset, layout: Layout, stance_speed: float) -> np.ndarray:
    """(N, C) bool stance labels of every frame (computed per sequence: speeds never cross a
    sequence boundary). Small: N x 4 bools."""
    out = np.zeros((ds.num_frames, layout.num_contacts), bool)
    if layout.num_contacts:
        for seq in ds.sequences:
            out[seq.start:seq.end] = stance_labels(np.asarray(ds.joints[seq.start:seq.end]),
                                                   np.asarray(ds.contact[seq.start:seq.end]),
                                                   layout.contact_joints, ds.fps, stance_speed)
        release(ds.joints)
    return out


class WindowDataset(Dataset):
    """Windows of one split. `stats=None` computes them on the train split of the same dataset."""

    def __init__(self, ds: MotionDataset, split: str | None, cfg: WindowConfig, stats: NormStats | None = None,
                 previous: int = 0):
        """previous > 0: each item also carries the window that starts `previous` model frames
        earlier in the same sequence (keys "prev_*", `has_prev` False where the sequence starts
        too late): training on the network's own transition frames (`training/rollout.py`)."""
        if cfg.length < 2 or cfg.stride < 1 or cfg.hop < 1:
            raise ConfigError(f"window length must be >= 2 and stride, hop >= 1 (got {cfg.length}, {cfg.stride}, {cfg.hop})")
        if not 0 <= previous < cfg.length:
            raise ConfigError(f"previous window offset must be in 0..{cfg.length - 1} frames (got {previous})")
        self.ds, self.split, self.cfg, self.previous = ds, split, cfg, previous
        self.starts = window_starts(ds, split, cfg)
        self._seq_starts = sequence_starts(ds, self.starts)                     # (W,) the start of each one's sequence
        self.layout = Layout.for_window(cfg, ds.joint_set)
        self.stats = stats if stats is not None else compute_stats(ds, cfg)
        if len(self.stats.center) != self.layout.channels:
            raise ConfigError(f"normalisation statistics have {len(self.stats.center)} channels, the window layout "
                              f"{self.layout.channels}")
        self.stance = dataset_stance(ds, self.layout, cfg.stance_speed)
        self._offsets = cfg.stride * np.arange(cfg.length)
        self.spec = LocalGridSpec(tuple(cfg.grid_res), (cfg.grid_lo[0], cfg.grid_hi[0]),
                                  (cfg.grid_lo[1], cfg.grid_hi[1]), (cfg.grid_lo[2], cfg.grid_hi[2]))
        self._object_grids: dict[int, object] = {}                                  # object id -> grid (per worker)

    def __len__(self) -> int:
        return len(self.starts)

    def window_frames(self, i: int) -> np.ndarray:
        return self.starts[i] + self._offsets

    def __getitem__(self, i: int) -> dict:
        frames = self.window_frames(i)                                           # (L,)
        item = self.item_at(frames)
        if self.previous:
            back = frames - self.previous * self.cfg.stride
            has = bool(back[0] >= self._seq_starts[i])
            prev = self.item_at(back if has else frames)                           # same shapes either way
            item.update({f"prev_{k}": prev[k] for k in ("motion", "actions", "to_world", "scene") if k in prev})
            item["has_prev"] = torch.tensor(has)
        return item

    def item_at(self, frames: np.ndarray) -> dict:
        """The window of source frames `frames` (L,): its features, conditions and frame."""
        joints = np.asarray(self.ds.joints[frames], np.float64)                  # (L, J, 3)
        local, T = canonicalize(joints)                                          # (L, J, 3), (4, 4)
        motion = self.stats.normalize(self.layout.encode(local, self.stance[frames]).astype(np.float32))  # (L, D)
        item = {
            "motion": torch.from_numpy(motion),
            "actions": torch.from_numpy(np.asarray(self.ds.actions[frames], np.float32)),
            "goal": torch.from_numpy(local[-1, PELVIS].astype(np.float32)),
            "to_world": torch.from_numpy(T.astype(np.float32)),
            "scene_id": torch.tensor(int(self.ds.scene_id[frames[0]]), dtype=torch.long),
        }
        if self.cfg.scene:
            item["scene"] = torch.from_numpy(self.local_scene(frames, local[-1, PELVIS], T))
        return item

    def local_scene(self, frames: np.ndarray, goal: np.ndarray, T: np.ndarray) -> np.ndarray:
        """(Hy, Hx, Hz) float32 occupancy around the goal pelvis `goal` (3,) of the window of
        source frames `frames` (L,) in its frame T (4, 4) local -> world, axes aligned with that
        frame, with the objects present at the goal frame added. Height counts from the floor."""
        at_goal = T.copy()
        at_goal[:3, 3] = T[:3, :3] @ np.array([goal[0], 0.0, goal[2]]) + T[:3, 3]        # goal (x, 0, z) in world
        objects = self._objects_at(int(frames[-1])) if self.cfg.objects else []
        occ = local_occupancy_np(self.ds.grid(int(self.ds.scene_id[frames[0]])), at_goal, self.spec, objects,
                                 outside=self.cfg.outside_occupied)
        return occ.astype(np.float32)

    def _objects_at(self, frame: int) -> list:
        """[(object grid, pose (4, 4) object -> world)] for the objects present at `frame`."""
        if self.ds.object_ids is None:
            return []
        out = []
        for slot, oid in enumerate(np.asarray(self.ds.object_ids[frame])):
            if oid < 0:
                continue
            if oid not in self._object_grids:
                self._object_grids[oid] = self._voxelize_object(int(oid))
            if self._object_grids[oid] is not None:
                out.append((self._object_grids[oid], np.asarray(self.ds.object_poses[frame, slot], np.float64)))
        return out

    def _voxelize_object(self, oid: int):
        mesh = self.ds.object_mesh(oid)
        if mesh is None:
            return None
        vs = self.ds.grid(self.ds.sequences[0].scene).voxel_size
        return voxelize_mesh(mesh, voxel_size=vs)
