#!/usr/bin/env bash
# The figures of docs/quality.md for one recipe: train it with several seeds, then evaluate the
# checkpoints together on one split (mean ± spread over the seeds, the ablation table, the
# network's own joints beside the output). Settings are chosen on `val`; a recipe's `test`
# figures are taken once, after.
#
#   bash scripts/quality_figures.sh                       # demo, seeds 0 1 2, validation scenes
#   RECIPE=quality SEEDS="0 1" bash scripts/quality_figures.sh
#   SPLIT=test bash scripts/quality_figures.sh            # once the recipe and its defaults are fixed
#
# Checkpoints go to runs/<recipe>-s<seed> (resumed when there), the report to
# runs/quality-<recipe>-<split>/report.md. PAIRS and K set the protocol's pairs per scene and
# samples per pair (default 2 and 3: about 20 minutes per demo checkpoint on 2 CPU cores); JOBS the
# evaluation's worker processes (default 2: `evaluate jobs=2`, the same figures sooner).
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${VENV:-.venv}/bin/python"
RECIPE="${RECIPE:-demo}"
SEEDS="${SEEDS:-0 1 2}"
SPLIT="${SPLIT:-val}"
ckpts=()
for s in $SEEDS; do
  run="runs/$RECIPE-s$s"
  "$PY" train.py "experiment=$RECIPE" "seed=$s" "hydra.run.dir=$run" train.resume=auto
  ckpts+=("$run/checkpoints/last.pt")
done
list=$(IFS=,; echo "${ckpts[*]}")
"$PY" evaluate.py "ckpt=[$list]" "split=$SPLIT" "pairs=${PAIRS:-2}" "k=${K:-3}" "jobs=${JOBS:-2}" progress=false \
  "out=runs/quality-$RECIPE-$SPLIT"
