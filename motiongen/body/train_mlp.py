"""Train the 3-frame joints → SMPL-X MLP (`motiongen train-body-mlp`, or `motiongen train
task=joints2body`: motiongen/commands/).

Training pairs are (joints, parameters) with joints produced by *our* body model from the
parameters, so the network learns the inverse of exactly the kinematics that refinement uses.
Parameters come from a dataset's SMPL-X fields when `data.root` names one that has them,
otherwise from `motiongen.body.random_motion.sample_motion` (joint-limited smooth random motion and
gait cycles). Logs to TensorBoard under `out`; the checkpoint `out/mlp.pt` holds the config.
"""

from __future__ import annotations

import math
import os
import pickle
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from motiongen.body._threads import torch_threads
from motiongen.body.mlp import JointsToBodyMLP, MLPConfig, canonicalise
from motiongen.body.model import BodyModel, load_body_model
from motiongen.body.random_motion import sample_motion
from motiongen.body.rotations import axis_angle_to_matrix, rot6d_to_matrix
from motiongen.checks import require_fps, require_range
from motiongen.data.format import MotionDataset
from motiongen.errors import ConfigError, DataError
from motiongen.geometry import yaw_matrix
from motiongen.rates import DATA_FPS


@dataclass
class BodyConfig:
    model_path: str | None = None   # SMPL-X .npz; None: $MOTIONGEN_SMPLX_MODEL, else procedural
    num_betas: int = 10


@dataclass
class DataConfig:
    root: str | None = None         # motiongen dataset with SMPL-X fields; None: synthetic motion
    split: str | None = "train"
    num_sequences: int = 256        # synthetic: sequences in the pool
    seq_frames: int = 240           # synthetic: frames per sequence
    fps: float = DATA_FPS
    edge_prob: float = 0.1          # chance a neighbour is replaced by the middle frame (as at edges)


@dataclass
class TrainMLPConfig:
    out: str = "runs/joints_to_body"
    seed: int = 0
    steps: int = 20000
    batch_size: int = 512
    lr: float = 1e-3
    weight_decay: float = 0.0
    w_rot: float = 1.0              # squared Frobenius distance of rotation matrices
    w_joints: float = 50.0          # squared joint error (m²) through forward kinematics
    w_betas: float = 0.05
    log_every: int = 100
    threads: int = 0                # torch intra-op threads while training; 0: leave unchanged
    device: str = "cpu"
    mlp: MLPConfig = field(default_factory=MLPConfig)
    body: BodyConfig = field(default_factory=BodyConfig)
    data: DataConfig = field(default_factory=DataConfig)

    def __post_init__(self):
        """Every key's range and the device, checked once before the body model is loaded."""
        r = require_range
        r("steps", self.steps, 1, integer=True)
        r("batch_size", self.batch_size, 1, 1 << 20, integer=True)
        r("lr", self.lr, 0, lo_open=True)
        for key in ("weight_decay", "w_rot", "w_joints", "w_betas"):
            r(key, getattr(self, key), 0)
        r("log_every", self.log_every, 1, integer=True)
        r("threads", self.threads, 0, integer=True)
        r("seed", self.seed, 0, integer=True)
        r("body.num_betas", self.body.num_betas, 0, 300, integer=True)
        r("data.num_sequences", self.data.num_sequences, 1, 1 << 20, integer=True)
        r("data.seq_frames", self.data.seq_frames, 3, 1 << 20, integer=True)
        require_fps("data.fps", self.data.fps)
        r("data.edge_prob", self.data.edge_prob, 0, 1)
        check_device(self.device)


def check_device(name: str) -> torch.device:
    """`device` as a torch device that this machine has: cpu, cuda, cuda:N or mps."""
    try:
        dev = torch.device(name)
    except (RuntimeError, TypeError):
        dev = None
    if dev is None or dev.type not in ("cpu", "cuda", "mps"):
        raise ConfigError(f"device: expected cpu, cuda, cuda:N or mps, got {name!r}")
    if dev.type == "cuda" and not (torch.cuda.is_available() and (dev.index or 0) < torch.cuda.device_count()):
        raise ConfigError(f"device={name}: no such CUDA device on this machine (use device=cpu)")
    if dev.type == "mps" and not torch.backends.mps.is_available():
        raise ConfigError("device=mps: MPS is not available on this machine (use device=cpu)")
    return dev


def _pool_from_dataset(cfg: DataConfig, num_betas: int):
    ds = MotionDataset.open(cfg.root)
    if ds.smplx is None:
        return None
    seqs = ds.split_sequences(cfg.split)
    if not seqs:
        raise DataError(cfg.root, "split", f"no sequences in split {cfg.split!r}")
    out = []
    for s in seqs:
        sl = slice(s.start, s.end)
        b = np.asarray(ds.smplx["betas"][sl], np.float32)[:, :num_betas]
        out.append({"global_orient": np.asarray(ds.smplx["global_orient"][sl], np.float32),
                    "body_pose": np.asarray(ds.smplx["body_pose"][sl], np.float32),
                    "transl": np.asarray(ds.smplx["transl"][sl], np.float32),
                    "betas": np.pad(b.mean(0), (0, num_betas - b.shape[1]))})
    return out


def build_pool(cfg: DataConfig, bm: BodyModel, rng: np.random.Generator) -> dict[str, torch.Tensor]:
    """Frames of all sequences, concatenated: rotmats (N, 22, 3, 3), betas (N, nβ), joints
    (N, 22, 3), and prev/next indices (N,) of each frame's neighbours (itself at edges)."""
    seqs = _pool_from_dataset(cfg, bm.num_betas) if cfg.root else None
    if seqs is None:
        seqs = [sample_motion(cfg.seq_frames, cfg.fps, rng, num_betas=bm.num_betas) for _ in range(cfg.num_sequences)]
    R, B, J, prev, nxt = [], [], [], [], []
    n = 0
    with torch.no_grad():
        for s in seqs:
            T = len(s["global_orient"])
            go, bp = torch.as_tensor(s["global_orient"]), torch.as_tensor(s["body_pose"]).reshape(T, 21, 3)
            rot = axis_angle_to_matrix(torch.cat([go[:, None], bp], 1))           # (T, 22, 3, 3)
            betas = torch.as_tensor(s["betas"]).expand(T, -1)
            J.append(bm.joints_from_rotmats(rot, torch.as_tensor(s["transl"]), betas))
            R.append(rot)
            B.append(betas)
            idx = torch.arange(n, n + T)
            prev.append(torch.cat([idx[:1], idx[:-1]]))
            nxt.append(torch.cat([idx[1:], idx[-1:]]))
            n += T
    return {"rotmats": torch.cat(R), "betas": torch.cat(B), "joints": torch.cat(J),
            "prev": torch.cat(prev), "next": torch.cat(nxt)}


def train(cfg: TrainMLPConfig, bm: BodyModel | None = None, log_dir: str | None = None,
          verbose: bool = True) -> JointsToBodyMLP:
    """Train and return the MLP (the caller saves it; `main` does)."""
    if cfg.steps < 1 or cfg.batch_size < 1:
        raise ConfigError("steps and batch_size must be positive")
    with torch_threads(cfg.threads):
        return _train(cfg, bm, log_dir, verbose)


def _train(cfg: TrainMLPConfig, bm: BodyModel | None, log_dir: str | None, verbose: bool) -> JointsToBodyMLP:
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    dev = torch.device(cfg.device)
    bm = bm if bm is not None else load_body_model(cfg.body.model_path, cfg.body.num_betas)
    bm = bm.to(dev)
    mlp_cfg = MLPConfig(**{**asdict(cfg.mlp), "num_betas": min(cfg.mlp.num_betas, bm.num_betas)})
    model = JointsToBodyMLP(mlp_cfg).to(dev)
    pool = {k: v.to(dev) for k, v in build_pool(cfg.data, bm, rng).items()}
    N = pool["joints"].shape[0]
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 0.5 * (1 + math.cos(math.pi * min(s / cfg.steps, 1.0))))
    writer = None
    if log_dir:
        from torch.utils.tensorboard import SummaryWriter  # TensorBoard pulls in its own stack: only when logging

        writer = SummaryWriter(log_dir)
    t0 = time.time()
    nb = mlp_cfg.num_betas
    for step in range(1, cfg.steps + 1):
        i = torch.randint(0, N, (cfg.batch_size,), device=dev)
        ip, inx = pool["prev"][i], pool["next"][i]
        # Random edge padding, so first/last frames (neighbour = middle) are in distribution.
        ip = torch.where(torch.rand(i.shape, device=dev) < cfg.data.edge_prob, i, ip)
        inx = torch.where(torch.rand(i.shape, device=dev) < cfg.data.edge_prob, i, inx)
        trip = torch.stack([pool["joints"][ip], pool["joints"][i], pool["joints"][inx]], 1)   # (B, 3, 22, 3)
        feats, yaw = canonicalise(trip)
        R_gt = pool["rotmats"][i].clone()                                                    # (B, 22, 3, 3)
        R_gt[:, 0] = yaw_matrix(-yaw) @ R_gt[:, 0]                                            # canonical root
        rot6d, betas = model(feats)
        R = rot6d_to_matrix(rot6d)
        b_gt = pool["betas"][i]
        b_pred = torch.cat([betas, b_gt[:, nb:]], -1) if betas is not None else b_gt
        J = bm.joints_from_rotmats(R, None, b_pred)
        J_gt = bm.joints_from_rotmats(R_gt, None, b_gt)
        l_rot = (R - R_gt).square().sum((-1, -2)).mean()
        l_j = (J - J[:, :1] - (J_gt - J_gt[:, :1])).square().sum(-1).mean()
        l_b = (betas - b_gt[:, :nb]).square().mean() if betas is not None else torch.zeros((), device=dev)
        loss = cfg.w_rot * l_rot + cfg.w_joints * l_j + cfg.w_betas * l_b
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        if step % cfg.log_every == 0 or step == cfg.steps:
            mpjpe = (J - J[:, :1] - (J_gt - J_gt[:, :1])).norm(dim=-1).mean().item()
            if writer:
                writer.add_scalar("loss/total", loss.item(), step)
                writer.add_scalar("loss/rot", l_rot.item(), step)
                writer.add_scalar("loss/joints", l_j.item(), step)
                writer.add_scalar("loss/betas", l_b.item(), step)
                writer.add_scalar("mpjpe_m", mpjpe, step)
            if verbose:
                print(f"step {step}/{cfg.steps} loss {loss.item():.4f} mpjpe {mpjpe * 100:.2f} cm "
                      f"({time.time() - t0:.0f} s)", flush=True)
    if writer:
        writer.close()
    model.eval()
    return model


def save_checkpoint(model: JointsToBodyMLP, cfg: TrainMLPConfig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    torch.save(model.checkpoint({"train_config": _plain(asdict(cfg))}), tmp)
    os.replace(tmp, path)
    return path


def load_mlp(path: str | Path, device: str | torch.device = "cpu") -> JointsToBodyMLP:
    path = Path(path)
    if not path.is_file():
        raise DataError(path, None, "MLP checkpoint not found")
    try:
        ckpt = torch.load(path, map_location=device, weights_only=True)
        if ckpt.get("kind") != "joints_to_body_mlp":
            raise KeyError("kind")
        return JointsToBodyMLP.from_checkpoint(ckpt).to(device)
    except pickle.UnpicklingError:
        # An MLP checkpoint holds tensors only; torch's advice on loading other objects is no help here.
        raise DataError(path, None, "not a joints-to-body MLP checkpoint (it holds Python objects, like a motion "
                                    "model from `motiongen train`); give the mlp.pt of `motiongen train-body-mlp`, "
                                    "mlp=auto or mlp=none") from None
    except Exception as e:
        raise DataError(path, None, f"not a joints-to-body MLP checkpoint ({type(e).__name__}: "
                                    f"{str(e).splitlines()[0] if str(e) else ''})") from None


def _plain(d):
    return {k: _plain(v) if isinstance(v, dict) else v for k, v in d.items()}


def train_and_save(cfg: TrainMLPConfig) -> Path:
    """Train with TensorBoard logs in `cfg.out/tb`, save `cfg.out/mlp.pt` and say where."""
    out = Path(cfg.out)
    model = train(cfg, log_dir=str(out / "tb"))
    path = save_checkpoint(model, cfg, out / "mlp.pt")
    print(f"saved {path}")
    return path
