"""Cost of the benchmark harness: an isolated episode (spawned process) vs in-process.

Fixed workload: the smoke suite's two scenarios, the scripted method, a 1 s
time limit, ``--episodes`` episodes each way. The reference is the same episode
function called in this process (no isolation). Reports the per-episode
overhead of isolation (process spawn + imports + pipe) and the suite build time.

Usage: python benchmarks/bench_runner.py [--json] [--episodes N]
"""

import argparse
import dataclasses as dc
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from vamg_drake.bench.methods import load_methods
from vamg_drake.bench.runner import episode_specs, run_isolated, run_scenario_episode
from vamg_drake.bench.suites import SUITES, materialize_suite


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--episodes", type=int, default=4)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        config = dc.replace(SUITES["smoke"], time_limit=1.0)
        t = time.perf_counter()
        suite = materialize_suite(config, Path(tmp), progress=False)
        build_s = time.perf_counter() - t
        specs = episode_specs(suite, load_methods(["scripted"]), args.episodes)[: args.episodes]
        run_scenario_episode(specs[0])  # warm caches (numba, YCB) for the in-process reference
        inproc, isolated = [], []
        for spec in specs:
            t = time.perf_counter()
            run_scenario_episode(spec)
            inproc.append(time.perf_counter() - t)
            record = run_isolated(spec, wall_limit=300)
            assert record.status != "error", record.error
            isolated.append(record.wall_time)
    result = {
        "episodes": len(specs),
        "suite_build_s": round(build_s, 2),
        "episode_in_process_s_median": round(float(np.median(inproc)), 2),
        "episode_isolated_s_median": round(float(np.median(isolated)), 2),
        "isolation_overhead_s_median": round(float(np.median(np.array(isolated) - np.array(inproc))), 2),
    }
    if not args.json:
        for k, v in result.items():
            print(f"{k:32s} {v}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
