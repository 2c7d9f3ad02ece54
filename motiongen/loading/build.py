"""Build the model, diffusion, conditions and masks from a resolved config or a checkpoint."""

from __future__ import annotations

from dataclasses import fields, replace

import torch
from omegaconf import DictConfig, OmegaConf, open_dict

from motiongen.data.representation import Layout
from motiongen.data.swing_rise import SwingRise
from motiongen.data.windows import NormStats, WindowConfig
from motiongen.diffusion import DiffusionConfig, GaussianDiffusion, sample
from motiongen.diffusion.masks import MaskConfig, predicts_goal, replace_mask, sample_known_mask
from motiongen.errors import ConfigError, DataError, MotiongenError
from motiongen.geometry import facing_yaw
from motiongen.importers.sources import DataConfig
from motiongen.loading.checkpoint import load_checkpoint
from motiongen.models import Condition, ModelConfig, build_model
from motiongen.models.condition import drop_conditions
from motiongen.models.denoiser import INT8_AVAILABLE
from motiongen.rates import DATA_FPS, DEFAULT_STEPS
from motiongen.skeleton import JointSet, joint_set_for


def _dataclass_from(cls, node):
    d = OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node)
    known = {f.name for f in fields(cls)}
    unknown = set(d) - known
    if unknown:
        raise ConfigError(f"unknown {cls.__name__} key(s): {sorted(unknown)}")
    return cls(**d)


def data_config(cfg) -> DataConfig:
    return _dataclass_from(DataConfig, cfg.data)


def window_config(cfg) -> WindowConfig:
    return _dataclass_from(WindowConfig, cfg.window)


def mask_config(cfg) -> MaskConfig:
    return _dataclass_from(MaskConfig, cfg.mask)


def build_from_config(cfg, joint_set: JointSet, action_names: list[str]):
    """(model, diffusion, checkpoint metadata) for a run config."""
    mcfg = _dataclass_from(ModelConfig, cfg.model)
    dcfg = _dataclass_from(DiffusionConfig, cfg.diffusion)
    w = window_config(cfg)
    if not w.scene and mcfg.use_scene:
        # Windows without a scene grid: a scene encoder would never see an input (and under
        # DDP its parameters would never get a gradient).
        mcfg = replace(mcfg, use_scene=False)
    if not 0 <= mcfg.temporal_basis <= w.length:
        raise ConfigError(f"model.temporal_basis={mcfg.temporal_basis}: expected 0 (off) .. window.length={w.length}")
    if mcfg.temporal_basis and dcfg.prediction != "x0":
        raise ConfigError(f"model.temporal_basis={mcfg.temporal_basis} confines the output to smooth windows, "
                          f"which only an x0 prediction is; diffusion.prediction={dcfg.prediction}")
    if mcfg.skip_sigma_data and dcfg.prediction != "x0":
        raise ConfigError(f"model.skip_sigma_data={mcfg.skip_sigma_data} makes the output an x0 estimate through a "
                          f"skip; diffusion.prediction={dcfg.prediction}")
    layout = Layout.for_window(w, joint_set)
    diffusion = GaussianDiffusion(dcfg)
    p_facing = mask_config(cfg).p_facing
    if not 0 <= p_facing <= 1:
        raise ConfigError(f"mask.p_facing: expected a probability in 0..1, got {p_facing}")
    model = build_model(mcfg, num_joints=joint_set.num_joints, num_actions=len(action_names), window=w.length,
                        scene_res=(w.grid_res[1], w.grid_res[0], w.grid_res[2]), channels=layout.channels,
                        alphas_cumprod=diffusion.alphas_cumprod, facing_goal=p_facing > 0)
    meta = {"joint_names": list(joint_set.names), "action_names": list(action_names),
            "model_config": OmegaConf.to_container(OmegaConf.structured(mcfg)),
            "diffusion_config": OmegaConf.to_container(OmegaConf.structured(dcfg))}
    return model, diffusion, meta


def batch_condition(batch: dict, device, tc, generator, train: bool) -> Condition:
    cond = Condition(scene=batch["scene"].to(device, non_blocking=True) if "scene" in batch else None,
                     actions=batch["actions"].to(device, non_blocking=True))
    if train and (tc.cond_drop_scene > 0 or tc.cond_drop_actions > 0):
        cond = drop_conditions(cond, tc.cond_drop_scene, tc.cond_drop_actions, generator)
    return cond


def known_mask_for_batch(cfg, shape, num_joints: int, device, generator, action_hand=None) -> torch.Tensor:
    """action_hand: `acting_hands(...)` of the batch, for `mask.p_hand_action`."""
    B, L, D = shape
    return sample_known_mask(B, L, num_joints, mask_config(cfg), generator, channels=D,
                             action_hand=action_hand).to(device)


def acting_hands(m: MaskConfig, batch: dict, layout, stats, action_names) -> tuple[torch.Tensor, torch.Tensor] | None:
    """(acting (B,) bool, wrist (B,) long) for `mask.p_hand_action` of the mask config m: the
    windows whose last frame carries a `mask.hand_actions` label, and of the wrists a hand goal
    may go to (`MaskConfig.goal_hands`) the one that moved most relative to the pelvis over the
    window. None when the config gives no such goals."""
    idx = [list(action_names).index(a) for a in m.hand_actions if a in action_names]
    if m.p_hand_action <= 0 or not idx:
        return None
    acting = batch["actions"][:, -1, idx].amax(-1) > 0                                        # (B,)
    joints, _ = layout.decode(stats.denormalize(batch["motion"]))                            # (B, L, J, 3)
    hands = torch.as_tensor(m.goal_hands)                                                     # (H,)
    rel = joints[:, :, hands] - joints[:, :, :1]                                              # (B, L, H, 3) from the pelvis
    moved = (rel[:, -1] - rel[:, 0]).norm(dim=-1)                                             # (B, H)
    return acting, hands[moved.argmax(-1)]


def facing_goals(m: MaskConfig, batch: dict, layout, stats, generator) -> tuple[torch.Tensor, torch.Tensor] | None:
    """(facing (B, 2) (sin, cos) of the last frame's yaw in the window frame, given (B,) bool
    drawn with probability `mask.p_facing`) for `Condition.facing`; None when the config gives
    no facing goal (and then nothing is drawn from the generator: other recipes keep their
    random sequence)."""
    if m.p_facing <= 0:
        return None
    facing = last_facing(batch["motion"], layout, stats)                                     # (B, 2)
    gen_device = generator.device if generator is not None else "cpu"
    given = torch.rand(facing.shape[0], generator=generator, device=gen_device) < m.p_facing  # (B,)
    return facing, given


def last_facing(motion: torch.Tensor, layout, stats) -> torch.Tensor:
    """(B, 2) float32 (sin, cos) of the last frame's yaw (from the hips) of normalised windows
    motion (B, L, D), in their window frame: the facing goal they carry (`Condition.facing`)."""
    joints, _ = layout.decode(stats.denormalize(motion))                                     # (B, L, J, 3)
    yaw = facing_yaw(joints[:, -1])                                                          # (B,)
    return torch.stack([torch.sin(yaw), torch.cos(yaw)], -1).float()


def goal_predicted(cfg) -> bool:
    """Whether the model of this config predicts its goal entries (`mask.predict_goal` and x0
    prediction): then the loss covers them and samplers keep the prediction there."""
    return predicts_goal(mask_config(cfg), str(cfg.diffusion.prediction))


def fixed_known_mask(shape, transition: int, goal: bool, device) -> torch.Tensor:
    """The sampling-time mask: the first `transition` frames and the last-frame pelvis x, z."""
    m = torch.zeros(shape, dtype=torch.bool, device=device)
    m[:, :transition] = True
    if goal:
        m[:, -1, [0, 2]] = True
    return m


@torch.no_grad()
def sample_windows(model, diffusion, batch: dict, cfg, device, generator, steps: int = DEFAULT_STEPS,
                   facing: torch.Tensor | None = None) -> torch.Tensor:
    """Sample windows for a batch, pinning its first 2 frames and its goal (as sampling does);
    `facing` (B, 2): a facing goal for a model built with one (`Condition.facing`)."""
    x0 = batch["motion"].to(device)
    cond = Condition(scene=batch["scene"].to(device) if "scene" in batch else None, actions=batch["actions"].to(device),
                     facing=None if facing is None else facing.to(device))
    mask = fixed_known_mask(x0.shape, 2, True, device)
    model.eval()
    replace = replace_mask(mask, goal_predicted(cfg))
    return sample(diffusion, model, x0.shape, cond, known=x0, known_mask=mask, sampler="ddim",
                            steps=min(steps, diffusion.num_timesteps), generator=generator, replace_mask=replace)


def _with_legacy_defaults(cfg):
    """Checkpoints from before the representation key and goal prediction hold absolute joints
    without stance channels and pinned goals: missing keys mean the old behaviour, not today's
    defaults."""
    with open_dict(cfg):
        if "representation" not in cfg.window:
            cfg.window.representation = "absolute"
            cfg.window.contact_joints = []
        if "predict_goal" not in cfg.mask:
            cfg.mask.predict_goal = False
    return cfg


class LoadedModel:
    """Everything a tool needs from a checkpoint alone: the EMA denoiser (eval mode), the
    diffusion, normalisation statistics, joint set, action vocabulary and window config, and
    the rates: `fps` of the training data and `model_fps` of the model's windows."""

    precision = "fp32"                              # of the transformer layers (load_model)

    def __init__(self, state: dict, device, use_ema: bool = True, path=None):
        cfg = _with_legacy_defaults(OmegaConf.create(state["config"]))
        self.config = cfg
        self.step = int(state["step"])
        self.joint_set = joint_set_for(state["joint_names"])
        self.action_names = list(state["action_names"])
        self.stats = NormStats.from_state_dict(state["stats"])
        self.window = window_config(cfg)
        self.mask = mask_config(cfg)
        self.layout = Layout.for_window(self.window, self.joint_set)
        self.predict_goal = goal_predicted(cfg)
        self.fps = float(state.get("fps") or DATA_FPS)      # the training data's frame rate
        # A distilled student's `distill` entry (method, steps, teacher...; motiongen.training.distill),
        # None for a model trained by `motiongen train`: samplers take their defaults from it.
        self.distill = state.get("distill")
        # The training data's swing heights for the sampler's swing lift; None (a checkpoint from
        # before 2026-11-27): the embedded dataset's (`data/swing_rise.py`).
        self.swing_rise = SwingRise.from_state_dict(state["swing_rise"]) if state.get("swing_rise") else None
        model, self.diffusion, _ = build_from_config(cfg, self.joint_set, self.action_names)
        part = "ema" if use_ema else "model"
        load_weights(model, state[part], path or "checkpoint", part, "its own config")
        self.model = model.to(device).eval().requires_grad_(False)
        self.device = torch.device(device)

    @property
    def model_fps(self) -> float:
        """The data rate the model was trained at: frames per second of its windows, the
        training data's rate over the window stride."""
        return self.fps / self.window.stride


def load_weights(module: torch.nn.Module, weights: dict, path, part: str, model_from: str) -> None:
    """`weights` (a state dict, the checkpoint's `part`) into `module`, refused in one line naming
    the file when a tensor is not finite (a diverged run) or the weights belong to another
    architecture than `model_from` builds (a width, layer count or joint set changed)."""
    bad = [k for k, v in weights.items() if torch.is_tensor(v) and v.is_floating_point() and not torch.isfinite(v).all()]
    if bad:
        more = f" and {len(bad) - 1} more tensors" if len(bad) > 1 else ""
        raise DataError(path, part, f"non-finite weights (NaN or inf) in {bad[0]}{more}: the run that wrote it diverged")
    own = module.state_dict()
    missing, extra = sorted(set(own) - set(weights)), sorted(set(weights) - set(own))
    shapes = [k for k in own if k in weights and tuple(own[k].shape) != tuple(weights[k].shape)]
    if missing or extra or shapes:
        what = (f"{shapes[0]} is {tuple(weights[shapes[0]].shape)} there, {tuple(own[shapes[0]].shape)} here"
                if shapes else f"{len(missing)} tensors missing, {len(extra)} unexpected (e.g. {(missing or extra)[0]})")
        raise DataError(path, part, f"weights of another architecture than {model_from} builds ({what})")
    module.load_state_dict(weights)


PRECISIONS = ("fp32", "bf16", "int8", "int8-encoders")
# precision=auto: bf16 from this many parameters in the denoiser's transformer layers, where
# the device multiplies bfloat16 natively. On such a CPU the paper-size layers (12.6 M) run
# their steps faster in bf16, the quality recipe's (1.2 M) do not; on a CPU without (AVX2 only)
# bf16 is emulated and the paper-size steps are slower than fp32 (benchmarks/sample.py
# measures both). auto never chooses int8: no paper-size checkpoint has been measured with it
# (docs/sampling.md).
AUTO_BF16_PARAMS = 4_000_000


def check_precision(precision: str) -> str:
    if precision not in (*PRECISIONS, "auto"):
        raise ConfigError(f"precision: expected one of {', '.join(PRECISIONS)}, auto, got {precision!r}")
    return precision


def resolve_precision(model, precision: str) -> str:
    """One of PRECISIONS for a model and a `precision` key (one of them or auto)."""
    if check_precision(precision) != "auto":
        return precision
    big = sum(p.numel() for p in model.blocks.parameters()) >= AUTO_BF16_PARAMS
    return "bf16" if big and native_bf16(next(model.parameters()).device) else "fp32"


def set_precision(model, precision: str):
    """Put an eval-mode denoiser's transformer layers at `precision` (one of PRECISIONS) for
    sampling: bf16 weights (Denoiser.blocks_to), or int8 ones on the CPU for every transformer
    layer or the encoders' only (quantize_layers)."""
    if precision.startswith("int8"):
        return model.quantize_layers(denoiser=precision == "int8")
    if precision == "bf16":
        return model.blocks_to(torch.bfloat16)
    return model


def native_bf16(device: torch.device) -> bool:
    """Whether `device` multiplies bfloat16 matrices in hardware: a CUDA device that supports
    it, or a CPU whose oneDNN has bf16 kernels (AVX-512 or AMX; not an AVX2-only CPU)."""
    if device.type == "cuda":
        return torch.cuda.is_bf16_supported()
    return device.type == "cpu" and bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


def load_model(path, device="cpu", use_ema: bool = True, precision: str = "fp32") -> LoadedModel:
    """Rebuild a trained model from a checkpoint file (config and statistics inside it).
    `precision`: the transformer layers for sampling, one of PRECISIONS (set_precision)
    or auto (resolve_precision); `loaded.precision` says which.
    Anything wrong with the file or the device is a user error (MotiongenError)."""
    check_precision(precision)                      # a bad key fails before the file is read
    device = str(device)
    if precision.startswith("int8"):
        if device != "cpu":
            raise ConfigError(f"precision={precision}: int8 layers run on the CPU only, not device={device} (use fp32 or bf16)")
        if not INT8_AVAILABLE:
            raise ConfigError(f"precision={precision}: torch {torch.__version__} has no dynamic quantization (use fp32 or bf16)")
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(f"device={device}: CUDA is not available")
    state = load_checkpoint(path, map_location="cpu")
    missing = [k for k in ("config", "stats", "joint_names", "action_names", "ema", "model") if k not in state]
    if missing:
        raise MotiongenError(f"{path}: incompatible checkpoint, missing {missing}")
    try:
        loaded = LoadedModel(state, device, use_ema, path)
    except MotiongenError:
        raise
    except Exception as e:  # a config or tensors this version cannot rebuild: the user's file
        first = str(e).splitlines()[0] if str(e) else ""
        raise DataError(path, None, f"unreadable or incompatible checkpoint ({type(e).__name__}: {first})") from None
    loaded.precision = resolve_precision(loaded.model, precision)
    set_precision(loaded.model, loaded.precision)
    return loaded


def loss_channel_weights(tc, channels: int, device) -> torch.Tensor | None:
    """(D,) per-channel loss weights: the pelvis (joint 0) channels get train.pelvis_loss_weight."""
    if tc.pelvis_loss_weight == 1.0:
        return None
    w = torch.ones(channels, device=device)
    w[:3] = tc.pelvis_loss_weight
    return w


def hand_goal_weights(known_mask: torch.Tensor, hands, weight: float) -> torch.Tensor | None:
    """(B, L, D) loss weights: `weight` on the x, y, z of the wrist whose last-frame entries
    known_mask (B, L, D) gives (a hand goal on one of the joints `hands`) over the window's last
    quarter, 1 elsewhere; None when weight is 1 (the plain mean)."""
    if weight == 1.0:
        return None
    B, L, D = known_mask.shape
    tail = max(1, L // 4)
    w = torch.ones(B, L, D, device=known_mask.device)
    for j in hands:
        given = known_mask[:, -1, 3 * j]                                                          # (B,) bool
        w[:, L - tail:, 3 * j:3 * j + 3] = torch.where(given, weight, 1.0)[:, None, None]
    return w
