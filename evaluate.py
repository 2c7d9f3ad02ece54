"""Evaluate a trained model: `python evaluate.py ckpt=PATH [scenes=[91,92]] [k=5] [steps=10] ...`.

The TRUMANS static/dynamic protocol on the test scenes of the checkpoint's dataset, with the
dataset's own motion as a reference row: report.json, report.md and plots/ in `out`
(docs/evaluation.md). `--help` lists every key (EvaluateConfig). Same as
`motiongen evaluate ...`.
"""

if __name__ == "__main__":
    from motiongen.commands import run_script

    run_script("evaluate")
