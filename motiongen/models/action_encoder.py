"""Transformer over per-frame multi-hot action labels."""

from __future__ import annotations

import threading
from collections import OrderedDict

import torch
from torch import Tensor, nn

from motiongen.models.layers import Dropout, TransformerStack, sinusoidal_embedding


class ActionEncoder(nn.Module):
    """(B, L, A) -> pooled (B, out_dim) and, with ``per_frame``, (B, L, out_dim).

    Mean pooling over frames as in the reference; the per-frame outputs let the denoiser
    add frame-aligned action information to its frame tokens (the reference's variant).
    """

    def __init__(self, num_actions: int, window: int, width: int, layers: int, heads: int, ff: int,
                 dropout: float, act: str, norm_first: bool, out_dim: int, per_frame: bool,
                 attention_dropout: float = 0.0):
        super().__init__()
        self.per_frame = per_frame
        self.embed = nn.Linear(num_actions, width)
        self.register_buffer("pos", sinusoidal_embedding(torch.arange(window), width), persistent=False)
        self.drop = Dropout(dropout)
        self.blocks = TransformerStack(width, layers, heads, ff, dropout, act, norm_first, attention_dropout)
        self.out = nn.Identity() if width == out_dim else nn.Linear(width, out_dim)
        self.out_frames = nn.Linear(width, out_dim) if per_frame else None

    def forward(self, actions: Tensor) -> tuple[Tensor, Tensor | None]:
        B, L, A = actions.shape
        if L > self.pos.shape[0]:
            raise ValueError(f"action window {L} longer than configured {self.pos.shape[0]}")
        h = self.blocks(self.drop(self.embed(actions) + self.pos[:L]))  # (B, L, W)
        pooled = self.out(h.mean(1))  # (B, out_dim)
        frames = self.out_frames(h) if self.out_frames is not None else None  # (B, L, out_dim)
        return pooled, frames


class ActionMemo:
    """The action encoder's outputs by label window, for sampling. An episode's windows repeat
    their labels (every walking window is all "walk") and a batch's rows mostly share them:
    encoding each distinct row once is the same answer (up to the last bits of a batched matrix
    product) for less, a third of a 2-step student's time at batch 1 (docs/results.md).
    Dropped when the encoder's weights change: a parameter's storage or in-place version
    (inference-mode weights have no version: only their storage, and `Denoiser.train`, count)."""

    def __init__(self, size: int = 256):
        self.size = size
        self.rows: OrderedDict[bytes, tuple[Tensor, Tensor | None]] = OrderedDict()
        self.stamp: tuple = ()
        self.lock = threading.Lock()    # `serve` may sample from more than one thread

    def __getstate__(self):             # deepcopy / pickle: an empty memo, a new lock
        return {"size": self.size}

    def __setstate__(self, state):
        self.__init__(state["size"])

    def clear(self) -> None:
        with self.lock:
            self.rows.clear()

    def __call__(self, enc: ActionEncoder, actions: Tensor) -> tuple[Tensor, Tensor | None]:
        """enc in eval mode, actions (B, L, A) -> pooled (B, out_dim), frames (B, L, out_dim) | None."""
        with self.lock:
            return self._lookup(enc, actions)

    def _lookup(self, enc: ActionEncoder, actions: Tensor) -> tuple[Tensor, Tensor | None]:
        stamp = (actions.shape[1:], actions.dtype, actions.device,
                 tuple((p.data_ptr(), -1 if p.is_inference() else p._version) for p in enc.parameters()))
        if stamp != self.stamp:
            self.rows.clear()
            self.stamp = stamp
        keys = [r.tobytes() for r in actions.detach().to("cpu", torch.float32).numpy()]
        first: dict[bytes, int] = {}                                          # each distinct window's first row
        for i, k in enumerate(keys):
            first.setdefault(k, i)
        missing = [k for k in first if k not in self.rows]
        if missing:
            pooled, frames = enc(actions[[first[k] for k in missing]])        # (M, W), (M, L, W) | None
            for i, k in enumerate(missing):
                self.rows[k] = (pooled[i], None if frames is None else frames[i])
        for k in first:
            self.rows.move_to_end(k)
        while len(self.rows) > max(self.size, len(first)):
            self.rows.popitem(last=False)
        pooled = torch.stack([self.rows[k][0] for k in keys])                  # (B, W)
        frames = None if enc.out_frames is None else torch.stack([self.rows[k][1] for k in keys])
        return pooled, frames
