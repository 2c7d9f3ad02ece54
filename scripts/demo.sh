#!/usr/bin/env bash
# The main job on the embedded default: install, generate the synthetic dataset, train the demo
# model, sample a motion through goal points in a synthetic test scene, write npz + video.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup_env.sh
PY="${VENV:-.venv}/bin/python"
RUN="${RUN_DIR:-runs/demo}"
"$PY" train.py experiment=demo "hydra.run.dir=$RUN" train.resume=auto "$@"
if [ -f sample.py ]; then
  "$PY" sample.py "ckpt=$RUN/checkpoints/last.pt" scene=synthetic:91 "out=$RUN/sample"
fi
echo "demo outputs: $RUN (checkpoints/, tb/ for TensorBoard${RUN:+, sample/ for motion.npz and the video})"
