#!/usr/bin/env bash
# Install everything the test suite needs and run it.
set -euo pipefail
cd "$(dirname "$0")/.."
# Real CMU mocap for the BVH tests comes from Debian's assimp-testmodels.
if [ ! -d /usr/share/assimp/models/BVH ] && command -v apt-get >/dev/null; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq && $SUDO apt-get install -y -qq assimp-testmodels >/dev/null
fi
bash scripts/setup_env.sh test
"${VENV:-.venv}/bin/python" -m pytest "$@"
