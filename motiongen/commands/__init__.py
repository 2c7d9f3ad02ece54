"""The `motiongen` command: one entry point for every tool.

    motiongen <command> [key=value ...]      motiongen <command> --help      motiongen --help

Every command is a module with `main(argv=None)` (argv: the arguments after the command name;
None = sys.argv[1:], when the module runs as a script). A module that is only a command line is
`motiongen/commands/<command>_command.py`; a tool that is one library module with its own
command line (the importers, annotation and capture tools) has its `main` at the end of that
module. `train`, `distill`, `sample`, `serve`, `evaluate` and `train-body-mlp` are Hydra applications
(motiongen/configs/<app>.yaml over the structured configs of motiongen/config.py; `--help`
prints their whole config); the others take `key=value` arguments in the same override syntax
and list their keys and defaults with `--help`. Every user error is one line on stderr and exit
status 2; Ctrl-C is one line (`interrupted[: what is left]`) and exit status 130.
"""

from __future__ import annotations

import importlib
import sys

# name -> (module with `main(argv=None)`, what it does).
COMMANDS: dict[str, tuple[str, str]] = {
    "train": ("motiongen.commands.train_command", "train a motion model (or the joints-to-body MLP: task=joints2body)"),
    "distill": ("motiongen.commands.distill_command", "a 1-, 2- or 4-step student of a trained model (trajectory distillation)"),
    "sample": ("motiongen.commands.sample_command", "generate motion through goal points in a scene: npz, video, BVH, SMPL-X"),
    "serve": ("motiongen.commands.serve_command", "a web page that steers the body live: click goals, pick actions, download glTF"),
    "evaluate": ("motiongen.commands.evaluate_command", "the TRUMANS static/dynamic protocol against the data and real mocap"),
    "fit": ("motiongen.commands.fit_command", "joint trajectories -> SMPL-X body parameters (MLP + refinement)"),
    "synthetic": ("motiongen.commands.synthetic_command", "generate the embedded synthetic dataset"),
    "import-bvh": ("motiongen.importers.bvh", "BVH files -> a motiongen dataset"),
    "import-amass": ("motiongen.importers.amass", "AMASS-style SMPL-X / SMPL-H npz -> a motiongen dataset"),
    "import-trumans": ("motiongen.importers.trumans", "the public TRUMANS release -> a motiongen dataset"),
    "annotate-contact": ("motiongen.annotation.annotate_contact", "per-vertex body-scene/object contact labels for a dataset (B.6)"),
    "augment": ("motiongen.annotation.augment", "contact-preserving augmentation: scale, swap, move objects (B.5)"),
    "fit-multiview": ("motiongen.capture.fit_multiview", "calibrated cameras + 2D keypoints -> SMPL-X motion (3 stages, the multi-view capture paper)"),
    "pose-prior": ("motiongen.capture.pose_prior", "build the multi-view fit's PCA pose prior from a dataset or AMASS files"),
    "contact-sensors": ("motiongen.capture.contact_sensors", "force-sensor recordings -> per-frame joint contact (clap sync, thresholds)"),
    "train-body-mlp": ("motiongen.commands.train_body_mlp_command", "train the joints-to-SMPL-X MLP alone (Hydra, TrainMLPConfig)"),
    "train-motion-prior": ("motiongen.commands.train_motion_prior_command", "train a LEMO motion prior (kind=smooth|infill) on marker sequences"),
}


def usage() -> str:
    width = max(len(c) for c in COMMANDS)
    rows = "\n".join(f"  {name:<{width}}  {what}" for name, (_, what) in COMMANDS.items())
    return f"usage: motiongen <command> [key=value ...]   (motiongen <command> --help for its keys)\n\ncommands:\n{rows}"


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage())
        sys.exit(0 if argv else 2)
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"error: unknown command {name!r}; expected one of {', '.join(COMMANDS)}", file=sys.stderr)
        sys.exit(2)
    sys.exit(_load(name).main(rest) or 0)


def run_script(name: str) -> None:
    """What the repository's root scripts (train.py, sample.py, evaluate.py) do: the command's
    `main()` on sys.argv, with Ctrl-C during the imports one line too."""
    _load(name).main()


def _load(name: str):
    """The module of command `name`, imported."""
    try:
        return importlib.import_module(COMMANDS[name][0])         # torch and friends: seconds
    except KeyboardInterrupt:
        # Ctrl-C before the command's own handler (motiongen.cli.user_errors_exit_2) is in place:
        # the same one line and status; not imported from there, to keep `motiongen --help` fast.
        print("interrupted", file=sys.stderr, flush=True)
        sys.exit(130)
