"""Does the network glide because it continues its own frames? (not a timed test)

On the data's `split` sequences, the network samples `windows` windows one after another along
each sequence, as the sampler's loop does (each starts L - 2 frames after the one before), the
data's pelvis x, z at each window's last frame as its goal and the data's action labels, two
ways: given the data's first 2 frames every time, and chained, given its own last 2 frames of
the window before (canonicalised at the first, the goal and the scene grid in that frame, as
the loop does). Printed at the model's rate for the free frames of every window but the first:
the skating figure and the toes' height when they move (`toe_clearance.row`), and how far the
pelvis and the toes go (`toe_clearance.travel`) on the windows whose data pelvis goes over
1.2 m. A network that glides only in the loop, not here, glides for another reason than its
own frames (the loop's goals, labels or scenes).

    python benchmarks/chained_windows.py ckpt=PATH [split=val] [windows=6] [chains=120] [steps=10]
"""

from __future__ import annotations

import numpy as np
import torch

from network_facing import model_and_data
from toe_clearance import row, travel

from motiongen.cli import parse_key_values, tool_main
from motiongen.data.windows import WindowDataset, canonicalize
from motiongen.geometry import invert_rigid, transform_points
from motiongen.loading.build import sample_windows
from motiongen.skeleton import PELVIS

SPEC = {"ckpt": (str, None), "split": (str, "val"), "windows": (int, 6), "chains": (int, 120), "steps": (int, 10)}
K = 2                     # frames handed on, as the sampler's loop does


def chain_starts(ds, wd: WindowDataset, split: str, windows: int, chains: int) -> np.ndarray:
    """(N,) first source frames of up to `chains` runs of `windows` windows, each inside one
    sequence of `split`, apart."""
    L, st = wd.cfg.length, wd.cfg.stride
    hop, span = (L - K) * st, (L - 1) * st + 1
    need = span + (windows - 1) * hop
    starts = [a for s in ds.split_sequences(split) for a in range(s.start, s.end - need + 1, need)]
    return np.array(starts[:chains], np.int64)


def run_chains(loaded, wd: WindowDataset, starts: np.ndarray, windows: int, steps: int, own: bool) -> tuple:
    """(data, network): world joints (N, windows, L, J, 3) of the data's windows and the
    network's along the chains at `starts`, given the data's first K frames each window or
    (own) its own last K frames of the window before."""
    L, st, layout, stats = wd.cfg.length, wd.cfg.stride, loaded.layout, loaded.stats
    gen = torch.Generator().manual_seed(0)
    data, net, prev, prev_stance = [], [], None, None
    for i in range(windows):
        frames = starts[:, None] + i * (L - K) * st + st * np.arange(L)[None]                # (N, L)
        items = [wd.item_at(f) for f in frames]
        batch = {key: torch.stack([it[key] for it in items]) for key in items[0]}
        T = batch["to_world"].double()                                                       # (N, 4, 4)
        local = layout.decode(stats.denormalize(batch["motion"].double()))[0]                # (N, L, J, 3)
        data.append(transform_points(T[:, None], local))
        x0 = batch["motion"]
        if own and prev is not None:
            local = local.clone()
            local[:, :K], T = canonicalize(prev[:, L - K:])                                  # the loop's frame
            local[:, -1, PELVIS] = transform_points(invert_rigid(T), data[-1][:, -1, PELVIS][:, None])[:, 0]
            stance = torch.zeros(local.shape[0], L, layout.num_contacts, dtype=torch.bool)
            stance[:, :K] = prev_stance[:, L - K:]
            x0 = stats.normalize(layout.encode(local, stance)).float()
            if "scene" in batch:
                batch["scene"] = torch.stack([torch.from_numpy(wd.local_scene(f, g.numpy(), t.numpy()))
                                              for f, g, t in zip(frames, local[:, -1, PELVIS], T)])
        x = sample_windows(loaded.model, loaded.diffusion, dict(batch, motion=x0), loaded.config, loaded.device,
                           gen, steps)
        joints, prev_stance = layout.decode(stats.denormalize(x.double()))
        prev = transform_points(T[:, None], joints)
        net.append(prev)
    return torch.stack(data, 1).numpy(), torch.stack(net, 1).numpy()


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, required=("ckpt",), usage=__doc__.splitlines()[-2].strip())
    loaded, ds = model_and_data(opts["ckpt"])
    wd = WindowDataset(ds, opts["split"], loaded.window, loaded.stats)
    starts = chain_starts(ds, wd, opts["split"], opts["windows"], opts["chains"])
    fps = loaded.model_fps
    print(f"{opts['ckpt']}: {len(starts)} chains of {opts['windows']} windows along the {opts['split']} sequences "
          f"({fps:g} fps, DDIM-{opts['steps']}; windows 2.. measured, their free frames)")
    for own in (False, True):
        data, net = run_chains(loaded, wd, starts, opts["windows"], opts["steps"], own)
        if not own:
            print(row("the data", list(later(data, K)), fps))
        print(row("network, its own frames" if own else "network, data's frames", list(later(net, K)), fps))
        (dp, dt), (np_, nt) = travel(later(data, K - 1)), travel(later(net, K - 1))
        w = dp > 1.2
        print(f"    windows whose data pelvis goes over 1.2 m ({w.sum()}): the data's pelvis {dp[w].mean():.2f} m, "
              f"toes {dt[w].mean():.2f}; the network's pelvis {np_[w].mean():.2f}, toes {nt[w].mean():.2f}")


def later(chains: np.ndarray, first: int) -> np.ndarray:
    """(N, C, L, J, 3) -> (N * (C - 1), L - first, J, 3): every window but each chain's first,
    from frame `first` on."""
    N, C, L, J, _ = chains.shape
    return chains[:, 1:, first:].reshape(N * (C - 1), L - first, J, 3)

if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
