#!/usr/bin/env bash
# Create/refresh the project virtual environment at $VENV (default .venv) and install motiongen.
# torch==2.13.0 goes in first where no torch is present: on CPU-only machines that is the local
# CPU build, and it stops pip from resolving a multi-GB CUDA build for the bare `torch` requirement.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${VENV:-.venv}"
EXTRAS="${1:-}"
PY="${PYTHON:-python3}"
if [ ! -x "$VENV/bin/python" ]; then
  "$PY" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null
if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
  "$VENV/bin/python" -m pip install -q "torch==2.13.0"
fi
"$VENV/bin/python" -m pip install -q -e ".${EXTRAS:+[$EXTRAS]}"
