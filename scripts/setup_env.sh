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
# Headless OpenGL (Mesa's EGL and its llvmpipe software renderer) for the video's camera panel.
# Best effort: without it videos fall back to matplotlib + numpy (scene as boxes) and
# tests/test_gl_render.py is skipped.
if ! ls /usr/lib/*/libEGL_mesa.so.0 /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1 && command -v apt-get >/dev/null; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq libegl1 libegl-mesa0 libgl1-mesa-dri >/dev/null; } \
    || echo "warning: could not install Mesa EGL (libegl1 libegl-mesa0 libgl1-mesa-dri); videos use the slower fallback" >&2
fi
