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
from motiongen.commands import evaluate_command


def _weight(text: str | None) -> float | None:
    """The weight in $MOTIONGEN_CLEARANCE, None where it is unset or not a number >= 0."""
    try:
        w = float(text) if text is not None else None
    except ValueError:
        return None
    return w if w is not None and 0 <= w < float("inf") else None


WEIGHT = _weight(os.environ.get("MOTIONGEN_CLEARANCE"))
if WEIGHT is not None:
    cleanup.clearance_for_rate = lambda model_fps: WEIGHT

if __name__ == "__main__":
    if WEIGHT is None:
        print(f"error: MOTIONGEN_CLEARANCE: expected the swing-clearance weight, a number >= 0, got "
              f"{os.environ.get('MOTIONGEN_CLEARANCE')!r}", file=sys.stderr)
        sys.exit(2)
    sys.argv = ["evaluate", *sys.argv[1:]]
    evaluate_command.main()
