#!/usr/bin/env bash
# Idempotent set-up on a fresh Debian/Ubuntu machine: the apt libraries for
# headless EGL rendering and Graphviz (the notebooks draw the diagram; only
# when missing), a virtual environment in .venv/, and the package with its
# test and jupyter extras.
set -euo pipefail
cd "$(dirname "$0")/.."

need_apt=()
for lib in libEGL.so.1 libGL.so.1 libglib-2.0.so.0; do
  if ! ldconfig -p 2>/dev/null | grep -q "$lib"; then need_apt+=("$lib"); fi
done
command -v dot >/dev/null || need_apt+=(graphviz)
if [ ${#need_apt[@]} -gt 0 ]; then
  echo "setup: installing rendering libraries (missing: ${need_apt[*]})"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libglib2.0-0 libegl1 libgl1 libgl1-mesa-dri graphviz >/dev/null
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv"
  "$PY" -m venv .venv
fi
stamp=.venv/.vamg-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "setup: installing vamg_drake and its dependencies into .venv"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e ".[test,jupyter]"
  touch "$stamp"
fi
