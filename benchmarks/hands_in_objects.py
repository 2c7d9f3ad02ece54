"""Hands in objects, on the body mesh (not a timed test): for the `evaluate` protocol's dynamic
setting, the share of pick-up frames with any hand vertex inside the picked-up object, the share
of interactions whose hand touches it, the per-frame contact and the closest signed hand-object
distance (`motiongen.eval.mesh_scores`), in one run: for the output with the hand reach as it
is, with its parts taken away one at a time (a wrist-only reach: the hand beyond the wrist
ignored, `interactions.HAND_SPAN = ()`; no hands moved out of objects on the mesh after the
solve, `hand_clearance.ROUNDS = 0`), for the network's own joints and for the data.

    python benchmarks/hands_in_objects.py ckpt=PATH [split=val] [k=2] [pairs=5] [steps=10] [parts=true]

parts=false: the hand reach as it is only (a third of the time).
"""

from __future__ import annotations

import warnings

import motiongen.sampling.hand_clearance as hand_clearance
import motiongen.sampling.interactions as interactions
from motiongen.cli import parse_key_values, tool_main
from motiongen.eval.pairs import ProtocolConfig
from motiongen.eval.protocol import evaluate
from motiongen.importers.sources import DataConfig, open_dataset
from motiongen.loading.build import load_model
from motiongen.sampling import SamplerSettings

SPEC = {"ckpt": (str, None), "split": (str, "val"), "k": (int, 2), "pairs": (int, 5), "steps": (int, 10),
        "parts": (bool, True)}
KEYS = (("hand_inside_frames", "hand inside"), ("touched", "touched"), ("mesh_contact_rate", "contact"),
        ("hand_object_sdist_m", "signed dist [m]"), ("completed", "completed"))


def line(label: str, row: dict) -> str:
    return f"{label:34s}" + "".join(f"{row.get(k, float('nan')) if row.get(k) is not None else float('nan'):>16.3f}"
                                    for k, _ in KEYS)


def run(argv: list[str]) -> None:
    opts = parse_key_values(argv, SPEC, required=("ckpt",), usage=__doc__.splitlines()[8].strip())
    loaded = load_model(opts["ckpt"])
    ds = open_dataset(DataConfig(), verbose=False)
    scenes = [s for s in ds.splits[opts["split"]] if s in ds.scenes]
    cfg = ProtocolConfig(k=opts["k"], pairs=opts["pairs"], ablation_pairs=0)
    sampler = SamplerSettings("ddim", opts["steps"])
    warnings.simplefilter("ignore")
    rows = {}
    span, rounds = interactions.HAND_SPAN, hand_clearance.ROUNDS
    variants = (("output, wrist-only reach", (), 0), ("output, no mesh check", span, 0),
                ("output (hand reach as is)", span, rounds))
    for label, hand, settle in variants if opts["parts"] else variants[-1:]:
        interactions.HAND_SPAN, hand_clearance.ROUNDS = hand, settle
        ev = evaluate(loaded, ds, scenes, cfg, ["dynamic"], sampler, progress=False)
        rows[label] = ev.model["dynamic"]
    interactions.HAND_SPAN, hand_clearance.ROUNDS = span, rounds
    rows["network's own joints"] = ev.model_raw["dynamic"]
    rows["data"] = ev.reference["dynamic"]
    print(f"{opts['ckpt']}: {opts['split']} scenes {scenes[0]}-{scenes[-1]}, dynamic setting, k={opts['k']}, "
          f"{opts['pairs']} pairs per scene, DDIM-{opts['steps']}")
    print(f"{'':34s}" + "".join(f"{name:>16s}" for _, name in KEYS))
    for label, row in rows.items():
        print(line(label, row))


if __name__ == "__main__":
    tool_main(run)()                     # a bad key: one line, exit 2
