"""Raw per-frame columns streamed to disk row block by row block and published as `.npy`
(the dataset writer and the contact-label writer both stream this way)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np


class RawColumn:
    """Appends rows of a fixed per-row shape/dtype to a raw file; `finish` writes the .npy."""

    def __init__(self, path: Path, row_shape: tuple[int, ...], dtype):
        self.path, self.row_shape, self.dtype = path, tuple(row_shape), np.dtype(dtype)
        self.raw = path.with_suffix(".raw")
        self.f = open(self.raw, "wb")
        self.rows = 0

    def append(self, a: np.ndarray) -> None:
        a = np.ascontiguousarray(a, dtype=self.dtype)
        if a.shape[1:] != self.row_shape:
            raise ValueError(f"{self.path.name}: rows of shape {self.row_shape} expected, got {a.shape[1:]}")
        a.tofile(self.f)
        self.rows += a.shape[0]

    def finish(self) -> None:
        self.f.close()
        header = {"descr": np.lib.format.dtype_to_descr(self.dtype), "fortran_order": False,
                  "shape": (self.rows,) + self.row_shape}
        with open(self.path, "wb") as out, open(self.raw, "rb") as src:
            np.lib.format.write_array_header_2_0(out, header)
            shutil.copyfileobj(src, out, length=16 << 20)
        self.raw.unlink()
