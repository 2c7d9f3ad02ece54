"""LEMO's learned motion priors on marker sequences: the motion smoothness prior and the motion
infilling prior (LEMO supplement), their checkpoints, and the terms a fit uses.

A marker sequence (T, M, 3) is an image for a 2D CNN: xyz are 3 channels, height = time T,
width = markers M (the marker order puts body neighbours next to each other, so 3x3 kernels
mix neighbouring markers and neighbouring frames).

    smooth   encoder: 5 blocks [conv3x3, LeakyReLU, conv3x3, LeakyReLU], channels [32, 64, 64, 64, 64],
             no pooling: the latent keeps the full T x M resolution (the smoothness constraint
             works on the latent's change over time); decoder: 5 blocks of two 3x3 (de)convs
             back to xyz.
    infill   input xyz with the missing entries zeroed + the observed mask (4 channels); encoder
             5 blocks [conv, LReLU, conv, LReLU, MaxPool 2x2], channels [32, 64, 128, 256, 256];
             decoder 5 blocks [upsample x2, conv, LReLU, conv, LReLU], then a 3x3 conv to xyz.
             The input is padded (replicate) to multiples of 32 in T and M and cropped back.
             Its output is a correction added to `interpolate_missing` (each missing marker
             at the visible body's horizontal centre plus its offset from it, linear in time
             between the marker's observed frames): not in the paper, which
             trained for days on a GPU; with minutes on a CPU, whole positions through the
             1/32-resolution bottleneck stay tens of cm off, the correction does not.

A stride-1 3x3 transposed convolution is a 3x3 convolution (with a flipped kernel), so the
decoders use `Conv2d`, which has replicate padding (`ConvTranspose2d` pads with zeros only):
every convolution pads by replicating the border, so a sequence that is constant in time has a
latent that is exactly constant in time (no border effects), and `smoothness_term` is exactly 0
there.

Coordinates. The networks see markers in a canonical frame, normalised per (marker,
coordinate) by the training data's mean and std (stored in the checkpoint):
`canonical_frame` puts the origin at the first frame's marker mean on the floor (x, z; y stays
the height above the floor) and turns about y so that the first frame faces +z (facing =
left-right x up, from the mean left-minus-right vector of the mirror pairs). The public terms
(`smoothness_term`, `infill`) take world-frame markers (T, M, 3): they cut the clip into
windows of the training length (half overlapping), canonicalise each window by its own first
frame (the frame computed without gradients, then applied differentiably), and map the result
back. Windows, not the whole clip at once: the networks only ever saw windows of that length
starting near the canonical origin; a long clip in one piece would put its later frames metres
away from anything in the training data (the normalisation makes that an input many standard
deviations off), while a window's own frame keeps every input in distribution.

Checkpoints: `save_prior` / `load_prior` (format "motiongen-motion-prior"); trained by
`motiongen train-motion-prior` (motiongen/capture/train_motion_prior.py).
"""

from __future__ import annotations

import os
import pickle
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import torch
from torch import nn
import torch.nn.functional as F

from motiongen.checks import require_choice, require_range
from motiongen.errors import ConfigError, DataError

FORMAT = "motiongen-motion-prior"
FORMAT_VERSION = 1
KINDS = ("smooth", "infill")
PAPER_CHANNELS = {"smooth": [32, 64, 64, 64, 64], "infill": [32, 64, 128, 256, 256]}
DEFAULT_WINDOW = 64           # frames: the window of the public terms when a prior does not say
MIN_STD = 0.01                # m: floor of the per-(marker, coordinate) std


@dataclass
class PriorNetConfig:
    kind: str = "smooth"                 # smooth | infill
    channels: list[int] | None = None    # encoder feature channels per block; None: the paper's for `kind`
    slope: float = 0.2                   # LeakyReLU negative slope

    def __post_init__(self):
        require_choice("net.kind", self.kind, KINDS)
        if self.channels is not None:
            chans = list(self.channels)
            if not chans:
                raise ConfigError("net.channels: expected a non-empty list of integers >= 1, got []")
            for c in chans:
                require_range("net.channels", c, 1, 4096, integer=True)
            self.channels = [int(c) for c in chans]
        require_range("net.slope", self.slope, 0, 1)

    def resolved_channels(self) -> list[int]:
        return list(self.channels) if self.channels is not None else list(PAPER_CHANNELS[self.kind])


# ---- networks ------------------------------------------------------------------------------

def _conv(cin: int, cout: int) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, padding=1, padding_mode="replicate")


class _Block(nn.Sequential):
    """[conv3x3, LeakyReLU, conv3x3, LeakyReLU]."""

    def __init__(self, cin: int, cout: int, slope: float):
        super().__init__(_conv(cin, cout), nn.LeakyReLU(slope), _conv(cout, cout), nn.LeakyReLU(slope))


class SmoothNet(nn.Module):
    """The smoothness prior's autoencoder: full-resolution latent (B, C[-1], T, M)."""

    def __init__(self, channels: Sequence[int], slope: float = 0.2, in_channels: int = 3):
        super().__init__()
        ch = [in_channels, *channels]
        self.encoder = nn.Sequential(*[_Block(ch[i], ch[i + 1], slope) for i in range(len(channels))])
        rev = list(reversed(channels))
        dec = [_Block(rev[i], rev[i + 1], slope) for i in range(len(rev) - 1)]
        # The last block ends in xyz: [deconv, LReLU, deconv] (no activation on the output).
        dec.append(nn.Sequential(_conv(rev[-1], rev[-1]), nn.LeakyReLU(slope), _conv(rev[-1], 3)))
        self.decoder = nn.Sequential(*dec)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        return self.encoder(x)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        z = self.encoder(x)
        return self.decoder(z), z


class InfillNet(nn.Module):
    """The infilling prior's encoder-decoder: 2x2 max-pooling after each encoder block,
    upsampling before each decoder block; T and M padded (replicate) to multiples of 2^blocks."""

    def __init__(self, channels: Sequence[int], slope: float = 0.2, in_channels: int = 4):
        super().__init__()
        ch = [in_channels, *channels]
        self.encoder = nn.ModuleList([_Block(ch[i], ch[i + 1], slope) for i in range(len(channels))])
        rev = list(reversed(channels))
        outs = rev[1:] + [rev[-1]]
        self.decoder = nn.ModuleList([_Block(rev[i], outs[i], slope) for i in range(len(rev))])
        self.head = _conv(outs[-1], 3)
        self.multiple = 2 ** len(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        T, M = x.shape[-2:]
        m = self.multiple
        pt, pm = (-T) % m, (-M) % m
        if pt or pm:
            x = F.pad(x, (0, pm, 0, pt), mode="replicate")
        for blk in self.encoder:
            x = F.max_pool2d(blk(x), 2)
        for blk in self.decoder:
            x = blk(F.interpolate(x, scale_factor=2.0, mode="nearest"))
        return self.head(x)[..., :T, :M]


def build_net(cfg: PriorNetConfig) -> nn.Module:
    """The network of `cfg`, He-initialised for its LeakyReLUs (torch's default init shrinks the
    signal by about 3x in variance per layer: 20 layers deep, the untrained net's output and
    gradients would be ~1e-5 of their input and training would stall)."""
    chans = cfg.resolved_channels()
    net = SmoothNet(chans, cfg.slope) if cfg.kind == "smooth" else InfillNet(chans, cfg.slope)
    convs = [m for m in net.modules() if isinstance(m, nn.Conv2d)]
    for i, m in enumerate(convs):
        last = i == len(convs) - 1                     # the output layer is linear
        nn.init.kaiming_normal_(m.weight, a=cfg.slope, nonlinearity="linear" if last else "leaky_relu")
        nn.init.zeros_(m.bias)
    return net


# ---- canonical frame -----------------------------------------------------------------------

def _as_index(idx) -> torch.Tensor:
    return torch.as_tensor(list(idx) if not isinstance(idx, torch.Tensor) else idx, dtype=torch.long).reshape(-1)


@torch.no_grad()
def canonical_frames(markers: torch.Tensor, left, right, observed: torch.Tensor | None = None
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """Batched `canonical_frame`: markers (B, T, M, 3), observed (B, T, M) bool or None (all) ->
    origin (B, 3), rot (B, 3, 3). The reference frame is each item's first frame with an
    observed marker; the origin is its observed markers' mean on the floor (y = 0), the
    rotation about y takes its facing (the mean left-minus-right vector of the pairs observed on
    both sides, crossed with up) to +z. No observed pair: no rotation."""
    x = markers.detach()
    B, T, M, _ = x.shape
    if observed is None:
        observed = torch.ones(B, T, M, dtype=torch.bool, device=x.device)
    observed = observed.to(torch.bool)
    x = torch.where(observed[..., None], x, torch.zeros((), dtype=x.dtype, device=x.device))
    first = observed.any(-1).to(torch.int8).argmax(-1)                       # (B,): 0 when none
    ar = torch.arange(B, device=x.device)
    x0, w = x[ar, first], observed[ar, first].to(x.dtype)                   # (B, M, 3), (B, M)
    origin = (x0 * w[..., None]).sum(1) / w.sum(1).clamp_min(1)[..., None]
    origin = origin * torch.tensor([1.0, 0.0, 1.0], dtype=x.dtype, device=x.device)
    li, ri = _as_index(left).to(x.device), _as_index(right).to(x.device)
    pair = w[:, li] * w[:, ri]                                              # (B, P)
    lr = ((x0[:, li] - x0[:, ri]) * pair[..., None]).sum(1) / pair.sum(1).clamp_min(1)[..., None]
    # facing = left x up = (-lr_z, 0, lr_x); yaw = atan2(f_x, f_z); rot = R_y(-yaw).
    yaw = torch.atan2(-lr[:, 2], lr[:, 0])
    c, s = torch.cos(-yaw), torch.sin(-yaw)
    zero, one = torch.zeros_like(c), torch.ones_like(c)
    rot = torch.stack([torch.stack([c, zero, s], -1), torch.stack([zero, one, zero], -1),
                       torch.stack([-s, zero, c], -1)], -2)
    return origin, rot


def canonical_frame(markers: torch.Tensor, left, right, observed: torch.Tensor | None = None
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """origin (3,), rot (3, 3) of a marker sequence (T, M, 3) (see `canonical_frames`): `left`
    and `right` index the two markers of each mirror pair (any marker set works); `observed`
    (T, M) bool restricts the reference to the observed markers. Computed without gradients."""
    x = torch.as_tensor(markers)
    o = None if observed is None else torch.as_tensor(observed)[None]
    origin, rot = canonical_frames(x[None], left, right, o)
    return origin[0], rot[0]


def to_canonical(markers: torch.Tensor, origin: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
    """World -> canonical: (x - origin) rot^T. markers (..., M, 3); origin (..., 3) and rot
    (..., 3, 3) broadcast over the leading axes ((3,), (3, 3) for one sequence; (B, 1, 1, 3),
    (B, 1, 3, 3) for a batch (B, T, M, 3))."""
    return (markers - origin[..., None, :]) @ rot.transpose(-1, -2)


def from_canonical(markers: torch.Tensor, origin: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
    """Canonical -> world: x rot + origin (the inverse of `to_canonical`)."""
    return markers @ rot + origin[..., None, :]


def _batch_to_canonical(x: torch.Tensor, origin: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
    return to_canonical(x, origin[:, None], rot[:, None])


def _batch_from_canonical(x: torch.Tensor, origin: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
    return from_canonical(x, origin[:, None], rot[:, None])


def _interp_time(v: torch.Tensor, obs: torch.Tensor, fill: torch.Tensor) -> torch.Tensor:
    """v (B, T, M, 3): each entry where `obs` (B, T, M) is False replaced by linear interpolation
    in time between its column's nearest observed frames, held before the first and after the
    last; `fill` (broadcast to v) where a column has no observed frame."""
    B, T, M, _ = v.shape
    t = torch.arange(T, device=v.device).view(1, T, 1).expand(B, T, M)
    prev = torch.where(obs, t, torch.full_like(t, -1)).cummax(1).values                   # (B, T, M)
    nxt = torch.where(obs, t, torch.full_like(t, T)).flip(1).cummin(1).values.flip(1)
    has_prev, has_next = prev >= 0, nxt < T
    vp = v.gather(1, prev.clamp(0, T - 1)[..., None].expand(B, T, M, 3))
    vn = v.gather(1, nxt.clamp(0, T - 1)[..., None].expand(B, T, M, 3))
    w = ((t - prev).to(v.dtype) / (nxt - prev).clamp_min(1).to(v.dtype))[..., None]
    out = torch.where((has_prev & has_next)[..., None], vp + (vn - vp) * w,
                      torch.where(has_prev[..., None], vp, torch.where(has_next[..., None], vn, fill.expand_as(v))))
    return torch.where(obs[..., None], v, out)


def interpolate_missing(x: torch.Tensor, observed: torch.Tensor, fill: torch.Tensor,
                        reference: torch.Tensor | None = None) -> torch.Tensor:
    """x (B, T, M, 3) with each missing entry filled from its marker's nearest observed frames,
    as an offset from the body's horizontal centre: the centre r_t (x, z; y = 0) is the mean of
    the `reference` markers (M,) bool (None: all) observed in frame t (interpolated in time over
    frames with none); a missing marker is r_t plus its offset from the centre interpolated
    linearly in time (held before its first and after its last observation), so a walking body's
    hidden legs travel with its visible trunk. A marker never observed in the window gets `fill`
    (M, 3), the mean body, placed at r_t. Observed entries are unchanged; NaN in missing entries
    never leaks (values are selected, not multiplied)."""
    obs = observed.to(torch.bool)
    zero = torch.zeros((), dtype=x.dtype, device=x.device)
    xs = torch.where(obs[..., None], x, zero)
    ref = obs if reference is None else obs & reference.to(device=x.device, dtype=torch.bool)
    cnt = ref.sum(-1, keepdim=True)                                                        # (B, T, 1)
    flat = torch.tensor([1.0, 0.0, 1.0], dtype=x.dtype, device=x.device)
    r = (torch.where(ref[..., None], xs, zero).sum(2) / cnt.clamp_min(1)) * flat          # (B, T, 3)
    r = _interp_time(r[:, :, None], cnt > 0, torch.zeros(3, dtype=x.dtype, device=x.device))  # (B, T, 1, 3)
    fill = fill.to(x.dtype)
    rel_fill = fill - fill.mean(0) * flat
    return torch.where(obs[..., None], xs, r + _interp_time(xs - r, obs, rel_fill))


# ---- the prior -----------------------------------------------------------------------------

class MotionPrior(nn.Module):
    """A motion prior: the network, its normalisation (mean, std per (marker, coordinate) of
    canonical training markers), its kind, marker count, mirror pairs and training window.

    The methods take *canonical* batches (B, T, M, 3) (what training feeds them; see
    `canonicalise`); the module-level `smoothness_term` and `infill` take world-frame (T, M, 3).
    """

    def __init__(self, config: PriorNetConfig, num_markers: int, left: Sequence[int], right: Sequence[int],
                 mean: torch.Tensor | None = None, std: torch.Tensor | None = None, window: int = DEFAULT_WINDOW,
                 reference: Sequence[int] | None = None):
        super().__init__()
        self.config = config
        self.num_markers = int(num_markers)
        self.window = int(window)
        self.net = build_net(config)
        self.register_buffer("left", _as_index(left))
        self.register_buffer("right", _as_index(right))
        if len(self.left) != len(self.right):
            raise ConfigError(f"mirror pairs: {len(self.left)} left markers but {len(self.right)} right ones")
        if len(self.left) and int(torch.cat([self.left, self.right]).max()) >= self.num_markers:
            raise ConfigError(f"mirror pairs: a marker index is >= the marker count {self.num_markers}")
        M = self.num_markers
        self.register_buffer("mean", torch.zeros(M, 3) if mean is None else torch.as_tensor(mean, dtype=torch.float32).clone())
        self.register_buffer("std", torch.ones(M, 3) if std is None else torch.as_tensor(std, dtype=torch.float32).clone())
        ref = torch.ones(M, dtype=torch.bool)
        if reference is not None:
            ref = torch.zeros(M, dtype=torch.bool)
            ref[_as_index(reference)] = True
        self.register_buffer("reference", ref)      # infill: the markers whose centre the gaps follow
        if self.mean.shape != (M, 3) or self.std.shape != (M, 3):
            raise ConfigError(f"normalisation: expected mean and std of shape ({M}, 3), got "
                              f"{tuple(self.mean.shape)} and {tuple(self.std.shape)}")

    @property
    def kind(self) -> str:
        return self.config.kind

    def set_normalisation(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        self.mean.copy_(torch.as_tensor(mean, dtype=self.mean.dtype))
        self.std.copy_(torch.as_tensor(std, dtype=self.std.dtype).clamp_min(MIN_STD))

    # -- coordinates
    def canonicalise(self, markers: torch.Tensor, observed: torch.Tensor | None = None):
        """World batch (B, T, M, 3) -> (canonical batch, origin (B, 3), rot (B, 3, 3)); the
        frame is computed without gradients and applied differentiably."""
        origin, rot = canonical_frames(markers, self.left, self.right, observed)
        return _batch_to_canonical(markers, origin, rot), origin, rot

    def normalise(self, canon: torch.Tensor) -> torch.Tensor:
        """Canonical (B, T, M, 3) -> the network's image (B, 3, T, M)."""
        return ((canon - self.mean) / self.std).permute(0, 3, 1, 2)

    def denormalise(self, image: torch.Tensor) -> torch.Tensor:
        """The network's image (B, 3, T, M) -> canonical (B, T, M, 3)."""
        return image.permute(0, 2, 3, 1) * self.std + self.mean

    def _check(self, canon: torch.Tensor) -> None:
        if canon.ndim != 4 or canon.shape[-2:] != (self.num_markers, 3) or canon.shape[1] < 1:
            raise ConfigError(f"markers: expected shape (B, T>=1, {self.num_markers}, 3), got {tuple(canon.shape)}")

    # -- smooth
    def encode(self, canon: torch.Tensor) -> torch.Tensor:
        """Smoothness prior: canonical (B, T, M, 3) -> latent (B, C, T, M)."""
        self._need("smooth", "encode")
        self._check(canon)
        return self.net.encode(self.normalise(canon))

    def reconstruct(self, canon: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Smoothness prior: canonical (B, T, M, 3) -> (reconstruction (B, T, M, 3) canonical,
        latent (B, C, T, M))."""
        self._need("smooth", "reconstruct")
        self._check(canon)
        out, z = self.net(self.normalise(canon))
        return self.denormalise(out), z

    # -- infill
    def infill_input(self, canon: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
        """(B, 4, T, M): normalised xyz with the missing entries 0 (NaN there never leaks), and
        the observed mask."""
        obs = observed.to(torch.bool)
        x = self.normalise(torch.where(obs[..., None], canon, self.mean.detach()))
        mask = obs[:, None].to(x.dtype)
        return torch.cat([x * mask, mask], 1)

    def predict(self, canon: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
        """Infilling prior: the network's full markers (B, T, M, 3) canonical, observed ones
        included (training compares them all). The network predicts the correction to
        `interpolate_missing` (each missing marker's offset from the visible body's horizontal
        centre, linear in time between its observed frames): the interpolation carries where the
        legs are, the network the motion inside a gap (a stride's swing), which it learns far
        sooner than whole positions through its 1/32-resolution bottleneck."""
        self._need("infill", "predict")
        self._check(canon)
        base = self.normalise(interpolate_missing(canon, observed, self.mean, self.reference))
        return self.denormalise(base + self.net(self.infill_input(canon, observed)))

    def complete(self, canon: torch.Tensor, observed: torch.Tensor) -> torch.Tensor:
        """Infilling prior: canonical (B, T, M, 3) with observed (B, T, M) -> the observed entries
        as given, the missing ones from the network."""
        obs = observed.to(torch.bool)[..., None]
        return torch.where(obs, canon, self.predict(canon, observed))

    def _need(self, kind: str, what: str) -> None:
        if self.kind != kind:
            raise ConfigError(f"{what} needs a {kind} prior; this one is a {self.kind} prior")

    # -- checkpoint
    def checkpoint(self, meta: dict | None = None) -> dict:
        return {"format": FORMAT, "version": FORMAT_VERSION, "kind": self.kind, "config": asdict(self.config),
                "num_markers": self.num_markers, "window": self.window,
                "left": self.left.tolist(), "right": self.right.tolist(),
                "reference": self.reference.nonzero().flatten().tolist(),
                "mean": self.mean.detach().cpu().clone(), "std": self.std.detach().cpu().clone(),
                "state_dict": {k: v.detach().cpu().clone() for k, v in self.net.state_dict().items()},
                "meta": _plain(meta or {})}

    @classmethod
    def from_checkpoint(cls, ckpt: dict) -> "MotionPrior":
        cfg = PriorNetConfig(**ckpt["config"])
        prior = cls(cfg, ckpt["num_markers"], ckpt["left"], ckpt["right"], ckpt["mean"], ckpt["std"],
                    window=ckpt.get("window", DEFAULT_WINDOW), reference=ckpt.get("reference"))
        prior.net.load_state_dict(ckpt["state_dict"])
        prior.meta = ckpt.get("meta", {})
        return prior.eval()


def _plain(x):
    """Meta as plain Python (what a weights-only torch.load reads back)."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, (str, int, float, bool)) or x is None:
        return x
    if isinstance(x, Path):
        return str(x)
    if hasattr(x, "item") and getattr(x, "ndim", 1) == 0:
        return x.item()
    if hasattr(x, "tolist"):
        return x.tolist()
    return str(x)


# ---- the terms a fit uses (world-frame (T, M, 3)) -----------------------------------------

def _windows(T: int, W: int) -> list[int]:
    """Starts of half-overlapping windows of W frames covering [0, T) (one window when T <= W)."""
    if T <= W:
        return [0]
    hop = max(1, W // 2)
    starts = list(range(0, T - W + 1, hop))
    if starts[-1] != T - W:
        starts.append(T - W)
    return starts


def _check_world(prior: MotionPrior, markers: torch.Tensor, name: str = "markers") -> torch.Tensor:
    x = torch.as_tensor(markers)
    if x.ndim != 3 or x.shape[1:] != (prior.num_markers, 3) or x.shape[0] < 1:
        raise ConfigError(f"{name}: expected shape (T>=1, {prior.num_markers}, 3), got {tuple(x.shape)}")
    return x


def _param_dtype(prior: MotionPrior) -> tuple[torch.dtype, torch.device]:
    p = prior.mean
    return p.dtype, p.device


def smoothness_term(prior: MotionPrior, markers: torch.Tensor, window: int | None = None) -> torch.Tensor:
    """E_smooth: the mean over the latent of ||z_{t+1} - z_t||^2 (per latent entry, a scalar
    tensor, differentiable with respect to `markers` (T, M, 3), world frame). Windows of the
    prior's training length (half overlapping, each in its own canonical frame); exactly 0 for
    a sequence constant in time; 0 for T = 1."""
    prior._need("smooth", "smoothness_term")
    x = _check_world(prior, markers)
    dtype, dev = _param_dtype(prior)
    x = x.to(dtype=dtype, device=dev)
    T = x.shape[0]
    if T < 2:
        return x.sum() * 0
    W = max(2, int(window or prior.window))
    starts = _windows(T, W)
    L = min(W, T)
    batch = torch.stack([x[s:s + L] for s in starts])                       # (n, L, M, 3)
    canon, _, _ = prior.canonicalise(batch)
    z = prior.encode(canon)                                                 # (n, C, L, M)
    return (z[:, :, 1:] - z[:, :, :-1]).square().mean()


def infill(prior: MotionPrior, markers: torch.Tensor, observed: torch.Tensor, window: int | None = None) -> torch.Tensor:
    """Markers (T, M, 3) world frame with the missing ones filled in: `observed` (T, M) bool
    entries are returned exactly as given, the others (any value, NaN included) come from the
    network. Any T >= 1: half-overlapping windows of the prior's training length, each in the
    canonical frame of its own observed markers, blended with triangular weights. Runs without
    gradients (the result is a target, not a term)."""
    prior._need("infill", "infill")
    x = _check_world(prior, markers)
    obs = torch.as_tensor(observed)
    if obs.shape != x.shape[:2]:
        raise ConfigError(f"observed: expected shape {tuple(x.shape[:2])}, got {tuple(obs.shape)}")
    obs = obs.to(device=x.device, dtype=torch.bool)
    dtype, dev = _param_dtype(prior)
    T = x.shape[0]
    W = max(1, int(window or prior.window))
    with torch.no_grad():
        xc = torch.where(obs[..., None], x, torch.zeros((), dtype=x.dtype, device=x.device)).to(dtype=dtype, device=dev)
        oc = obs.to(dev)
        starts = _windows(T, W)
        L = min(W, T)
        batch = torch.stack([xc[s:s + L] for s in starts])
        bobs = torch.stack([oc[s:s + L] for s in starts])
        canon, origin, rot = prior.canonicalise(batch, bobs)
        pred = _batch_from_canonical(prior.predict(canon, bobs), origin, rot)   # (n, L, M, 3)
        # Triangular weights (ends > 0): overlapping windows fade into each other.
        ramp = torch.minimum(torch.arange(1, L + 1, dtype=dtype, device=dev), torch.arange(L, 0, -1, dtype=dtype, device=dev))
        acc = torch.zeros(T, x.shape[1], 3, dtype=dtype, device=dev)
        wsum = torch.zeros(T, 1, 1, dtype=dtype, device=dev)
        for i, s in enumerate(starts):
            acc[s:s + L] += pred[i] * ramp[:, None, None]
            wsum[s:s + L] += ramp[:, None, None]
        full = (acc / wsum).to(dtype=x.dtype, device=x.device)
    return torch.where(obs[..., None], x, full)


# ---- checkpoints -----------------------------------------------------------------------------

def save_prior(path: str | Path, prior: MotionPrior, meta: dict | None = None) -> Path:
    """Write `prior` (kind, net config, normalisation, marker count, mirror pairs, window,
    weights) and the training `meta` to `path`, atomically (temp file, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        torch.save(prior.checkpoint(meta), tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def load_prior(path: str | Path, device: str | torch.device = "cpu") -> MotionPrior:
    """The prior at `path` (eval mode). DataError(path, None, reason) when the file is missing
    or is not a motion-prior checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, None, "motion prior checkpoint not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise DataError(path, None, "not a motion-prior checkpoint (it holds Python objects, like a motion model "
                                    "from `motiongen train`); give the prior.pt of `motiongen train-motion-prior`") from None
    except Exception as e:
        raise DataError(path, None, f"not a motion-prior checkpoint ({type(e).__name__}: "
                                    f"{str(e).splitlines()[0] if str(e) else 'unreadable'})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        what = ckpt.get("kind") if isinstance(ckpt, dict) else None
        hint = f" (its kind is {what!r})" if isinstance(what, str) else ""
        raise DataError(path, None, f"not a motion-prior checkpoint{hint}; give the prior.pt of "
                                    "`motiongen train-motion-prior`")
    if ckpt.get("version") != FORMAT_VERSION:
        raise DataError(path, "version", f"expected motion-prior format version {FORMAT_VERSION}, "
                                         f"found {ckpt.get('version')!r}")
    try:
        return MotionPrior.from_checkpoint(ckpt).to(device)
    except Exception as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise DataError(path, None, f"corrupt motion-prior checkpoint ({msg})") from None


def latent_shape(prior: MotionPrior, T: int) -> tuple[int, int, int]:
    """(C, T, M) of the smoothness prior's latent for T frames (the full input resolution)."""
    return (prior.config.resolved_channels()[-1], T, prior.num_markers)


def count_parameters(prior: MotionPrior) -> int:
    return sum(p.numel() for p in prior.net.parameters())

