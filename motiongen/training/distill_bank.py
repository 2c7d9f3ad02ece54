"""The bank of teacher runs a distilled student learns from, made once and cached in the run
directory (`bank.pt`, written atomically) so a resumed run reads it instead of making it again.

Each entry is one training window with its conditions, masks and known entries exactly as
training builds them (`batch_condition`, `known_mask_for_batch`, `acting_hands`; no condition
dropped), the teacher's guided DDIM run from x_T on it recorded at the student's timesteps
(`diffusion.trajectory.teacher_trajectory`) and the teacher's output.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from motiongen.data.windows import WindowDataset
from motiongen.diffusion.masks import replace_mask
from motiongen.diffusion.trajectory import teacher_trajectory
from motiongen.errors import ConfigError
from motiongen.importers.sources import open_dataset
from motiongen.loading.build import LoadedModel, acting_hands, batch_condition, data_config, known_mask_for_batch
from motiongen.loading.checkpoint import save_atomic
from motiongen.models import Condition
from motiongen.training.distill_config import DistillConfig

BANK_NAME = "bank.pt"
BANK_FORMAT = "motiongen-distill-bank"


@dataclass
class Bank:
    """N teacher runs of a student with n steps (tensors on the CPU)."""

    states: Tensor                 # (N, n, L, D) float: the teacher's state at each student timestep
    target: Tensor                 # (N, L, D) float: the teacher's output x0*
    known: Tensor                  # (N, L, D) float: the clean window (its values at known entries)
    known_mask: Tensor             # (N, L, D) bool
    actions: Tensor                # (N, L, A) float
    scene: Tensor | None           # (N, ceil(V / 8)) uint8: the local occupancy, V bits packed; None: no scene
    scene_shape: tuple | None      # (Hy, Hx, Hz) of one window's occupancy
    index: Tensor                  # (N,) long: the training window of each entry
    key: dict                      # what the bank was made from (DistillConfig.bank_key + teacher)

    def __len__(self) -> int:
        return int(self.states.shape[0])

    def batch(self, idx, device) -> dict:
        """Entries `idx` on `device`: states, target, known, known_mask and their Condition."""
        idx = torch.as_tensor(idx, dtype=torch.long)
        scene = None
        if self.scene is not None:
            bits = np.unpackbits(self.scene[idx].numpy(), axis=1)[:, :int(np.prod(self.scene_shape))]
            scene = torch.from_numpy(bits.reshape(len(idx), *self.scene_shape).astype(np.float32)).to(device)
        cond = Condition(scene=scene, actions=self.actions[idx].to(device))
        return {"states": self.states[idx].to(device), "target": self.target[idx].to(device),
                "known": self.known[idx].to(device), "known_mask": self.known_mask[idx].to(device), "cond": cond}

    def state_dict(self) -> dict:
        return {"format": BANK_FORMAT, **{k: getattr(self, k) for k in self.__dataclass_fields__}}


def teacher_key(dc: DistillConfig, teacher_path: Path, teacher: LoadedModel) -> dict:
    """The key a cached bank must carry to be reused: the config's and the teacher's identity."""
    return {**dc.bank_key(), "teacher": str(Path(teacher_path).resolve()), "teacher_step": teacher.step}


def load_or_make_bank(run_dir: Path, dc: DistillConfig, teacher_path: Path, teacher: LoadedModel, device,
                      log=print) -> Bank:
    """The run's bank: read from `run_dir/bank.pt` when it was made for this config and teacher,
    else made (and written there). A resumed run whose bank belongs to another config is refused:
    its student learnt from that bank."""
    path, key = Path(run_dir) / BANK_NAME, teacher_key(dc, teacher_path, teacher)
    if path.is_file():
        state = torch.load(path, map_location="cpu", weights_only=False)
        if isinstance(state, dict) and state.get("format") == BANK_FORMAT and state.get("key") == key:
            log(f"bank: {len(state['index'])} teacher runs read from {path}")
            return Bank(**{k: state[k] for k in Bank.__dataclass_fields__})
        log(f"bank: {path} was made for another config or teacher; making it again")
    bank = make_bank(dc, teacher, key, device, log)
    save_atomic(bank.state_dict(), path)
    return bank


def make_bank(dc: DistillConfig, teacher: LoadedModel, key: dict, device, log=print) -> Bank:
    """`dc.bank_size` teacher runs on training windows drawn without replacement (seeded)."""
    ds = open_dataset(data_config(teacher.config), verbose=False)
    windows = WindowDataset(ds, "train", teacher.window, teacher.stats)
    if len(windows) < dc.bank_size:
        raise ConfigError(f"bank_size={dc.bank_size}: the teacher's train split has only {len(windows)} windows")
    gen = torch.Generator().manual_seed(dc.seed)
    order = torch.randperm(len(windows), generator=gen)[:dc.bank_size]
    parts = []
    for b0 in range(0, dc.bank_size, dc.bank_batch):
        idx = order[b0:b0 + dc.bank_batch]
        parts.append(_teacher_runs(dc, teacher, windows, idx, gen, device))
        log(f"bank: {min(b0 + dc.bank_batch, dc.bank_size)}/{dc.bank_size} teacher runs "
            f"(DDIM-{dc.teacher_steps}, guidance {dc.guidance_scale:g})")
    cat = {k: torch.cat([p[k] for p in parts]) if parts[0][k] is not None else None for k in parts[0]}
    scene_shape = tuple(windows[0]["scene"].shape) if windows.cfg.scene else None
    return Bank(cat["states"], cat["target"], cat["known"], cat["known_mask"], cat["actions"], cat["scene"],
                scene_shape, order.clone(), key)


def _teacher_runs(dc: DistillConfig, teacher: LoadedModel, windows: WindowDataset, idx: Tensor,
                  gen: torch.Generator, device) -> dict:
    """One batch of teacher runs on windows `idx` (b,): the Bank's fields for them, on the CPU.
    Masks and noise come from the CPU generator `gen`, so the bank is the same on every device."""
    items = [windows[int(i)] for i in idx]
    batch = {k: torch.stack([it[k] for it in items]) for k in items[0]}
    x0 = batch["motion"]                                                             # (b, L, D)
    mask = known_mask_for_batch(teacher.config, x0.shape, teacher.joint_set.num_joints, "cpu", gen,
                                acting_hands(teacher.mask, batch, windows.layout, windows.stats, teacher.action_names))
    cond = batch_condition(batch, device, None, None, train=False)
    states, target = teacher_trajectory(teacher.diffusion, teacher.model, tuple(x0.shape), cond, dc.steps,
                                        known=x0.to(device), known_mask=mask.to(device),
                                        replace_mask=replace_mask(mask, teacher.predict_goal).to(device),
                                        teacher_steps=dc.teacher_steps, guidance_scale=dc.guidance_scale,
                                        generator=gen, device=device)
    scene = None
    if "scene" in batch:
        scene = torch.from_numpy(np.packbits(batch["scene"].numpy().reshape(len(idx), -1) > 0.5, axis=1))
    return {"states": states.cpu(), "target": target.cpu(), "known": x0, "known_mask": mask,
            "actions": batch["actions"], "scene": scene}
