"""PSKL by body part, for each final solve (not a timed test).

    python benchmarks/pskl_by_part.py ckpt=PATH [split=val] [settings=static,dynamic] [k=2] [pairs=1] [steps=10]
                                      [solves=lbfgs,joint-space,refined]

Runs the `evaluate` protocol (seed 0, DDIM-`steps`) on the split's scenes once per final
solve (`loop.solve`, each of `solves`) and prints PSKL(gen, ref) / PSKL(ref, gen) of the
output against the data, on all 22 joints as `evaluate` reports it and on each part alone:
the legs and feet, the arms (collars to wrists), the trunk and head. A solve whose PSKL is off
in one setting only is off somewhere in particular; this says where.
"""

from __future__ import annotations

import warnings

from motiongen.checks import require_choice
from motiongen.cli import parse_key_values, tool_main
from motiongen.eval.pairs import ProtocolConfig
from motiongen.eval.protocol import evaluate
from motiongen.eval.pskl_sets import pskl_equal, reference_halves
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.loading.build import load_model
from motiongen.sampling import SamplerSettings
from motiongen.sampling.assemble import SOLVE_METHODS
from motiongen.skeleton import BODY_JOINT_NAMES

SPEC = {"ckpt": (str, None), "split": (str, "val"), "settings": (list, ["static", "dynamic"]), "k": (int, 2),
        "pairs": (int, 1), "steps": (int, 10), "solves": (list, list(SOLVE_METHODS))}
PARTS = {"all": ("",), "legs and feet": ("hip", "knee", "ankle", "foot"),
         "arms": ("collar", "shoulder", "elbow", "wrist"), "trunk and head": ("pelvis", "spine", "neck", "head")}


def part_joints(keys: tuple[str, ...]) -> list[int]:
    """The body joints whose names hold one of `keys` ("" holds every name)."""
    return [i for i, name in enumerate(BODY_JOINT_NAMES) if any(k in name for k in keys)]


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, required=("ckpt",), usage=__doc__.splitlines()[2].strip())
    for solve in opts["solves"]:
        require_choice("solves", solve, SOLVE_METHODS)
    loaded = load_model(opts["ckpt"])
    ds = open_dataset(DataConfig(), verbose=False)
    scenes = [s for s in ds.splits[opts["split"]] if s in ds.scenes]
    sampler = SamplerSettings("ddim", opts["steps"])
    warnings.simplefilter("ignore")                  # a sample's episode limit: counted by evaluate, not here
    print(f"{opts['ckpt']}: {opts['split']} scenes {scenes[0]}-{scenes[-1]}, k={opts['k']}, {opts['pairs']} pair(s) "
          f"per scene, DDIM-{opts['steps']}; PSKL(gen,ref) / PSKL(ref,gen) in nats")
    print(f"{'':24s}" + "".join(f"{name:>20s}" for name in PARTS))
    for setting in opts["settings"]:
        for solve in opts["solves"]:
            cfg = ProtocolConfig(k=opts["k"], pairs=opts["pairs"], ablation_pairs=0, loop={"solve": solve})
            ev = evaluate(loaded, ds, scenes, cfg, [setting], sampler, progress=False)
            gen = [m for r in ev.results[setting] for m in r.kept]                         # (T, J, 3) each
            ref = [m for r in ev.references[setting] for m in r.motions]
            cells = []
            for keys in PARTS.values():
                js = part_joints(keys)
                _, half = reference_halves([m[:, js] for m in ref], cfg.pskl_frames)
                a, b, _ = pskl_equal([m[:, js] for m in gen], half, ds.fps, cfg.pskl_frames)
                cells.append(f"{a:.3f} / {b:.3f}")
            print(f"{setting + ', ' + solve:24s}" + "".join(f"{c:>20s}" for c in cells), flush=True)


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
