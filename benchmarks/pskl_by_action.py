"""PSKL by action, and how fast each set walks (not a timed test).

    python benchmarks/pskl_by_action.py ckpt=PATH [split=val] [settings=static,dynamic] [k=2] [pairs=1] [steps=10]

`evaluate`'s PSKL compares every 2 s chunk of the generated motion with every chunk of the
scenes' data, whatever is done in them: the data sits, lies, stands and walks, a dynamic
sample walks and picks up. A mixture of spectra can read near the data's where no action does.
This runs the `evaluate` protocol (seed 0, DDIM-`steps`) on the split's scenes and prints,
for each action, PSKL(gen, ref) / PSKL(ref, gen) between the output's chunks labelled with it
and the data's chunks with the same label, beside the data's own split-half value for that
action (a chunk has an action when at least half its frames carry the label; both sides
thinned to one size, as `evaluate` does), and `evaluate`'s own figure over every chunk. Then
the pelvis's pace over the floor in the walking chunks: its quartiles for the output and the
data.
"""

from __future__ import annotations

import warnings

import numpy as np

from motiongen.cli import parse_key_values, tool_main
from motiongen.eval.pairs import ProtocolConfig
from motiongen.eval.protocol import even_subset, evaluate, pskl_equal, reference_halves
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.loading.build import load_model
from motiongen.sampling import SamplerSettings
from motiongen.skeleton import PELVIS

SPEC = {"ckpt": (str, None), "split": (str, "val"), "settings": (list, ["static", "dynamic"]), "k": (int, 2),
        "pairs": (int, 1), "steps": (int, 10)}
FEW = 8                       # chunks: fewer on a side, and the action's figures are printed as too few


def labelled_chunks(motions, labels, n: int, action: int) -> list[np.ndarray]:
    """The n-frame chunks (as `evaluate` cuts them: non-overlapping, from each motion's start) of
    motions (T_i, J, 3) whose frames carry `action` on at least half of them; labels: per
    motion (T_i,) int action index (-1 none) or (T_i, A) bool, one column per action."""
    out = []
    for m, lab in zip(motions, labels):
        lab = np.asarray(lab)
        has = lab[:, action] if lab.ndim == 2 else lab == action                              # (T_i,)
        out += [m[i:i + n] for i in range(0, len(m) - n + 1, n) if 2 * has[i:i + n].sum() >= n]
    return out


def action_pskl(gen, gen_labels, ref, ref_labels, action: int, n: int, fps: float) -> dict:
    """One action's PSKL: the output's chunks with it against one half of the data's (every
    other sequence), the data's halves against each other, every set thinned to the smallest
    (`pskl_equal`). Returns {"gen": (gen,ref), (ref,gen)), "floor": (a,b), (b,a)), "chunks": m,
    "gen_chunks", "ref_chunks"}; the PSKL entries are None where a set has fewer than two chunks."""
    g = labelled_chunks(gen, gen_labels, n, action)
    a = labelled_chunks(ref[0::2], ref_labels[0::2], n, action)
    b = labelled_chunks(ref[1::2], ref_labels[1::2], n, action)
    m = min(len(g), len(a), len(b))
    out = {"gen_chunks": len(g), "ref_chunks": len(a) + len(b), "chunks": m, "gen": None, "floor": None}
    if m >= 2:
        a, b = even_subset(a, m), even_subset(b, m)
        out["gen"] = pskl_equal(even_subset(g, m), b, fps, n)[:2]
        out["floor"] = pskl_equal(a, b, fps, n)[:2]
    return out


def pace(chunks, fps: float) -> np.ndarray:
    """(N,) each chunk's mean pelvis speed over the floor (m/s)."""
    return np.array([np.linalg.norm(np.diff(c[:, PELVIS, [0, 2]], axis=0), axis=-1).mean() * fps for c in chunks])


def scene_data(ds, contexts) -> tuple[list, list]:
    """The evaluated scenes' own sequences, as `evaluate`'s reference takes them: joints
    (T_i, J, 3) and labels (T_i, A) bool."""
    joints, labels = [], []
    for ctx in contexts.values():
        for seq in ctx.sequences:
            joints.append(np.asarray(ds.joints[seq.start:seq.end], np.float32))    # as `evaluate` keeps them
            labels.append(np.asarray(ds.actions[seq.start:seq.end], bool))
    return joints, labels


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, required=("ckpt",), usage=__doc__.splitlines()[2].strip())
    loaded = load_model(opts["ckpt"])
    ds = open_dataset(DataConfig(), verbose=False)
    scenes = [s for s in ds.splits[opts["split"]] if s in ds.scenes]
    warnings.simplefilter("ignore")                  # a sample's episode limit: counted by evaluate, not here
    cfg = ProtocolConfig(k=opts["k"], pairs=opts["pairs"], ablation_pairs=0)
    n, names = cfg.pskl_frames, list(ds.action_names)
    print(f"{opts['ckpt']}: {opts['split']} scenes {scenes[0]}-{scenes[-1]}, k={opts['k']}, {opts['pairs']} pair(s) "
          f"per scene, DDIM-{opts['steps']}; {n}-frame chunks; PSKL(gen,ref) / PSKL(ref,gen) in nats")
    for setting in opts["settings"]:
        ev = evaluate(loaded, ds, scenes, cfg, [setting], SamplerSettings("ddim", opts["steps"]), progress=False)
        gen = [m for r in ev.results[setting] for m in r.kept]
        gen_labels = [lab for r in ev.results[setting] for lab in r.labels]
        ref, ref_labels = scene_data(ds, ev.contexts)
        print(f"\n{setting}: {'action':10s} {'output chunks':>13s} {'data chunks':>11s} {'compared':>8s} "
              f"{'output vs data':>16s} {'data vs data':>15s} {'ratio':>11s}")
        for a, name in enumerate(names):
            f = action_pskl(gen, gen_labels, ref, ref_labels, a, n, ds.fps)
            if not f["gen_chunks"] and not f["ref_chunks"]:
                continue
            if f["gen"] is None or f["chunks"] < FEW:
                cells = "too few chunks to compare"
            else:
                (x, y), (fx, fy) = f["gen"], f["floor"]
                cells = f"{x:7.3f} / {y:.3f} {fx:7.3f} / {fy:.3f} {x / fx:5.1f} {y / fy:5.1f}"
            print(f"{'':{len(setting) + 1}s} {name:10s} {f['gen_chunks']:13d} {f['ref_chunks']:11d} "
                  f"{f['chunks']:8d} {cells}")
        a, b = reference_halves(ref, n)
        x, y, m = pskl_equal(gen, b, ds.fps, n)
        fx, fy, _ = pskl_equal(a, b, ds.fps, n)
        print(f"{'':{len(setting) + 1}s} {'every chunk (evaluate)':36s} {m:8d} {x:7.3f} / {y:.3f} {fx:7.3f} / {fy:.3f} "
              f"{x / fx:5.1f} {y / fy:5.1f}")
        walk = names.index("walk") if "walk" in names else None
        if walk is not None:
            for tag, ms, ls in (("output", gen, gen_labels), ("data", ref, ref_labels)):
                v = pace(labelled_chunks(ms, ls, n, walk), ds.fps)
                q = np.percentile(v, [25, 50, 75]) if len(v) else [np.nan] * 3
                print(f"{'':{len(setting) + 1}s} walking chunks, {tag}: pelvis pace quartiles "
                      f"{q[0]:.2f} / {q[1]:.2f} / {q[2]:.2f} m/s ({len(v)} chunks)")


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
