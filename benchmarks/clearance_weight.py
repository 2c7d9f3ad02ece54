"""`motiongen evaluate` with the final solve's swing-clearance weight set to one value at every
model rate (not a timed test): the sweep behind `assemble.clearance_for_rate`'s two values
(docs/results.md, "Swing clearance by the model's rate").

    MOTIONGEN_CLEARANCE=W python benchmarks/clearance_weight.py [any evaluate keys]

The weight comes from the environment rather than a key so that `evaluate jobs=N`'s worker
processes, which import this module again when they start, replace the rule too.
"""

from __future__ import annotations

import os
import sys

import motiongen.sampling.cleanup as cleanup

if "MOTIONGEN_CLEARANCE" in os.environ:
    WEIGHT = float(os.environ["MOTIONGEN_CLEARANCE"])
    cleanup.clearance_for_rate = lambda model_fps: WEIGHT

if __name__ == "__main__":
    if "MOTIONGEN_CLEARANCE" not in os.environ:
        print("error: set MOTIONGEN_CLEARANCE to the swing-clearance weight", file=sys.stderr)
        sys.exit(2)
    from motiongen.commands import evaluate_command

    sys.argv = ["evaluate", *sys.argv[1:]]
    evaluate_command.main()
