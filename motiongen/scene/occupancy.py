"""Occupancy grids: a bit-packed boolean voxel grid with an origin and a voxel size.

Voxel (i, j, k) covers [origin + (i, j, k) * voxel_size, origin + (i+1, j+1, k+1) * voxel_size).
On disk a grid is two files: ``<stem>.occ.npy`` (uint8, (X, Y, ceil(Z/8)), bits packed along
z with numpy's big bit order) and ``<stem>.occ.json`` (shape, origin, voxel_size). Packing
keeps a 6 x 2 x 8 m room at 2 cm under 2 MB, and the .npy is memory-mapped on load so RAM
does not grow with the number of scenes.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage

from motiongen.errors import DataError


@dataclass
class OccupancyGrid:
    bits: np.ndarray          # (X, Y, ceil(Z/8)) uint8, packed along z
    shape: tuple[int, int, int]  # (X, Y, Z) voxels
    origin: np.ndarray        # (3,) float64, world position of voxel (0,0,0)'s min corner
    voxel_size: float
    # The signed distance field, kept with the grid by `distance_field.surface_distance`.
    _distance: object = field(default=None, init=False, repr=False, compare=False)
    # The exact signed distance to the mesh this grid voxelises (a `distance_field.MeshField`),
    # where its maker had the mesh: placed objects, whose surface the voxels miss by up to half
    # a voxel, which is most of a hand's depth in them (`sampling.hand_clearance`).
    exact_surface: object = field(default=None, repr=False, compare=False)

    @classmethod
    def from_dense(cls, occ: np.ndarray, origin, voxel_size: float) -> "OccupancyGrid":
        occ = np.asarray(occ, dtype=bool)
        if occ.ndim != 3:
            raise ValueError(f"occupancy must be 3-D, got shape {occ.shape}")
        bits = np.packbits(occ, axis=2, bitorder="big")
        return cls(bits, tuple(int(s) for s in occ.shape), np.asarray(origin, np.float64), float(voxel_size))

    def dense(self) -> np.ndarray:
        """(X, Y, Z) bool."""
        return np.unpackbits(np.asarray(self.bits), axis=2, count=self.shape[2], bitorder="big").astype(bool)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) world min and max corners."""
        lo = self.origin
        return np.stack([lo, lo + np.asarray(self.shape) * self.voxel_size])

    def index_of(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Voxel index (..., 3) int64 of each point (..., 3) and whether it is inside the grid."""
        ijk = np.floor((np.asarray(points, np.float64) - self.origin) / self.voxel_size).astype(np.int64)
        inside = np.all((ijk >= 0) & (ijk < np.asarray(self.shape)), axis=-1)
        return ijk, inside

    def occupied(self, points: np.ndarray, outside: bool = True) -> np.ndarray:
        """Occupancy (...,) bool at world points (..., 3); points outside the grid get `outside`."""
        ijk, inside = self.index_of(points)
        ijk = np.where(inside[..., None], ijk, 0)
        byte = np.asarray(self.bits)[ijk[..., 0], ijk[..., 1], ijk[..., 2] >> 3]
        bit = (byte >> (7 - (ijk[..., 2] & 7))) & 1
        return np.where(inside, bit.astype(bool), outside)

    def save(self, stem: str | Path) -> None:
        """Write ``<stem>.occ.npy`` and ``<stem>.occ.json`` (each via a temp file and rename)."""
        stem = Path(stem)
        npy, meta = Path(f"{stem}.occ.npy"), Path(f"{stem}.occ.json")
        tmp = npy.with_name(npy.name + f".tmp{os.getpid()}")
        with open(tmp, "wb") as f:
            np.save(f, np.ascontiguousarray(self.bits, dtype=np.uint8))
        os.replace(tmp, npy)
        info = {"shape": list(self.shape), "origin": [float(v) for v in self.origin],
                "voxel_size": self.voxel_size, "packing": "packbits-z-big"}
        tmp = meta.with_name(meta.name + f".tmp{os.getpid()}")
        tmp.write_text(json.dumps(info))
        os.replace(tmp, meta)

    @classmethod
    def load(cls, stem: str | Path) -> "OccupancyGrid":
        """Memory-map a grid saved by `save`; validates shapes and metadata."""
        stem = Path(str(stem).removesuffix(".occ.npy").removesuffix(".occ.json"))
        npy, meta = Path(f"{stem}.occ.npy"), Path(f"{stem}.occ.json")
        for p in (npy, meta):
            if not p.is_file():
                raise DataError(p, None, "occupancy grid file is missing")
        try:
            info = json.loads(meta.read_text())
            shape = tuple(int(s) for s in info["shape"])
            origin = np.asarray(info["origin"], np.float64)
            voxel_size = float(info["voxel_size"])
        except (ValueError, KeyError, TypeError) as e:
            raise DataError(meta, None, f"malformed grid metadata ({e})") from None
        if len(shape) != 3 or origin.shape != (3,) or not voxel_size > 0:
            raise DataError(meta, None, f"expected 3-D shape, 3-vector origin and positive voxel_size, "
                                        f"found shape={shape}, origin={origin.tolist()}, voxel_size={voxel_size}")
        bits = load_npy(npy, "occupancy")
        expect = (shape[0], shape[1], (shape[2] + 7) // 8)
        if bits.shape != expect or bits.dtype != np.uint8:
            raise DataError(npy, "occupancy", f"expected uint8 {expect}, found {bits.dtype} {bits.shape}")
        return cls(bits, shape, origin, voxel_size)


def load_npy(path: str | Path, field: str | None = None, mmap: bool = True) -> np.ndarray:
    """np.load with a memory map, turning missing/truncated/corrupt files into a DataError."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, field, "file is missing")
    try:
        return np.load(path, mmap_mode="r" if mmap else None, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise DataError(path, field, f"not a readable .npy file ({e})") from None


# ---------------------------------------------------------------------------------------
# Dilation by a ball


def _ball_boxes(r: float) -> list[tuple[int, int, int]]:
    """Half-extents of the maximal centred boxes whose union is the digital ball |d| <= r.

    Every lattice point d of the ball lies in box(|dx|,|dy|,|dz|), which is inside the ball,
    so the ball is the union of these boxes; dilating by a box is three 1-D max filters.
    """
    R = int(np.floor(r))
    cands = [(a, b, int(np.floor(np.sqrt(r * r - a * a - b * b))))
             for a in range(R + 1) for b in range(R + 1) if a * a + b * b <= r * r]
    return [c for c in cands
            if not any(o != c and o[0] >= c[0] and o[1] >= c[1] and o[2] >= c[2] for o in cands)]


def near_occupied(occ: np.ndarray, radius_vox: float) -> np.ndarray:
    """(X,Y,Z) bool: voxels whose centre is within `radius_vox` voxels of an occupied centre."""
    u = np.ascontiguousarray(occ, dtype=bool).view(np.uint8)
    out = np.zeros(occ.shape, bool)
    for box in _ball_boxes(radius_vox):
        d = u
        for axis, h in enumerate(box):
            if h:
                d = ndimage.maximum_filter1d(d, 2 * h + 1, axis=axis, mode="constant", cval=0)
        out |= d.view(bool)
    return out
