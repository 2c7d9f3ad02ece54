"""PSKL by action, and how fast each set walks (not a timed test).

    python benchmarks/pskl_by_action.py ckpt=PATH [split=val] [settings=static,dynamic] [k=2] [pairs=1] [steps=10]

`evaluate`'s PSKL compares every 2 s chunk of the generated motion with every chunk of the
scenes' data, whatever is done in them: the data sits, lies, stands and walks, a dynamic
sample walks and picks up. A mixture of spectra can read near the data's where no action does.
This runs the `evaluate` protocol (seed 0, DDIM-`steps`) on the split's scenes and prints,
for each action, PSKL(gen, ref) / PSKL(ref, gen) between the output's chunks labelled with it
and one half of the data's chunks with the same label, beside the data's own split-half value
for that action (a chunk has an action when at least half its frames carry the label; the
figures `evaluate` reports by action, `motiongen.eval.pskl_sets.action_figures`, with the
chunk counts), and `evaluate`'s figure over every chunk. Then the pelvis's pace over the floor
in the walking chunks: its quartiles for the output and the data.
"""

from __future__ import annotations

import warnings

import numpy as np

from motiongen.cli import parse_key_values, tool_main
from motiongen.eval.pairs import ProtocolConfig
from motiongen.eval.protocol import evaluate
from motiongen.eval.pskl_sets import action_figures, labelled_chunks
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.loading.build import load_model
from motiongen.sampling import SamplerSettings
from motiongen.skeleton import PELVIS

SPEC = {"ckpt": (str, None), "split": (str, "val"), "settings": (list, ["static", "dynamic"]), "k": (int, 2),
        "pairs": (int, 1), "steps": (int, 10)}


def pace(chunks, fps: float) -> np.ndarray:
    """(N,) each chunk's mean pelvis speed over the floor (m/s)."""
    return np.array([np.linalg.norm(np.diff(c[:, PELVIS, [0, 2]], axis=0), axis=-1).mean() * fps for c in chunks])


def cells(gen, floor) -> str:
    """The output's figures, the data's, and their ratios."""
    if gen is None or floor is None:
        return "too few chunks to compare"
    (x, y), (fx, fy) = gen, floor
    return f"{x:7.3f} / {y:.3f} {fx:7.3f} / {fy:.3f} {x / fx:5.1f} {y / fy:5.1f}"


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, required=("ckpt",), usage=__doc__.splitlines()[2].strip())
    loaded = load_model(opts["ckpt"])
    ds = open_dataset(DataConfig(), verbose=False)
    scenes = [s for s in ds.splits[opts["split"]] if s in ds.scenes]
    warnings.simplefilter("ignore")                  # a sample's episode limit: counted by evaluate, not here
    cfg = ProtocolConfig(k=opts["k"], pairs=opts["pairs"], ablation_pairs=0)
    n, names = cfg.pskl_frames, list(loaded.action_names)
    print(f"{opts['ckpt']}: {opts['split']} scenes {scenes[0]}-{scenes[-1]}, k={opts['k']}, {opts['pairs']} pair(s) "
          f"per scene, DDIM-{opts['steps']}; {n}-frame chunks; PSKL(gen,ref) / PSKL(ref,gen) in nats")
    for setting in opts["settings"]:
        ev = evaluate(loaded, ds, scenes, cfg, [setting], SamplerSettings("ddim", opts["steps"]), progress=False)
        gen = [m for r in ev.results[setting] for m in r.kept]
        gen_labels = [lab for r in ev.results[setting] for lab in r.labels]
        refs = ev.references[setting]
        ref, ref_labels = [m for r in refs for m in r.motions], [x for r in refs for x in r.labels]
        pad = " " * (len(setting) + 1)
        print(f"\n{setting}: {'action':10s} {'output chunks':>13s} {'half chunks':>11s} {'compared':>8s} "
              f"{'output vs data':>16s} {'data vs data':>15s} {'ratio':>11s}")
        figures = action_figures(gen, gen_labels, names, ref, ref_labels, list(ds.action_names), n, ds.fps)
        for name, f in figures.items():
            if f["gen_chunks"] or f["half_chunks"]:
                print(f"{pad} {name:10s} {f['gen_chunks']:13d} {f['half_chunks']:11d} {f['chunks']:8d} "
                      f"{cells(f['gen'], f['floor'])}")
        out, data = ev.model[setting], ev.reference[setting]          # evaluate's own figures over every chunk
        print(f"{pad} {'every chunk (evaluate)':36s} {out['pskl_chunks']:8d} "
              f"{cells((out['pskl_gen_ref'], out['pskl_ref_gen']), (data['pskl_gen_ref'], data['pskl_ref_gen']))}")
        if "walk" in names:
            for tag, ms, ls, w in (("output", gen, gen_labels, names.index("walk")),
                                   ("data", ref, ref_labels, list(ds.action_names).index("walk"))):
                v = pace(labelled_chunks(ms, ls, n, w), ds.fps)
                q = np.percentile(v, [25, 50, 75]) if len(v) else [np.nan] * 3
                print(f"{pad} walking chunks, {tag}: pelvis pace quartiles "
                      f"{q[0]:.2f} / {q[1]:.2f} / {q[2]:.2f} m/s ({len(v)} chunks)")


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
