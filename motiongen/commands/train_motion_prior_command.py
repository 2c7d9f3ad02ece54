"""`motiongen train-motion-prior`: train a LEMO motion prior on marker sequences.

    motiongen train-motion-prior kind=smooth out=runs/prior_smooth
    motiongen train-motion-prior kind=infill data=DATASET_DIR out=DIR [steps=...] [net.channels=[...]]

The keys: TrainPriorConfig (motiongen/capture/train_motion_prior.py), through
configs/train_motion_prior.yaml. Writes `out/prior.pt` (the file `fit` loads), the resumable
`out/checkpoints/last.pt` and TensorBoard logs under `out/tb`.

`data=` and `window=` are taken here, not by Hydra: `data` and `window` are also the names of
config groups (those of `motiongen train`), so Hydra would read `data=PATH` or `window=64` as a
choice from that group and refuse it. Their values (Hydra's override grammar: quotes for paths
with spaces) are put into the composed config before the run, type-checked like any other key.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import OverrideParseException
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ValidationError

from motiongen.capture.motion_prior import KINDS
from motiongen.capture.train_motion_prior import train_and_save
from motiongen.checks import require_choice
from motiongen.cli import user_errors_exit_2, value_error
from motiongen.commands.hydra_app import hydra_command
from motiongen.errors import ConfigError
from motiongen.output_lock import OutputLock

TAKEN_KEYS = ("data", "window")          # keys that are config-group names elsewhere
_TAKEN = re.compile(r"^\+{0,2}(" + "|".join(TAKEN_KEYS) + r")=")
_taken: dict = {}


def run(cfg: DictConfig, run_dir: Path) -> None:
    for key, value in _taken.items():
        try:
            cfg[key] = value
        except ValidationError as e:
            raise ConfigError(value_error(e)) from None
    require_choice("kind", cfg.kind, KINDS)             # before net.kind, which follows it
    with OutputLock(cfg.out, "train-motion-prior"):     # one live run per output directory
        train_and_save(OmegaConf.to_object(cfg))


_hydra_main = hydra_command("train_motion_prior", run)


def _value(arg: str):
    """The value of a `key=value` argument, read with Hydra's override grammar."""
    try:
        value = OverridesParser.create().parse_overrides([arg.lstrip("+")])[0].value()
    except OverrideParseException as e:
        raise ConfigError(f"malformed override {arg!r}: {str(e).splitlines()[0]}") from None
    key = arg.lstrip("+").split("=", 1)[0]
    if value is not None and (not isinstance(value, (str, int, float)) or isinstance(value, bool) or value == ""):
        raise ConfigError(f"{key}: expected one value, got {arg.split('=', 1)[1]!r}")
    return value


@user_errors_exit_2
def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else list(argv)
    rest, taken = [], {}
    for a in argv:
        m = _TAKEN.match(a)
        if m:
            taken[m.group(1)] = _value(a)
        else:
            rest.append(a)
    _taken.clear()
    _taken.update(taken)
    try:
        _hydra_main(rest)
    finally:
        _taken.clear()


if __name__ == "__main__":
    main()
