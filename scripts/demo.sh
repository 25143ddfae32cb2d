#!/usr/bin/env bash
# README command 1: set up, then run a demo episode headless on the embedded
# default scenario (vamg_drake/scenarios/demo.yaml: the static benchmark suite's
# scene 3). SEED=N runs the procedural room of seed N instead (then --dynamic
# works too). Results in runs/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
if [[ -n "${SEED:-}" ]]; then
  exec .venv/bin/vamg run --seed "${SEED}" --out "${OUT:-runs/demo}" "$@"
fi
exec .venv/bin/vamg run --scenario vamg_drake/scenarios/demo.yaml --out "${OUT:-runs/demo}" "$@"
