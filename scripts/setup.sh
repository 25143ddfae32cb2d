#!/usr/bin/env bash
# Idempotent set-up on a fresh Debian/Ubuntu machine: the apt libraries for
# headless EGL rendering, Open3D's libusb/libgomp and Graphviz (the notebooks draw the diagram; only
# when missing), a virtual environment in .venv/, and the package with its
# test and jupyter extras.
set -euo pipefail
cd "$(dirname "$0")/.."

need_apt=()
for lib in libEGL.so.1 libGL.so.1 libglib-2.0.so.0 libusb-1.0.so.0 libgomp.so.1; do
  if ! ldconfig -p 2>/dev/null | grep -q "$lib"; then need_apt+=("$lib"); fi
done
command -v dot >/dev/null || need_apt+=(graphviz)
if [ ${#need_apt[@]} -gt 0 ]; then
  echo "setup: installing rendering libraries (missing: ${need_apt[*]})"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libglib2.0-0 libegl1 libgl1 libgl1-mesa-dri libusb-1.0-0 libgomp1 graphviz >/dev/null
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
  # torch first, from the CPU wheel when pip can find one (2.13.0+cpu sorts
  # above 2.13.0), so resolving the package below never downloads CUDA.
  .venv/bin/python -m pip install -q "torch==2.13.0"
  .venv/bin/python -m pip install -q -e ".[test,jupyter]"
  touch "$stamp"
fi
