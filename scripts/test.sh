#!/usr/bin/env bash
# Install everything the test suite needs and run it.
set -euo pipefail
cd "$(dirname "$0")/.."
# Real CMU mocap for the BVH tests comes from Debian's assimp-testmodels; the browser tests of
# `motiongen serve` (tests/test_serve_browser.py) drive Debian's headless chromium with playwright
# (never `playwright install`).
APT_PKGS=()
[ -d /usr/share/assimp/models/BVH ] || APT_PKGS+=(assimp-testmodels)
[ -x /usr/bin/chromium ] || APT_PKGS+=(chromium)
if [ "${#APT_PKGS[@]}" -gt 0 ] && command -v apt-get >/dev/null; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq && $SUDO apt-get install -y -qq "${APT_PKGS[@]}" >/dev/null
fi
bash scripts/setup_env.sh test
PY="${VENV:-.venv}/bin/python"
if [ "$#" -gt 0 ]; then
  exec "$PY" -m pytest "$@"
fi
# Two workers, one test file each at a time (a file's fixtures are built once); most tests wait
# on subprocesses and files as much as they compute. The tests of the live server play motion on
# the wall clock, so they run afterwards with the machine to themselves.
"$PY" -m pytest -n 2 --dist loadfile -m "not live"
"$PY" -m pytest -m live
