#!/usr/bin/env bash
# README command 1: set up, then run a demo episode headless on the embedded
# default scenario (procedural room, seed 0). Results in runs/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
exec .venv/bin/vamg run --seed "${SEED:-0}" --out "${OUT:-runs/demo}" "$@"
