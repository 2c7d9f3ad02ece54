"""Temporarily set torch's intra-op thread count.

The body-model tensors are small ((T, 22, 3, 3)): on shared CPUs torch's intra-op threads
cost more than they save (measured 10-100x slower per op with 2 threads under load)."""

from __future__ import annotations

import contextlib

import torch


@contextlib.contextmanager
def torch_threads(n: int):
    """Use n threads inside the block (0: leave unchanged), restoring the old value after."""
    old = torch.get_num_threads()
    if n and n != old:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        if n and n != old:
            torch.set_num_threads(old)
