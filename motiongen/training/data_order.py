"""A resumable, distributed batch order: epoch permutations from (seed, epoch), position saved.

Each step consumes one global batch of `batch_size` indices; rank r of W takes a contiguous
slice of it. The order depends only on (seed, epoch, position), so a resumed run sees exactly
the batches an uninterrupted run would, for any number of processes.
"""

from __future__ import annotations

import torch
from torch.utils.data import Sampler


class ResumableBatchSampler(Sampler[list[int]]):
    def __init__(self, n: int, batch_size: int, seed: int, rank: int = 0, world: int = 1, position: int = 0):
        if batch_size % world:
            raise ValueError(f"batch size {batch_size} is not divisible by {world} processes")
        self.n, self.batch_size, self.seed, self.rank, self.world = n, batch_size, seed, rank, world
        self.position = position   # global batches consumed so far

    def _perm(self, epoch: int) -> torch.Tensor:
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
        return torch.randperm(self.n, generator=g)

    def __iter__(self):
        per_epoch = self.n // self.batch_size   # drop the last partial batch of each epoch
        if per_epoch == 0:
            raise ValueError(f"dataset of {self.n} windows is smaller than one batch of {self.batch_size}")
        local = self.batch_size // self.world
        pos = self.position
        while True:
            epoch, b = divmod(pos, per_epoch)
            perm = self._perm(epoch)
            while b < per_epoch:
                batch = perm[b * self.batch_size:(b + 1) * self.batch_size]
                yield batch[self.rank * local:(self.rank + 1) * local].tolist()
                b += 1
                pos += 1

    def __len__(self):  # infinite; DataLoader only needs this for len(loader)
        return 2 ** 62
