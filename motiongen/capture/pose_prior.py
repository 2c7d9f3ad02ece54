"""A Gaussian pose prior with a linear decoder: θ = V(z), L_z = ‖z‖² of the multi-view capture
paper.

The paper optimises a latent z per frame and decodes the 21 body-joint rotations with a
pretrained VAE (VPoser). We ship no VAE. Its linear-Gaussian special case is PCA: with the
mean μ, the principal directions U (d, 63) and standard deviations σ (d,) of axis-angle body
poses,

    θ = V(z) = μ + (σ ⊙ z) U,      z ~ N(0, I),

so ‖z‖² is the Mahalanobis distance of θ from the pose distribution: the paper's L_z term
penalises unusual poses exactly as a standard-normal latent does. By default all 63
directions are kept (d = 63, a full-rank Gaussian) and σ is floored at `min_std`, so no pose
is out of reach, only more expensive; `dims` < 63 restricts poses to a subspace.

Where the statistics come from (`motiongen pose-prior`, `fit_prior`):
SMPL-X body poses of a motiongen dataset (`smplx_body_pose.npy`, e.g. AMASS imported with
`motiongen.importers.amass`) or AMASS-style npz files (`poses`/`pose_body`, e.g. our own
fits). Without one, `default_prior()` is fitted to parameter sequences of
`motiongen.body.random_motion.sample_motion` (the generator the joints→SMPL-X MLP trains on: per-joint
anatomical limits, smooth random postures, walking cycles). That is a hand-designed
anatomical prior, not statistics of real people; docs/capture.md says so.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from motiongen.body.random_motion import sample_motion
from motiongen.checks import require_output_path
from motiongen.cli import parse_key_values, tool_main
from motiongen.data.format import MotionDataset
from motiongen.errors import ConfigError, DataError
from motiongen.importers.amass import load_amass
from motiongen.output_lock import refuse_output_over_input

FORMAT = "motiongen-pose-prior"
POSE_DIM = 63
DEFAULT_MIN_STD = 0.05        # radians: the stiffest direction still moves ~3 degrees per unit of z
DEFAULT_SEED, DEFAULT_SEQUENCES, DEFAULT_FRAMES = 20240, 96, 240


@dataclass
class PosePrior:
    mean: np.ndarray          # (63,) axis-angle body pose
    components: np.ndarray    # (d, 63) orthonormal rows
    std: np.ndarray           # (d,) radians
    source: str
    num_poses: int

    @property
    def dims(self) -> int:
        return len(self.std)

    def decoder(self, dtype=torch.float32, device="cpu") -> "LinearDecoder":
        return LinearDecoder(self, dtype, device)

    def encode(self, poses: np.ndarray) -> np.ndarray:
        """Axis-angle poses (..., 63) -> latents (..., d) (the least-squares inverse of V)."""
        return ((np.asarray(poses, np.float64) - self.mean) @ self.components.T) / self.std

    def decode(self, z: np.ndarray) -> np.ndarray:
        return self.mean + (np.asarray(z, np.float64) * self.std) @ self.components

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
        np.savez(tmp, format=np.array(FORMAT), mean=self.mean, components=self.components, std=self.std,
                 source=np.array(self.source), num_poses=np.array(self.num_poses))
        os.replace(tmp, path)
        return path


class LinearDecoder(torch.nn.Module):
    """V(z) = μ + (σ ⊙ z) U as a differentiable map: (..., d) -> (..., 63)."""

    def __init__(self, prior: PosePrior, dtype=torch.float32, device="cpu"):
        super().__init__()
        self.register_buffer("mean", torch.as_tensor(prior.mean, dtype=dtype, device=device))
        self.register_buffer("W", torch.as_tensor(prior.std[:, None] * prior.components, dtype=dtype, device=device))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.mean + z @ self.W


def fit_prior(poses: np.ndarray, dims: int | None = None, min_std: float = DEFAULT_MIN_STD,
              source: str = "poses") -> PosePrior:
    """PCA of axis-angle body poses (N, 63) -> PosePrior with `dims` directions (all by default)."""
    X = np.asarray(poses, np.float64).reshape(-1, POSE_DIM)
    if len(X) < 2 or not np.isfinite(X).all():
        raise ConfigError(f"pose prior: need at least 2 finite poses, got {len(X)}")
    d = POSE_DIM if dims is None else int(dims)
    if not 1 <= d <= POSE_DIM:
        raise ConfigError(f"dims={dims}: expected 1..{POSE_DIM}")
    if not min_std > 0:
        raise ConfigError(f"min_std={min_std}: expected a positive number (radians)")
    mean = X.mean(0)
    evals, evecs = np.linalg.eigh(np.cov(X, rowvar=False))                # ascending, (63,), (63, 63)
    order = np.argsort(evals)[::-1][:d]
    std = np.sqrt(np.clip(evals[order], 0, None))
    return PosePrior(mean, evecs[:, order].T.copy(), np.maximum(std, min_std), source, len(X))


@functools.lru_cache(maxsize=4)
def default_prior(min_std: float = DEFAULT_MIN_STD, dims: int | None = None) -> PosePrior:
    """The built-in prior: PCA of `sample_motion` poses (fixed seed; about 0.5 s, cached in the
    process: treat the result as read-only)."""
    rng = np.random.default_rng(DEFAULT_SEED)
    poses = [sample_motion(DEFAULT_FRAMES, 30.0, rng)["body_pose"] for _ in range(DEFAULT_SEQUENCES)]
    return fit_prior(np.concatenate(poses), dims, min_std,
                     source=f"builtin: sample_motion seed {DEFAULT_SEED}, {DEFAULT_SEQUENCES}x{DEFAULT_FRAMES} frames")


def load_prior(path: str | Path | None) -> PosePrior:
    """A prior file written by `PosePrior.save`, or the built-in one for None / "builtin"."""
    if path in (None, "", "builtin"):
        return default_prior()
    path = Path(path)
    if not path.is_file():
        raise DataError(path, None, "pose prior file does not exist (make one with python -m "
                                    "motiongen.capture.pose_prior, or use prior=builtin)")
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except Exception as e:
        raise DataError(path, None, f"not a readable .npz file ({type(e).__name__}: {e})") from None
    if str(d.get("format", "")) != FORMAT:
        raise DataError(path, "format", f"not a pose prior file (expected format {FORMAT!r})")
    mean, comp, std = d["mean"], d["components"], d["std"]
    if mean.shape != (POSE_DIM,) or comp.ndim != 2 or comp.shape[1] != POSE_DIM or std.shape != (len(comp),):
        raise DataError(path, "components", f"inconsistent shapes mean {mean.shape}, components {comp.shape}, "
                                            f"std {std.shape}")
    if not (np.isfinite(comp).all() and np.isfinite(mean).all() and (std > 0).all()):
        raise DataError(path, "std", "non-finite values or non-positive standard deviations")
    return PosePrior(mean.astype(np.float64), comp.astype(np.float64), std.astype(np.float64),
                     str(d.get("source", "")), int(d.get("num_poses", 0)))


# ---- CLI ------------------------------------------------------------------------------------

SPEC = {"out": (str, None), "data.root": (str, None), "amass": (list, []), "dims": (int, None),
        "min_std": (float, DEFAULT_MIN_STD), "builtin": (bool, False)}
USAGE = ("motiongen pose-prior out=prior.npz "
         "(data.root=DATASET | amass=[a.npz,...] | builtin=true) [dims=63] [min_std=0.05]")


def _poses_from_dataset(root: str) -> np.ndarray:
    ds = MotionDataset.open(root)
    if not ds.meta.get("has_smplx"):
        raise DataError(Path(root) / "meta.json", "has_smplx", "the dataset has no SMPL-X poses "
                        "(import AMASS-style files with motiongen import-amass)")
    return np.asarray(np.load(Path(root) / "smplx_body_pose.npy", mmap_mode="r"), np.float64)


def _poses_from_amass(path: str) -> np.ndarray:
    return load_amass(path).body_pose


def run(argv: list[str]) -> PosePrior:
    opts = parse_key_values(argv, SPEC, required=("out",), usage=USAGE, doc=__doc__)
    sources = [bool(opts["data.root"]), bool(opts["amass"]), opts["builtin"]]
    if sum(sources) != 1:
        raise ConfigError(f"give exactly one of data.root=, amass=[...], builtin=true (usage: {USAGE})")
    require_output_path("out", opts["out"], directory=False)
    refuse_output_over_input(opts["out"], opts["amass"])
    if opts["builtin"]:
        prior = default_prior(opts["min_std"], opts["dims"])
    elif opts["data.root"]:
        prior = fit_prior(_poses_from_dataset(opts["data.root"]), opts["dims"], opts["min_std"],
                          source=f"dataset {opts['data.root']}")
    elif opts["amass"]:
        poses = np.concatenate([_poses_from_amass(p) for p in opts["amass"]])
        prior = fit_prior(poses, opts["dims"], opts["min_std"], source=f"amass {len(opts['amass'])} files")
    path = prior.save(opts["out"])
    print(f"pose prior: {prior.num_poses} poses, {prior.dims} directions, std {prior.std.min():.3f}.."
          f"{prior.std.max():.3f} rad ({prior.source}) -> {path}", flush=True)
    return prior


main = tool_main(run)


if __name__ == "__main__":
    main()
